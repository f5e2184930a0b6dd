// The Whitted integrator: the primal of fovjax.render.radiance on the CPU (its oracle and its
// derivative: fovjax/render/_integrator.py).
#pragma once

#include "native/csrc/layout.h"
#include "native/csrc/scene_cache.h"
#include "native/csrc/thread_pool.h"
#include "trace/_embree_queries.cc"

namespace {

//
// The same arithmetic as the JAX integrator (fovjax/render/_integrator.py), written per ray:
// closest hit, Blinn–Phong or Phong with a shadow ray per light (point, directional and spot
// lights), mirror reflections to max_depth (or until their weight's luminance falls below the
// contribution cut-off). It returns each ray's radiance (NaN/inf kept: the caller paints bad
// samples) and the rays it traced; derivatives come from the JAX integrator (a custom JVP on
// the Python side).

struct Vec3 {
  float x, y, z;
};
inline Vec3 Load3(const float* p) { return {p[0], p[1], p[2]}; }
inline Vec3 operator+(Vec3 a, Vec3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
inline Vec3 operator-(Vec3 a, Vec3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline Vec3 operator*(Vec3 a, Vec3 b) { return {a.x * b.x, a.y * b.y, a.z * b.z}; }
inline Vec3 operator*(Vec3 a, float s) { return {a.x * s, a.y * s, a.z * s}; }
inline Vec3 operator*(float s, Vec3 a) { return {s * a.x, s * a.y, s * a.z}; }
inline float Dot(Vec3 a, Vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 Cross(Vec3 a, Vec3 b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline Vec3 Normalize(Vec3 v) {
  float n2 = Dot(v, v);
  return v * (n2 > 0.0f ? 1.0f / std::sqrt(n2) : 0.0f);
}
inline Vec3 Interpolate(float b0, float b1, float b2, Vec3 c0, Vec3 c1, Vec3 c2) {
  return c0 * b0 + c1 * b1 + c2 * b2;
}
inline int Mod(int64_t a, int64_t m) { return static_cast<int>(((a % m) + m) % m); }
inline int64_t ToIndex(float x) {  // float to int with the huge values clamped (no overflow)
  return static_cast<int64_t>(std::fmin(std::fmax(x, -1e9f), 1e9f));
}

struct Texture {
  const float* texels;  // (h, w, 3)
  int64_t h, w;
};

// The shading options of `RenderConfig` (the handlers' attributes).
struct Shading {
  int32_t specular = kSpecularBlinnPhong;  // kSpecularBlinnPhong or kSpecularPhong
  bool payload = false;                    // the specular term times n·l too (`specular_payload`)
  float min_contribution = 0.0f;           // reflections stop below this luminance of their weight
};

struct ShadeScene {
  const float* vertices;
  const int32_t* faces;
  const int32_t* face_material;
  int64_t num_faces;
  int64_t num_vertices;
  std::atomic<int>* out_of_range;  // set where a hit face's vertex or material is out of range
  const float* normals;  // null: none
  const float* uvs;      // null: none
  const float* materials;  // (M, 16): ka, kd, ks, ke, kr, ns
  const int32_t* texture;  // (M,): index into textures, -1: none
  int64_t num_materials;
  std::vector<Texture> textures;
  const float* lights;  // (L, kLightStride): position (or direction towards the light), colour,
                        // a spot light's unit axis and cos of its (inner, outer) half-angles
  const int32_t* light_kind;  // kLightPoint, kLightDirectional or kLightSpot
  int num_lights;
  Vec3 ambient;
  Texture environment;
  float offset;
  int max_depth;
  bool recompute;  // u, v by Möller–Trumbore on `vertices` (RenderConfig.hits "recomputed")
  Shading shading;
  // Shading fidelity per class of rays (`ShadingClasses`, fovjax/render/_integrator.py), a ray's
  // class given with it (a reflection keeps its sample's): null tables, every ray at full
  // fidelity (`ClassesFrom`).
  const int32_t* class_depth = nullptr;    // (K,): reflections only while depth < it
  const int32_t* class_shadows = nullptr;  // (K,): kShadowsAll, kShadowsBrightest or kShadowsNone
  const int32_t* class_level = nullptr;    // (K,): the tree of a merged BVH, or null (tree 0)
  int32_t num_classes = 0;
  int brightest = 0;  // the light of the largest R + G + B (the first of equals, as jnp.argmax)
  bool spots = false;  // whether a light is a spot light
};

// A ray's class as an index of the tables (clamped, as a JAX gather clamps).
inline int32_t ClassIndex(const ShadeScene& s, int32_t c) {
  return c < 0 ? 0 : (c >= s.num_classes ? s.num_classes - 1 : c);
}

// Whether class `c` traces a shadow ray to light l (`_tested_lights`); a light it does not test
// lights the point unshadowed.
inline bool Tested(const ShadeScene& s, int32_t c, int l) {
  const int32_t mode = s.class_shadows[c];
  return mode == kShadowsAll || (mode == kShadowsBrightest && l == s.brightest);
}

// Where a light is and how much of it reaches p (`_shadow_rays`): the direction and distance
// towards it, and a spot light's cone factor (1 for the other kinds): 1 within the inner
// half-angle of its axis, 0 beyond the outer, linear in the cosine between.
struct LightAt {
  Vec3 to_light;
  bool positional;
  float spot;
};

// Always inlined: the adjoint runs it per light at every hit, and GCC left it out of line; the
// forward's is `LightPlanes`, the same arithmetic for a block's hits.
inline __attribute__((always_inline)) LightAt LightTowards(const ShadeScene& s, int l, Vec3 p, Vec3* dir) {
  const float* row = s.lights + kLightStride * l;
  const int32_t kind = s.light_kind[l];
  LightAt at;
  at.positional = kind == kLightPoint || kind == kLightSpot;
  Vec3 position = Load3(row);
  at.to_light = at.positional ? position - p : position;
  *dir = Normalize(at.to_light);
  at.spot = 1.0f;
  if (kind == kLightSpot) {
    const float c = -Dot(Load3(row + 6), *dir), cos_inner = row[9], cos_outer = row[10];
    at.spot = c >= cos_inner ? 1.0f : c > cos_outer ? (c - cos_outer) / (cos_inner - cos_outer) : 0.0f;
  }
  return at;
}

constexpr float kPi = 3.14159265358979323846f;

Vec3 Texel(const Texture& t, int64_t row, int64_t col) { return Load3(t.texels + 3 * (row * t.w + col)); }

// bilinear_wrap
Vec3 Bilinear(const Texture& t, float u, float v) {
  if (!std::isfinite(u)) u = 0.0f;
  if (!std::isfinite(v)) v = 0.0f;
  float x = u * t.w - 0.5f, y = v * t.h - 0.5f;
  float x0 = std::floor(x), y0 = std::floor(y);
  float fx = x - x0, fy = y - y0;
  int i0 = Mod(ToIndex(x0), t.w), j0 = Mod(ToIndex(y0), t.h);
  int i1 = Mod(i0 + 1, t.w), j1 = Mod(j0 + 1, t.h);
  Vec3 row0 = Texel(t, j0, i0) * (1 - fx) + Texel(t, j0, i1) * fx;
  Vec3 row1 = Texel(t, j1, i0) * (1 - fx) + Texel(t, j1, i1) * fx;
  return row0 * (1 - fy) + row1 * fy;
}

// envmap_lookup
Vec3 Environment(const Texture& e, Vec3 d) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  if (e.h == 1 && e.w == 1) {
    if (!std::isfinite(d.x + d.y + d.z)) return {nan, nan, nan};
    return Load3(e.texels);
  }
  if (!(std::isfinite(d.x) && std::isfinite(d.y) && std::isfinite(d.z))) return {nan, nan, nan};
  float n2 = Dot(d, d);
  float inv = n2 > 0.0f ? 1.0f / std::sqrt(n2) : 0.0f;
  float dx = d.x * inv, dy = d.y * inv, dz = d.z * inv;
  bool pole = dx == 0.0f && dz == 0.0f;
  float theta = std::atan2(pole ? 0.0f : dx, pole ? 1.0f : dz);
  float u = (theta + kPi) / (2.0f * kPi);
  float v = 0.5f * (1.0f + std::fmin(std::fmax(dy, -1.0f), 1.0f));
  float x = u * e.w - 0.5f, y = (1.0f - v) * e.h - 0.5f;
  float x0 = std::floor(x), y0 = std::floor(y);
  float fx = x - x0, fy = y - y0;
  int i0 = Mod(ToIndex(x0), e.w), i1 = Mod(i0 + 1, e.w);
  int64_t row = ToIndex(y0);
  int64_t j0 = std::min<int64_t>(std::max<int64_t>(row, 0), e.h - 1);
  int64_t j1 = std::min<int64_t>(std::max<int64_t>(row + 1, 0), e.h - 1);
  Vec3 top = Texel(e, j0, i0) * (1 - fx) + Texel(e, j0, i1) * fx;
  Vec3 bottom = Texel(e, j1, i0) * (1 - fx) + Texel(e, j1, i1) * fx;
  return top * (1 - fy) + bottom * fy;
}

// A hit's surface, as `hit_geometry` and the shading compute it: the point, the geometric
// normal and the shading normal (both facing the ray's origin) and the barycentrics, u and v
// recomputed from the face where `recompute` (else the given ones). SurfaceAt is the adjoint's,
// one ray at a time; the forward's are SurfacePlanes', the same arithmetic for a block of rays.
struct Surface {
  Vec3 p, ng, nsh;
  float b0, u, v;
};

inline __attribute__((always_inline)) Surface SurfaceAt(const ShadeScene& s, const int32_t* face, Vec3 o,
                                                        Vec3 d, float u, float v, bool recompute) {
  Vec3 c0 = Load3(s.vertices + 3 * face[0]), c1 = Load3(s.vertices + 3 * face[1]),
       c2 = Load3(s.vertices + 3 * face[2]);
  if (recompute) {
    Vec3 e1 = c1 - c0, e2 = c2 - c0;
    Vec3 pvec = Cross(d, e2);
    float det = Dot(e1, pvec);
    if (det != 0.0f) {
      float inv_det = 1.0f / det;
      Vec3 tvec = o - c0;
      Vec3 qvec = Cross(tvec, e1);
      u = Dot(tvec, pvec) * inv_det;
      v = Dot(d, qvec) * inv_det;
    } else {
      u = v = 0.0f;
    }
  }
  Surface at;
  at.u = u;
  at.v = v;
  at.b0 = 1.0f - u - v;
  at.p = Interpolate(at.b0, u, v, c0, c1, c2);
  Vec3 ng = Normalize(Cross(c1 - c0, c2 - c0));
  const float sign = Dot(ng, d) > 0.0f ? -1.0f : 1.0f;
  at.ng = ng * sign;
  at.nsh = at.ng;
  if (s.normals != nullptr) {
    Vec3 ni = Normalize(Interpolate(at.b0, u, v, Load3(s.normals + 3 * face[0]), Load3(s.normals + 3 * face[1]),
                                    Load3(s.normals + 3 * face[2])));
    if (!(ni.x == 0.0f && ni.y == 0.0f && ni.z == 0.0f)) at.nsh = ni * sign;
  }
  return at;
}

// `first ? a : b` and `keep ? x : 0.0f`, chosen bit by bit: both operands are used whichever is
// chosen, so GCC does not move the work of one (a division) into a branch of its own, which
// keeps a loop from vectorising (it will not divide where the source did not).
template <class Real>
inline Real Choose(bool first, Real a, Real b) {
  using Bits = std::conditional_t<sizeof(Real) == 4, uint32_t, uint64_t>;
  Bits x, y;
  std::memcpy(&x, &a, sizeof x);
  std::memcpy(&y, &b, sizeof y);
  const Bits mask = Bits{0} - static_cast<Bits>(first);
  x = (x & mask) | (y & ~mask);
  Real r;
  std::memcpy(&r, &x, sizeof r);
  return r;
}
inline float KeepWhere(bool keep, float x) { return Choose(keep, x, 0.0f); }

// Normalize, its reciprocal computed for every vector and kept where the length is not 0: the
// same values, with no branch.
inline Vec3 NormalizeEither(Vec3 v) {
  const float n2 = Dot(v, v);
  const float inv = 1.0f / std::sqrt(n2);
  return v * KeepWhere(n2 > 0.0f, inv);
}

// The specular power without libm, in double so that rounding to float gives glibc's value but
// in rare cases. log2(x) for a float x > 0 (finite): x = 2^e·m with m in [√½, √2), and
// log2 m = (2/ln 2)·atanh(s), s = (m − 1)/(m + 1), |s| ≤ 0.1716, by its series to s^13.
inline double Log2Of(float x) {
  const bool tiny = x < 1.17549435e-38f;  // a subnormal: scaled by 2^24 (exactly) first
  const float scaled = Choose(tiny, x * 16777216.0f, x);
  uint32_t bits;
  std::memcpy(&bits, &scaled, sizeof bits);
  const int32_t e = static_cast<int32_t>(bits >> 23) - 127 - 24 * static_cast<int32_t>(tiny);
  const uint32_t mant_bits = (bits & 0x7fffffu) | 0x3f800000u;
  float mf;
  std::memcpy(&mf, &mant_bits, sizeof mf);
  const bool high = mf > 1.41421356f;
  const double m = Choose(high, 0.5 * static_cast<double>(mf), static_cast<double>(mf));
  const double s = (m - 1.0) / (m + 1.0), s2 = s * s;
  constexpr double c = 2.0 / 0.693147180559945309417232121458;  // 2 / ln 2
  const double series =
      1.0 + s2 * (1.0 / 3 + s2 * (1.0 / 5 + s2 * (1.0 / 7 + s2 * (1.0 / 9 + s2 * (1.0 / 11 + s2 * (1.0 / 13))))));
  return static_cast<double>(e + static_cast<int32_t>(high)) + c * s * series;
}
// 2^y for a double y (|y| < 2^50; beyond ±1000 the float result is 0 or infinity anyway):
// 2^y = 2^n · 2^r, n the nearest integer, |r| ≤ ½, 2^r = e^(r ln 2) by its Taylor series to r^11.
inline double Exp2Of(double y) {
  const double yc = Choose(y < -1000.0, -1000.0, Choose(y > 1000.0, 1000.0, y));
  constexpr double kShift = 6755399441055744.0 + 1023.0;  // 1.5·2^52 + the exponent bias
  const double t = yc + kShift;  // rounded to an integer: its low bits hold n + 1023
  const double n = t - kShift;
  const double r = yc - n;
  uint64_t tb;
  std::memcpy(&tb, &t, sizeof tb);
  const uint64_t scale_bits = (tb & 0x7ffull) << 52;
  double scale;
  std::memcpy(&scale, &scale_bits, sizeof scale);
  constexpr double l = 0.693147180559945309417232121458;
  constexpr double c1 = l, c2 = c1 * l / 2, c3 = c2 * l / 3, c4 = c3 * l / 4, c5 = c4 * l / 5, c6 = c5 * l / 6,
                   c7 = c6 * l / 7, c8 = c7 * l / 8, c9 = c8 * l / 9, c10 = c9 * l / 10, c11 = c10 * l / 11;
  const double high_terms = c6 + r * (c7 + r * (c8 + r * (c9 + r * (c10 + r * c11))));
  const double p = 1.0 + r * (c1 + r * (c2 + r * (c3 + r * (c4 + r * (c5 + r * high_terms)))));
  return p * scale;  // (a NaN y gives NaN: every step keeps it)
}
// std::exp2(y * std::log2(x)) for x > 0, each function correctly rounded to float but in rare
// cases (glibc's are too: the two differ by 1 ulp in about 1 of 5,000 logarithms and 1 of 10,000
// powers of 2): GCC vectorises these, where it calls libm once per ray for those.
inline float PowOf(float x, float y) {
  const float lg = static_cast<float>(Log2Of(x));
  return static_cast<float>(Exp2Of(static_cast<double>(y * lg)));
}

// The three floats from base[j] (`Index` int32_t: GCC 12 gathers them with 32-bit indices, not
// with 64-bit ones).
template <class Index>
inline Vec3 Gather3(const float* base, Index j) {
  return {base[j], base[j + 1], base[j + 2]};
}

// SurfaceAt for the rays k < m, into 12 planes of m floats (the point, the geometric and the
// shading normal, each x, y, z; then b0, u, v): the same arithmetic in the same order, written
// without branches (both sides of a choice computed, one kept) so that GCC vectorises the loop,
// gathering the faces' vertices 16 rays at a time where the scalar loop waited on each ray's.
// `face`: each ray's face (a miss's: any face that was hit; its surface is never read).
template <bool kRecompute, bool kNormals, class Index>
FOVJAX_VECTOR_CLONES void SurfacePlanes(const float* __restrict__ vertices, const int32_t* __restrict__ faces,
                                        const float* __restrict__ normals, const int32_t* __restrict__ face,
                                        const float* __restrict__ o, const float* __restrict__ d,
                                        const float* __restrict__ u_in, const float* __restrict__ v_in, int64_t m,
                                        float* __restrict__ px, float* __restrict__ py, float* __restrict__ pz,
                                        float* __restrict__ gx, float* __restrict__ gy, float* __restrict__ gz,
                                        float* __restrict__ nx, float* __restrict__ ny, float* __restrict__ nz,
                                        float* __restrict__ b0_out, float* __restrict__ u_out,
                                        float* __restrict__ v_out) {
  for (int64_t k = 0; k < m; ++k) {
    const Index f = face[k];
    const Index j0 = 3 * faces[3 * f], j1 = 3 * faces[3 * f + 1], j2 = 3 * faces[3 * f + 2];
    const Vec3 c0 = Gather3(vertices, j0), c1 = Gather3(vertices, j1), c2 = Gather3(vertices, j2);
    const Vec3 dk = Load3(d + 3 * k);
    float u = u_in[k], v = v_in[k];
    if constexpr (kRecompute) {
      const Vec3 e1 = c1 - c0, e2 = c2 - c0;
      const Vec3 pvec = Cross(dk, e2);
      const float det = Dot(e1, pvec);
      const float inv_det = 1.0f / det;
      const Vec3 tvec = Load3(o + 3 * k) - c0;
      const Vec3 qvec = Cross(tvec, e1);
      const float uu = Dot(tvec, pvec) * inv_det, vv = Dot(dk, qvec) * inv_det;
      u = det != 0.0f ? uu : 0.0f;
      v = det != 0.0f ? vv : 0.0f;
    }
    const float b0 = 1.0f - u - v;
    const Vec3 p = Interpolate(b0, u, v, c0, c1, c2);
    const Vec3 ng = NormalizeEither(Cross(c1 - c0, c2 - c0));
    const float sign = Dot(ng, dk) > 0.0f ? -1.0f : 1.0f;
    const Vec3 g = ng * sign;
    Vec3 n = g;
    if constexpr (kNormals) {
      const Vec3 ni =
          NormalizeEither(Interpolate(b0, u, v, Gather3(normals, j0), Gather3(normals, j1), Gather3(normals, j2)));
      const bool zero = ni.x == 0.0f && ni.y == 0.0f && ni.z == 0.0f;
      const Vec3 ns = ni * sign;
      n = {zero ? g.x : ns.x, zero ? g.y : ns.y, zero ? g.z : ns.z};
    }
    px[k] = p.x, py[k] = p.y, pz[k] = p.z;
    gx[k] = g.x, gy[k] = g.y, gz[k] = g.z;
    nx[k] = n.x, ny[k] = n.y, nz[k] = n.z;
    b0_out[k] = b0, u_out[k] = u, v_out[k] = v;
  }
}

// `SurfacePlanes` for the options of `s`: 32-bit indices where three times the number of
// vertices and of faces fits in them, 64-bit ones (a loop GCC leaves scalar) otherwise.
void Surfaces(const ShadeScene& s, const int32_t* face, const float* o, const float* d, const float* u,
              const float* v, int64_t m, float* out) {
  const bool narrow = 3 * std::max(s.num_vertices, s.num_faces) < (int64_t{1} << 31);
  const bool normals = s.normals != nullptr;
  // (each plane its own restrict parameter: GCC vectorises the loop only where it knows the
  // planes apart without a check at run time per pair)
  auto run = [&](auto planes) {
    planes(s.vertices, s.faces, s.normals, face, o, d, u, v, m, out, out + m, out + 2 * m, out + 3 * m,
           out + 4 * m, out + 5 * m, out + 6 * m, out + 7 * m, out + 8 * m, out + 9 * m, out + 10 * m, out + 11 * m);
  };
  if (narrow) {
    if (s.recompute && normals) return run(SurfacePlanes<true, true, int32_t>);
    if (s.recompute) return run(SurfacePlanes<true, false, int32_t>);
    if (normals) return run(SurfacePlanes<false, true, int32_t>);
    return run(SurfacePlanes<false, false, int32_t>);
  }
  if (s.recompute && normals) return run(SurfacePlanes<true, true, int64_t>);
  if (s.recompute) return run(SurfacePlanes<true, false, int64_t>);
  if (normals) return run(SurfacePlanes<false, true, int64_t>);
  run(SurfacePlanes<false, false, int64_t>);
}

// `LightTowards` for one light and the hits k < m at once, and what the shadow rays and the
// shading read of it, each into a plane of m floats: the direction towards the light (x, y, z),
// n·l, the far end of its shadow ray (the distance, or INFINITY for a directional light), the
// spot factor, the specular factor (Blinn–Phong's (n·h)^Ns, Phong's (r·v)^Ns, 0 where the cosine
// is not positive; Ns the hit's material's) and whether the light is wanted (n·l > 0, n_g·l > 0,
// spot > 0: 1, else 0). The same arithmetic in the same order as `LightTowards` and the shading
// did it (the power `PowOf`'s, not libm's), without branches, so that GCC vectorises it: the
// loops that read the planes do no light arithmetic of their own (they did it twice per hit,
// one ray at a time).
constexpr int kLightPlanes = 7;  // float planes per light: dir x, y, z, n·l, far, spot, specular

template <bool kPositional, bool kSpot, bool kPhong>
FOVJAX_VECTOR_CLONES void LightPlanes(const float* __restrict__ row, const float* __restrict__ materials,
                                      const int32_t* __restrict__ material, const float* __restrict__ px,
                                      const float* __restrict__ py, const float* __restrict__ pz,
                                      const float* __restrict__ gx, const float* __restrict__ gy,
                                      const float* __restrict__ gz, const float* __restrict__ nx,
                                      const float* __restrict__ ny, const float* __restrict__ nz,
                                      const float* __restrict__ d, int64_t m, float* __restrict__ dx,
                                      float* __restrict__ dy, float* __restrict__ dz,
                                      float* __restrict__ ndl_out, float* __restrict__ far_out,
                                      float* __restrict__ spot_out, float* __restrict__ spec_out,
                                      int32_t* __restrict__ wanted_out) {
  const Vec3 position = Load3(row), axis = Load3(row + 6);
  const float cos_inner = row[9], cos_outer = row[10];
  for (int64_t k = 0; k < m; ++k) {
    const Vec3 p{px[k], py[k], pz[k]}, ng{gx[k], gy[k], gz[k]}, nsh{nx[k], ny[k], nz[k]};
    const Vec3 to_light = kPositional ? position - p : position;
    const float n2 = Dot(to_light, to_light);
    const float root = std::sqrt(n2), inv = 1.0f / root;
    const Vec3 dir = to_light * KeepWhere(n2 > 0.0f, inv);  // Normalize
    float spot = 1.0f;
    if constexpr (kSpot) {
      const float c = -Dot(axis, dir);
      const float ramp = (c - cos_outer) / (cos_inner - cos_outer);
      spot = Choose(c >= cos_inner, 1.0f, KeepWhere(c > cos_outer, ramp));
    }
    const float ndl = Dot(nsh, dir);
    const Vec3 dk = Load3(d + 3 * k);
    float cosine;
    if constexpr (kPhong) {  // r·v, r the light's direction mirrored about n, v = -d
      const Vec3 mirrored = (2.0f * ndl) * nsh - dir;
      cosine = -Dot(mirrored, dk);
    } else {
      cosine = Dot(nsh, NormalizeEither(dir - dk));
    }
    dx[k] = dir.x, dy[k] = dir.y, dz[k] = dir.z;
    ndl_out[k] = ndl;
    far_out[k] = kPositional ? (n2 > 0.0f ? root : 0.0f) : INFINITY;
    spot_out[k] = spot;
    const float shininess = materials[kMaterialStride * material[k] + 15];
    spec_out[k] = KeepWhere(cosine > 0.0f, PowOf(cosine, shininess));  // (n·h)^Ns or (r·v)^Ns
    wanted_out[k] = (ndl > 0.0f) & (Dot(ng, dir) > 0.0f) & (spot > 0.0f);
  }
}

// `LightPlanes` for light l of `s` into out (kLightPlanes planes of m floats) and wanted.
void Lights(const ShadeScene& s, int l, const float* surface, const float* d, const int32_t* material,
            int64_t m, float* out, int32_t* wanted) {
  const int32_t kind = s.light_kind[l];
  const bool spot = s.spots && kind == kLightSpot;
  const bool positional = kind == kLightPoint || spot;
  const bool phong = s.shading.specular == kSpecularPhong;
  auto run = [&](auto planes) {
    const float* a = surface;
    planes(s.lights + kLightStride * l, s.materials, material, a, a + m, a + 2 * m, a + 3 * m, a + 4 * m,
           a + 5 * m, a + 6 * m, a + 7 * m, a + 8 * m, d, m, out, out + m, out + 2 * m, out + 3 * m,
           out + 4 * m, out + 5 * m, out + 6 * m, wanted);
  };
  if (phong) {
    if (spot) return run(LightPlanes<true, true, true>);
    if (positional) return run(LightPlanes<true, false, true>);
    return run(LightPlanes<false, false, true>);
  }
  if (spot) return run(LightPlanes<true, true, false>);
  if (positional) return run(LightPlanes<true, false, false>);
  run(LightPlanes<false, false, false>);
}

// The texture's factor on Kd at a hit into `factor`, and whether material `mat` has one.
inline __attribute__((always_inline)) bool TextureAt(const ShadeScene& s, int32_t mat, const int32_t* face,
                                                     const Surface& at, Vec3* factor) {
  if (s.textures.empty()) return false;
  const int32_t ti = s.texture[mat];
  if (!(ti >= 0 && ti < static_cast<int32_t>(s.textures.size()))) return false;
  float tu = 0.0f, tv = 0.0f;
  if (s.uvs != nullptr) {
    const float* a = s.uvs + 2 * face[0];
    const float* bb = s.uvs + 2 * face[1];
    const float* c = s.uvs + 2 * face[2];
    tu = a[0] * at.b0 + bb[0] * at.u + c[0] * at.v;
    tv = a[1] * at.b0 + bb[1] * at.u + c[1] * at.v;
  }
  *factor = Bilinear(s.textures[ti], tu, tv);
  return true;
}

// One block's work buffers, kept per thread across blocks and calls.
struct WhittedBuffers {
  std::vector<float> o, d, weight, tmin, tmax, t, u, v;
  std::vector<int32_t> prim, face, pixel, column, cls, level;
  std::vector<float> kd, surface, light;
  std::vector<int32_t> material, wanted;
  std::vector<float> so, sd, stmin, stmax, st, su, sv;
  std::vector<int32_t> sprim, slevel;
  void Reserve(int64_t n, int lights, bool classes) {
    for (auto* x : {&o, &d, &weight, &kd}) x->resize(3 * n);
    for (auto* x : {&tmin, &tmax, &t, &u, &v}) x->resize(n);
    surface.resize(12 * n);
    light.resize(kLightPlanes * n * lights);
    wanted.resize(n * lights);
    prim.resize(n);
    face.resize(n);
    pixel.resize(n);
    column.resize(n);
    material.resize(n);
    const int64_t ns = n * std::max(lights, 1);
    for (auto* x : {&so, &sd}) x->resize(3 * ns);
    for (auto* x : {&stmin, &stmax, &st, &su, &sv}) x->resize(ns);
    sprim.resize(ns);
    if (classes) {
      cls.resize(n);
      level.resize(n);
      slevel.resize(ns);
    }
  }
};

// Rays [begin, end): each active ray's radiance into total (3 per ray) and, in `traced`, the
// shadow rays (bits 8 and up) and reflection rays (bits 0-7) its path traced.
// Which rays a block holds: a run [begin, begin + n) of the batch, or (width > 0) 4 rows ×
// `cols` columns of an image `width` rays wide from (row0, col0), taken 4×4 tile by tile, so
// that each 16-ray packet is a square of neighbouring pixels (a row strip of 16 spans four
// times the angle, and its traversal visits more nodes).
struct BlockRays {
  int64_t begin = 0, n = 0;
  int64_t width = 0, row0 = 0, col0 = 0;
  // Where non-null: each ray's primary hit point o + t·d (a miss: t = `miss_t`; inactive: 0),
  // indexed as `total` is, 3 floats a ray (Weier's points: `traced_sums`' first_points).
  float* primary_point = nullptr;
  float miss_t = 0.0f;
  int64_t Index(int64_t i) const {
    if (width == 0) return begin + i;
    const int64_t tile = i / 16, within = i % 16;
    return (row0 + within / 4) * width + col0 + 4 * tile + within % 4;
  }
};

// Where a block writes each ray's path (`paths` non-null): per depth level k and the block's ray
// i, at k·n + column[i] (column null: i), the face its ray hit (-1: a miss) and the lights its
// shadow rays reached (bit l set: light l was wanted there and unblocked). The caller fills the
// arrays with kPathNotTraced and 0 first: levels a ray never reached keep them. What the
// derivatives replay (fovjax/render/_replay.py) without tracing a ray.
struct PathsOut {
  int32_t* prim;
  uint32_t* visible;
  int64_t n;               // columns per level
  int64_t levels;          // max_depth + 1
  const int32_t* column;   // the block's rays' columns, or null
  void Clear() const {
    std::fill(prim, prim + levels * n, kPathNotTraced);
    std::fill(visible, visible + levels * n, 0u);
  }
};

// `sparse`: the rays are samples scattered over the screen (a foveated frame's), whose hits'
// faces and vertices are seldom in the cache from a neighbour's: they are prefetched a few rays
// ahead of the shading (a full frame's neighbouring rays share their faces: it gains nothing).
// `kClasses`: each ray's class in `ray_class` (indexed as the rays), its fidelity the tables' of
// `s` (`ShadingClasses`); without, the loop has none of their work (`WhittedBlock` picks).
// `kPlain`: no spot light, Blinn–Phong without the payload, no cut-off, no stored paths: the
// loop has none of those options' work.
template <bool kClasses, bool kPlain>
void WhittedRays(const NativeScene& tree, const ShadeScene& s, const float* o_in, const float* d_in,
                 const bool* active, const BlockRays& block, float* total, int32_t* traced, bool packets,
                 bool sparse, const PathsOut* paths, const int32_t* ray_class) {
  WhittedBuffers& b = ThreadLocal<WhittedBuffers>();
  const int64_t n = block.n;
  const int nl = s.num_lights;
  b.Reserve(n, nl, kClasses);
  const bool levels = kClasses && s.class_level != nullptr;  // rays traced against their class's tree
  int64_t m = 0;
  for (int64_t i = 0; i < n; ++i) {
    const int64_t g = block.Index(i);
    total[3 * g] = total[3 * g + 1] = total[3 * g + 2] = 0.0f;
    traced[g] = 0;
    if (block.primary_point != nullptr) std::fill(block.primary_point + 3 * g, block.primary_point + 3 * g + 3, 0.0f);
    if (!active[g]) continue;
    b.pixel[m] = static_cast<int32_t>(g);
    if constexpr (!kPlain) {
      b.column[m] = paths == nullptr ? 0 : static_cast<int32_t>(paths->column ? paths->column[i] : g);
    }
    if constexpr (kClasses) {
      b.cls[m] = ClassIndex(s, ray_class[g]);
      if (levels) b.level[m] = s.class_level[b.cls[m]];
    }
    for (int c = 0; c < 3; ++c) {
      b.o[3 * m + c] = o_in[3 * g + c];
      b.d[3 * m + c] = d_in[3 * g + c];
      b.weight[3 * m + c] = 1.0f;
    }
    ++m;
  }
  for (int depth = 0; m > 0; ++depth) {
    const bool spawn = depth < s.max_depth;
    for (int64_t k = 0; k < m; ++k) {
      b.tmin[k] = 0.0f;
      b.tmax[k] = INFINITY;
    }
    Rays rays{b.o.data(), b.d.data(), b.tmin.data(), b.tmax.data(), levels ? b.level.data() : nullptr,
              b.t.data(), b.prim.data(), b.u.data(), b.v.data()};
    TraceList(tree, rays, m, false, packets);
    if (depth == 0 && block.primary_point != nullptr) {
      for (int64_t k = 0; k < m; ++k) {
        const float t = b.prim[k] >= 0 ? b.t[k] : block.miss_t;
        float* p = block.primary_point + 3 * static_cast<int64_t>(b.pixel[k]);
        for (int c = 0; c < 3; ++c) p[c] = b.o[3 * k + c] + t * b.d[3 * k + c];
      }
    }
    if (!kPlain && paths != nullptr) {
      for (int64_t k = 0; k < m; ++k) {
        paths->prim[depth * paths->n + b.column[k]] = b.prim[k] < 0 ? -1 : b.prim[k];
      }
    }
    // Surfaces and their shadow rays: the hits' faces checked, their surfaces, then the rays.
    int64_t ns = 0, hits = 0;
    int32_t any_face = 0, any_material = 0;
    for (int64_t k = 0; k < m; ++k) {
      b.face[k] = -1;
      if (sparse) {  // the faces and vertices of hits a few rays ahead: see WhittedBlock
        constexpr int64_t kAhead = 8;
        if (k + 2 * kAhead < m && b.prim[k + 2 * kAhead] >= 0) {
          const int64_t f2 = std::min<int64_t>(b.prim[k + 2 * kAhead], s.num_faces - 1);
          __builtin_prefetch(s.faces + 3 * f2);
          __builtin_prefetch(s.face_material + f2);
        }
        if (k + kAhead < m && b.prim[k + kAhead] >= 0) {
          const int32_t* fa = s.faces + 3 * std::min<int64_t>(b.prim[k + kAhead], s.num_faces - 1);
          for (int j = 0; j < 3; ++j) {
            __builtin_prefetch(s.vertices + 3 * static_cast<int64_t>(fa[j]));
            if (s.normals != nullptr) __builtin_prefetch(s.normals + 3 * static_cast<int64_t>(fa[j]));
          }
        }
      }
      if (b.prim[k] < 0) continue;
      const int64_t f = std::min<int64_t>(b.prim[k], s.num_faces - 1);
      const int32_t* face = s.faces + 3 * f;
      const int32_t mat = s.face_material[f];
      if (face[0] < 0 || face[0] >= s.num_vertices || face[1] < 0 || face[1] >= s.num_vertices ||
          face[2] < 0 || face[2] >= s.num_vertices || mat < 0 || mat >= s.num_materials) {
        s.out_of_range->store(1);
        b.prim[k] = -1;  // shaded as a miss; the call returns an error
        continue;
      }
      b.face[k] = any_face = static_cast<int32_t>(f);
      b.material[k] = any_material = mat;
      ++hits;
    }
    // The hits' surfaces and their lights (a miss's lanes compute a hit's face's, unread).
    const float* planes = b.surface.data();
    const float* light = b.light.data();  // light l's planes from light + kLightPlanes * m * l
    const int32_t* wanted = b.wanted.data();  // light l's from wanted + m * l
    if (hits > 0) {
      for (int64_t k = 0; k < m; ++k) {
        if (b.face[k] < 0) b.face[k] = any_face, b.material[k] = any_material;
      }
      Surfaces(s, b.face.data(), b.o.data(), b.d.data(), b.u.data(), b.v.data(), m, b.surface.data());
      for (int l = 0; l < nl; ++l) {
        Lights(s, l, planes, b.d.data(), b.material.data(), m, b.light.data() + kLightPlanes * m * l,
               b.wanted.data() + m * l);
      }
    }
    for (int64_t k = 0; k < m; ++k) {
      if (b.prim[k] < 0) continue;
      const int32_t* face = s.faces + 3 * static_cast<int64_t>(b.face[k]);  // (checked above)
      const int32_t mat = b.material[k];  // (not the face's again: a load from memory per hit)
      Surface at;
      at.b0 = planes[9 * m + k], at.u = planes[10 * m + k], at.v = planes[11 * m + k];
      Vec3 kd = Load3(s.materials + kMaterialStride * mat + 3);
      Vec3 texture;
      if (TextureAt(s, mat, face, at, &texture)) kd = kd * texture;
      for (int c = 0; c < 3; ++c) b.kd[3 * k + c] = (&kd.x)[c];
      const Vec3 p{planes[k], planes[m + k], planes[2 * m + k]};
      const Vec3 ng{planes[3 * m + k], planes[4 * m + k], planes[5 * m + k]};
      const Vec3 origin = p + s.offset * ng;
      for (int l = 0; l < nl; ++l) {
        if (!wanted[m * l + k]) continue;
        if constexpr (kClasses) {
          if (!Tested(s, b.cls[k], l)) continue;  // no ray: the light shines unshadowed
        }
        const float* lp = light + kLightPlanes * m * l;
        const int64_t j = ns++;
        if constexpr (kClasses) {
          if (levels) b.slevel[j] = b.level[k];
        }
        for (int c = 0; c < 3; ++c) {
          b.so[3 * j + c] = (&origin.x)[c];
          b.sd[3 * j + c] = lp[c * m + k];
        }
        b.stmin[j] = 0.0f;
        b.stmax[j] = lp[4 * m + k];
      }
    }
    Rays shadow{b.so.data(), b.sd.data(), b.stmin.data(), b.stmax.data(), levels ? b.slevel.data() : nullptr,
                b.st.data(), b.sprim.data(), b.su.data(), b.sv.data()};
    TraceList(tree, shadow, ns, true, packets);
    // Shading, and the reflection rays compacted to the front.
    int64_t next = 0, js = 0;
    for (int64_t k = 0; k < m; ++k) {
      const int32_t px = b.pixel[k];
      Vec3 d = Load3(&b.d[3 * k]);
      Vec3 w = Load3(&b.weight[3 * k]);
      float* out = total + 3 * static_cast<int64_t>(px);
      if (b.prim[k] < 0) {
        Vec3 c = w * Environment(s.environment, d);
        out[0] += c.x;
        out[1] += c.y;
        out[2] += c.z;
        continue;
      }
      const float* row = s.materials + kMaterialStride * b.material[k];
      Vec3 ka = Load3(row), ks = Load3(row + 6), ke = Load3(row + 9), kr = Load3(row + 12);
      const Vec3 p{planes[k], planes[m + k], planes[2 * m + k]};
      const Vec3 ng{planes[3 * m + k], planes[4 * m + k], planes[5 * m + k]};
      const Vec3 nsh{planes[6 * m + k], planes[7 * m + k], planes[8 * m + k]};
      Vec3 local = ka * s.ambient + ke;
      if (nl > 0) {
        Vec3 kd = Load3(&b.kd[3 * k]);
        Vec3 sum{0.0f, 0.0f, 0.0f};
        bool first = true;
        for (int l = 0; l < nl; ++l) {
          if (!wanted[m * l + k]) continue;  // not wanted: no ray, no light
          const float* lp = light + kLightPlanes * m * l;
          if (!kClasses || Tested(s, b.cls[k], l)) {  // else no ray: unshadowed
            const int64_t j = js++;
            traced[px] += 1 << 8;
            if (b.sprim[j] >= 0) continue;  // blocked
          }
          const float n_dot_l = lp[3 * m + k], spot = lp[5 * m + k];
          if (!kPlain && paths != nullptr) paths->visible[depth * paths->n + b.column[k]] |= 1u << l;
          float spec = lp[6 * m + k];  // (n·h)^Ns, or Phong's (r·v)^Ns
          if (!kPlain && s.shading.payload) spec = spec * n_dot_l;  // §4.4.3's shadow payload, n·l
          Vec3 color = Load3(s.lights + kLightStride * l + 3) * spot;
          Vec3 term = (kd * n_dot_l + ks * spec) * color;
          sum = first ? term : sum + term;
          first = false;
        }
        local = local + sum;
      }
      Vec3 c = w * local;
      out[0] += c.x;
      out[1] += c.y;
      out[2] += c.z;
      w = w * kr;
      if (!(spawn && (w.x != 0.0f || w.y != 0.0f || w.z != 0.0f))) continue;
      if constexpr (kClasses) {
        if (!(depth < s.class_depth[b.cls[k]])) continue;  // the class's reflection depth
      }
      const float cut = kPlain ? 0.0f : s.shading.min_contribution;  // §2.5.2's contribution cut-off
      if (cut > 0.0f && !(0.30f * w.x + 0.59f * w.y + 0.11f * w.z >= cut)) continue;
      Vec3 reflected = d - 2.0f * Dot(d, nsh) * nsh;
      if (Dot(reflected, ng) <= 0.0f) reflected = d - 2.0f * Dot(d, ng) * ng;
      Vec3 o2 = p + s.offset * ng, d2 = Normalize(reflected);
      for (int c2 = 0; c2 < 3; ++c2) {
        b.o[3 * next + c2] = (&o2.x)[c2];
        b.d[3 * next + c2] = (&d2.x)[c2];
        b.weight[3 * next + c2] = (&w.x)[c2];
      }
      b.pixel[next] = px;
      if constexpr (!kPlain) b.column[next] = b.column[k];
      if constexpr (kClasses) {
        b.cls[next] = b.cls[k];
        if (levels) b.level[next] = b.level[k];
      }
      traced[px] += 1;
      ++next;
    }
    m = next;
  }
}

// `WhittedRays` with each ray's class in `ray_class` where `s` has class tables, else at full
// fidelity (without the options' work where none is asked for).
void WhittedBlock(const NativeScene& tree, const ShadeScene& s, const float* o_in, const float* d_in,
                  const bool* active, const BlockRays& block, float* total, int32_t* traced,
                  bool packets, bool sparse, const PathsOut* paths = nullptr,
                  const int32_t* ray_class = nullptr) {
  if (s.class_depth != nullptr && ray_class != nullptr) {
    WhittedRays<true, false>(tree, s, o_in, d_in, active, block, total, traced, packets, sparse, paths,
                             ray_class);
  } else if (paths == nullptr && !s.spots && s.shading.specular == kSpecularBlinnPhong && !s.shading.payload &&
             s.shading.min_contribution == 0.0f) {
    // The thesis's frame: none of the options' work (the same arithmetic: a spot factor of 1).
    WhittedRays<false, true>(tree, s, o_in, d_in, active, block, total, traced, packets, sparse, nullptr,
                             nullptr);
  } else {
    WhittedRays<false, false>(tree, s, o_in, d_in, active, block, total, traced, packets, sparse, paths,
                              nullptr);
  }
}

// The class tables of `ShadingClasses` (max_depth, shadows, level: int32 (K,), level empty for
// none; all three empty: no classes) into `s`, after `SceneFrom` (the brightest light is read
// from its lights).
ffi::Error ClassesFrom(ffi::Buffer<ffi::S32> depth, ffi::Buffer<ffi::S32> shadows, ffi::Buffer<ffi::S32> level,
                       ShadeScene* s) {
  const size_t k = depth.element_count();
  if (shadows.element_count() != k || (level.element_count() != 0 && level.element_count() != k) ||
      (k == 0 && level.element_count() != 0) || k > (size_t{1} << 30)) {
    return ffi::Error::InvalidArgument(
        "fovjax Whitted: class tables (max_depth, shadows, level) of different lengths");
  }
  if (k == 0) return ffi::Error::Success();
  s->class_depth = depth.typed_data();
  s->class_shadows = shadows.typed_data();
  s->class_level = level.element_count() ? level.typed_data() : nullptr;
  s->num_classes = static_cast<int32_t>(k);
  // jnp.argmax of the colours' sums: the first of equal sums, the first NaN above all.
  s->brightest = 0;
  float best = 0.0f;
  for (int l = 0; l < s->num_lights; ++l) {
    const float* c = s->lights + kLightStride * l + 3;
    const float sum = c[0] + c[1] + c[2];
    if (l == 0 || (!std::isnan(best) && (std::isnan(sum) || sum > best))) {
      best = sum;
      s->brightest = l;
    }
  }
  return ffi::Error::Success();
}

// The Whitted handlers' scene operands (`whitted_operands`), checked, as a ShadeScene and its
// Embree trees.
#define FOVJAX_SCENE_PARAMS                                                                          \
  ffi::Buffer<ffi::S32> scene_id, ffi::Buffer<ffi::F32> bvh_vertices, ffi::Buffer<ffi::S32> bvh_faces, \
      ffi::Buffer<ffi::S32> first_face, ffi::Buffer<ffi::F32> vertices, ffi::Buffer<ffi::S32> faces,   \
      ffi::Buffer<ffi::S32> face_material, ffi::Buffer<ffi::F32> normals, ffi::Buffer<ffi::F32> uvs,   \
      ffi::Buffer<ffi::F32> materials, ffi::Buffer<ffi::S32> texture, ffi::Buffer<ffi::F32> texels,    \
      ffi::Buffer<ffi::S32> texture_shape, ffi::Buffer<ffi::F32> lights,                              \
      ffi::Buffer<ffi::S32> light_kind, ffi::Buffer<ffi::F32> ambient,                                \
      ffi::Buffer<ffi::F32> environment, ffi::Buffer<ffi::F32> offset
#define FOVJAX_SCENE_ARGS                                                                            \
  scene_id, bvh_vertices, bvh_faces, first_face, vertices, faces, face_material, normals, uvs,        \
      materials, texture, texels, texture_shape, lights, light_kind, ambient, environment, offset

ffi::Error SceneFrom(FOVJAX_SCENE_PARAMS, int32_t max_depth, int32_t recompute, int32_t robust,
                     Shading shading, std::atomic<int>* out_of_range, ShadeScene* scene,
                     std::shared_ptr<NativeScene>* tree_out) {
  ShadeScene& s = *scene;
  const int64_t nv = static_cast<int64_t>(vertices.element_count() / 3);
  const int64_t nf = static_cast<int64_t>(faces.element_count() / 3);
  const int64_t nm = static_cast<int64_t>(texture.element_count());
  const int64_t nl = static_cast<int64_t>(light_kind.element_count());
  auto env_dims = environment.dimensions();
  if (nf < 1 || face_material.element_count() != static_cast<size_t>(nf) ||
      (normals.element_count() != 0 && normals.element_count() != 3 * static_cast<size_t>(nv)) ||
      (uvs.element_count() != 0 && uvs.element_count() != 2 * static_cast<size_t>(nv)) ||
      materials.element_count() != kMaterialStride * static_cast<size_t>(nm) || nm < 1 ||
      lights.element_count() != kLightStride * static_cast<size_t>(nl) || ambient.element_count() != 3 ||
      env_dims.size() != 3 || env_dims[2] != 3 || env_dims[0] < 1 || env_dims[1] < 1 ||
      offset.element_count() != 1 || texture_shape.element_count() % 2 != 0 ||
      scene_id.element_count() != 1 || first_face.element_count() < 2) {
    return ffi::Error::InvalidArgument("fovjax Whitted: scene arrays of unexpected shapes");
  }
  // Faces and their materials are checked where a ray hits them, not in a pass over every face
  // on every call.
  s.num_vertices = nv;
  s.out_of_range = out_of_range;
  s.vertices = vertices.typed_data();
  s.faces = faces.typed_data();
  s.face_material = face_material.typed_data();
  s.num_faces = nf;
  s.normals = normals.element_count() ? normals.typed_data() : nullptr;
  s.uvs = uvs.element_count() ? uvs.typed_data() : nullptr;
  s.materials = materials.typed_data();
  s.texture = texture.typed_data();
  s.num_materials = nm;
  int64_t used = 0;
  const int64_t nt = static_cast<int64_t>(texture_shape.element_count() / 2);
  for (int64_t i = 0; i < nt; ++i) {
    int64_t h = texture_shape.typed_data()[2 * i], w = texture_shape.typed_data()[2 * i + 1];
    if (h < 1 || w < 1 || used + 3 * h * w > static_cast<int64_t>(texels.element_count())) {
      return ffi::Error::InvalidArgument("fovjax Whitted: texture shapes do not match the texels");
    }
    s.textures.push_back(Texture{texels.typed_data() + used, h, w});
    used += 3 * h * w;
  }
  s.lights = lights.typed_data();
  s.light_kind = light_kind.typed_data();
  s.num_lights = static_cast<int>(nl);
  s.spots = std::any_of(s.light_kind, s.light_kind + nl, [](int32_t kind) { return kind == kLightSpot; });
  s.ambient = Load3(ambient.typed_data());
  s.environment = Texture{environment.typed_data(), env_dims[0], env_dims[1]};
  s.offset = offset.typed_data()[0];
  s.max_depth = max_depth;
  s.recompute = recompute != 0;
  if ((shading.specular != kSpecularBlinnPhong && shading.specular != kSpecularPhong) ||
      !(shading.min_contribution >= 0.0f)) {
    return ffi::Error::InvalidArgument("fovjax Whitted: unknown specular term or a negative cut-off");
  }
  s.shading = shading;
  std::string error;
  *tree_out = GetScene(scene_id.typed_data()[0], robust != 0, bvh_vertices.typed_data(),
                       static_cast<int64_t>(bvh_vertices.element_count() / 3), bvh_faces.typed_data(),
                       static_cast<int64_t>(bvh_faces.element_count() / 3), first_face.typed_data(),
                       static_cast<int64_t>(first_face.element_count()), &error);
  if (!*tree_out) return ffi::Error::InvalidArgument("fovjax Embree scene: " + error);
  return ffi::Error::Success();
}

// A handler's scene: `SceneFrom`'s shading scene and Embree trees, and the flag its rays raise
// where a hit face names a vertex or a material out of range (`Checked` then fails the call).
struct HandlerScene {
  std::atomic<int> out_of_range{0};
  ShadeScene s;
  std::shared_ptr<NativeScene> tree;
  ffi::Error Load(FOVJAX_SCENE_PARAMS, int32_t max_depth, int32_t recompute, int32_t robust, Shading shading) {
    return SceneFrom(FOVJAX_SCENE_ARGS, max_depth, recompute, robust, shading, &out_of_range, &s, &tree);
  }
  ffi::Error Checked(const char* message) const {
    return out_of_range.load() == 0 ? ffi::Error::Success() : ffi::Error::InvalidArgument(message);
  }
};

constexpr const char* kFaceOutOfRange = "fovjax Whitted: a hit face names a vertex or a material out of range";

ffi::Error Whitted(ffi::ThreadPool pool, ffi::Buffer<ffi::F32> origins, ffi::Buffer<ffi::F32> directions,
                   ffi::Buffer<ffi::PRED> active, FOVJAX_SCENE_PARAMS, ffi::ResultBuffer<ffi::F32> total,
                   ffi::ResultBuffer<ffi::S32> traced, ffi::ResultBuffer<ffi::S32> path_prim,
                   ffi::ResultBuffer<ffi::U32> path_visible, int32_t max_depth, int32_t recompute,
                   int32_t packets, int32_t tile_width, int32_t robust, int32_t specular,
                   int32_t specular_payload, float min_contribution) {
  if (g_device == nullptr) return ffi::Error::Internal("fovjax Embree backend used before init");
  const int64_t n = static_cast<int64_t>(active.element_count());
  if (origins.element_count() != 3 * static_cast<size_t>(n) ||
      directions.element_count() != 3 * static_cast<size_t>(n) ||
      total->element_count() != 3 * static_cast<size_t>(n) ||
      traced->element_count() != static_cast<size_t>(n)) {
    return ffi::Error::InvalidArgument("fovjax Whitted: ray arrays of different lengths");
  }
  // The paths (`PathsOut`): written where their buffers are not empty.
  const int64_t levels = static_cast<int64_t>(max_depth) + 1;
  const bool store = path_prim->element_count() != 0;
  if ((store && (path_prim->element_count() != static_cast<size_t>(levels * n) ||
                 path_visible->element_count() != static_cast<size_t>(levels * n) ||
                 light_kind.element_count() > 32)) ||
      (!store && path_visible->element_count() != 0)) {
    return ffi::Error::InvalidArgument(
        "fovjax Whitted: paths are (max_depth + 1) x rays, for at most 32 lights");
  }
  const PathsOut paths_out{path_prim->typed_data(), path_visible->typed_data(), n, levels, nullptr};
  const PathsOut* paths = store ? &paths_out : nullptr;
  if (paths != nullptr) paths->Clear();
  HandlerScene scene;
  const Shading shading{specular, specular_payload != 0, min_contribution};
  ffi::Error status = scene.Load(FOVJAX_SCENE_ARGS, max_depth, recompute, robust, shading);
  if (status.failure()) return status;
  const ShadeScene& s = scene.s;
  const NativeScene& t = *scene.tree;
  const float* o = origins.typed_data();
  const float* d = directions.typed_data();
  const bool* a = active.typed_data();
  float* out = total->typed_data();
  int32_t* counts = traced->typed_data();
  const int64_t per_block = 1024;
  const int64_t width = tile_width;
  if (width > 0 && width % 4 == 0 && n % (4 * width) == 0) {
    // Blocks of 4 rows × up to 256 columns, traced 4×4 tile by tile (`BlockRays`).
    const int64_t segments = (width + 255) / 256;
    ParallelFor(pool, (n / (4 * width)) * segments, [&](int64_t blk) {
      BlockRays block;
      block.width = width;
      block.row0 = 4 * (blk / segments);
      block.col0 = 256 * (blk % segments);
      block.n = 4 * std::min<int64_t>(256, width - block.col0);
      WhittedBlock(t, s, o, d, a, block, out, counts, packets != 0, false, paths);
    });
  } else {
    ParallelFor(pool, (n + per_block - 1) / per_block, [&](int64_t blk) {
      BlockRays block;
      block.begin = blk * per_block;
      block.n = std::min(n, (blk + 1) * per_block) - block.begin;
      WhittedBlock(t, s, o, d, a, block, out, counts, packets != 0, false, paths);
    });
  }
  return scene.Checked(kFaceOutOfRange);
}

}  // namespace

// The Whitted handlers' scene operands (`FOVJAX_SCENE_PARAMS`), appended to a binding.
template <typename Binding>
auto WithSceneArgs(Binding binding) {
  return std::move(binding)
      .template Arg<ffi::Buffer<ffi::S32>>()   // the BVH's host id (1)
      .template Arg<ffi::Buffer<ffi::F32>>()   // the BVH's vertices (V, 3)
      .template Arg<ffi::Buffer<ffi::S32>>()   // the BVH's faces (F, 3)
      .template Arg<ffi::Buffer<ffi::S32>>()   // first face of each tree, and F
      .template Arg<ffi::Buffer<ffi::F32>>()   // the scene's vertices (V, 3)
      .template Arg<ffi::Buffer<ffi::S32>>()   // faces (F, 3)
      .template Arg<ffi::Buffer<ffi::S32>>()   // face material (F)
      .template Arg<ffi::Buffer<ffi::F32>>()   // vertex normals (V, 3) or empty
      .template Arg<ffi::Buffer<ffi::F32>>()   // vertex uvs (V, 2) or empty
      .template Arg<ffi::Buffer<ffi::F32>>()   // materials (M, 16)
      .template Arg<ffi::Buffer<ffi::S32>>()   // texture per material (M)
      .template Arg<ffi::Buffer<ffi::F32>>()   // every texture's texels, flat
      .template Arg<ffi::Buffer<ffi::S32>>()   // (T, 2) texture heights, widths
      .template Arg<ffi::Buffer<ffi::F32>>()   // lights (L, kLightStride)
      .template Arg<ffi::Buffer<ffi::S32>>()   // light kind (L)
      .template Arg<ffi::Buffer<ffi::F32>>()   // ambient (3)
      .template Arg<ffi::Buffer<ffi::F32>>()   // environment (He, We, 3)
      .template Arg<ffi::Buffer<ffi::F32>>();  // ray offset (scene units)
}

XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxEmbreeWhitted, Whitted,
                              WithSceneArgs(ffi::Ffi::Bind()
                                                .Ctx<ffi::ThreadPool>()
                                                .Arg<ffi::Buffer<ffi::F32>>()    // origins (N, 3)
                                                .Arg<ffi::Buffer<ffi::F32>>()    // unit directions (N, 3)
                                                .Arg<ffi::Buffer<ffi::PRED>>())  // active (N)
                                  .Ret<ffi::Buffer<ffi::F32>>()   // radiance (N, 3)
                                  .Ret<ffi::Buffer<ffi::S32>>()   // rays traced (see WhittedBlock)
                                  .Ret<ffi::Buffer<ffi::S32>>()   // paths' faces ((max_depth + 1) x N) or empty
                                  .Ret<ffi::Buffer<ffi::U32>>()   // paths' unblocked lights, bits, or empty
                                  .Attr<int32_t>("max_depth")
                                  .Attr<int32_t>("recompute")
                                  .Attr<int32_t>("packets")
                                  .Attr<int32_t>("tile_width")  // rays an image this wide, 0
                                  .Attr<int32_t>("robust")
                                  .Attr<int32_t>("specular")          // kSpecularBlinnPhong, kSpecularPhong
                                  .Attr<int32_t>("specular_payload")  // the specular times n·l too
                                  .Attr<float>("min_contribution"));  // the reflections' cut-off
