// The Whitted integrator's adjoint in the shading parameters: given the paths a native forward
// stored (`PathsOut`) and the cotangent of each ray's radiance, the gradient with respect to
// every material's ka, kd, ks, ke, kr and ns, every light's colour and the ambient colour. Its
// oracle is the reverse pass of the replay (fovjax/render/_replay.py), which it replaces for
// those parameters: no ray is traced, hits are recomputed from the stored faces as there, and
// everything else (geometry, textures, the environment, the lights' positions) keeps the
// replay's derivatives.
#pragma once

#include "native/csrc/layout.h"
#include "native/csrc/scene_cache.h"
#include "native/csrc/thread_pool.h"
#include "render/_whitted.cc"

namespace {

// What one run of rays adds to the gradient, in double (the runs are summed in order, so the
// result does not depend on the threads).
struct AdjointSums {
  std::vector<double> materials;  // (M, kMaterialStride)
  std::vector<double> lights;     // (L, 3): the colours
  double ambient[3] = {0.0, 0.0, 0.0};
  void Reset(int64_t nm, int nl) {
    materials.assign(static_cast<size_t>(nm) * kMaterialStride, 0.0);
    lights.assign(static_cast<size_t>(nl) * 3, 0.0);
    ambient[0] = ambient[1] = ambient[2] = 0.0;
  }
};

inline void Add3(double* to, Vec3 v) {
  to[0] += v.x;
  to[1] += v.y;
  to[2] += v.z;
}

// One ray's path, level by level: its weight, material and radiance before the weight (the
// local shading of a hit, the environment of a miss), then the reflectances backwards.
constexpr int kMaxLevels = 64;

// Bits of `moving` (layout.h's kAdjoint*): the fields whose gradient is wanted; the specular
// term is computed only where one of them reads it.
constexpr int32_t kMovingKs = 1 << kAdjointKs, kMovingKr = 1 << kAdjointKr, kMovingNs = 1 << kAdjointNs,
                  kMovingLight = 1 << kAdjointLightColor;

void AdjointRay(const ShadeScene& s, Vec3 o, Vec3 d, const int32_t* prim, const uint32_t* visible,
                int64_t stride, int levels, Vec3 g, int32_t moving, AdjointSums* out) {
  const bool specular = (moving & (kMovingKs | kMovingKr | kMovingNs | kMovingLight)) != 0;
  Vec3 weight_at[kMaxLevels];
  Vec3 radiance_at[kMaxLevels];
  int32_t material_at[kMaxLevels];
  Vec3 w{1.0f, 1.0f, 1.0f};
  int count = 0;
  for (int k = 0; k < levels; ++k) {
    const int32_t f_hit = prim[k * stride];
    if (f_hit == kPathNotTraced) break;
    weight_at[k] = w;
    material_at[k] = -1;
    count = k + 1;
    if (f_hit < 0) {  // a miss: the environment, then nothing further
      radiance_at[k] = Environment(s.environment, d);
      break;
    }
    const int64_t f = std::min<int64_t>(f_hit, s.num_faces - 1);
    const int32_t* face = s.faces + 3 * f;
    const int32_t mat = s.face_material[f];
    if (face[0] < 0 || face[0] >= s.num_vertices || face[1] < 0 || face[1] >= s.num_vertices ||
        face[2] < 0 || face[2] >= s.num_vertices || mat < 0 || mat >= s.num_materials) {
      s.out_of_range->store(1);
      return;
    }
    const Surface at = SurfaceAt(s, face, o, d, 0.0f, 0.0f, true);  // hit_geometry, as the replay
    const Vec3 p = at.p, ng = at.ng, nsh = at.nsh;
    const float* row = s.materials + kMaterialStride * mat;
    Vec3 ka = Load3(row), kd = Load3(row + 3), ks = Load3(row + 6), ke = Load3(row + 9), kr = Load3(row + 12);
    const float shininess = row[15];
    Vec3 texture{1.0f, 1.0f, 1.0f};
    TextureAt(s, mat, face, at, &texture);
    const Vec3 kd_tex = kd * texture;
    const Vec3 gw = g * w;  // d loss / d (this level's radiance before the weight)
    double* dm = out->materials.data() + static_cast<int64_t>(kMaterialStride) * mat;
    Add3(dm + 0, gw * s.ambient);  // ka
    Add3(out->ambient, gw * ka);
    Add3(dm + 9, gw);  // ke
    Vec3 local = ka * s.ambient + ke;
    const uint32_t bits = visible[k * stride];
    for (int l = 0; l < s.num_lights; ++l) {
      Vec3 dir;
      const LightAt at = LightTowards(s, l, p, &dir);
      const float ndl = Dot(nsh, dir);
      if (!(ndl > 0.0f && Dot(ng, dir) > 0.0f && at.spot > 0.0f)) continue;  // not wanted
      if (((bits >> l) & 1u) == 0) continue;                                // blocked
      const Vec3 light = Load3(s.lights + kLightStride * l + 3);
      const Vec3 color = light * at.spot;
      if (!specular) {  // Kd's term alone (and Ka's, Ke's, the ambient's above)
        Add3(dm + 3, gw * texture * (ndl * color));
        continue;
      }
      float cosine;
      if (s.shading.specular == kSpecularPhong) {
        Vec3 mirrored = (2.0f * ndl) * nsh - dir;
        cosine = -Dot(mirrored, d);
      } else {
        cosine = Dot(nsh, Normalize(dir - d));
      }
      const float log2_cosine = cosine > 0.0f ? std::log2(cosine) : 0.0f;
      float spec = cosine > 0.0f ? std::exp2(shininess * log2_cosine) : 0.0f;
      if (s.shading.payload) spec = spec * ndl;
      const Vec3 unlit = kd_tex * ndl + ks * spec;  // the term before the light's colour
      local = local + unlit * color;
      Add3(dm + 3, gw * texture * (ndl * color));  // kd
      Add3(dm + 6, gw * (spec * color));           // ks
      if ((moving & kMovingNs) && cosine > 0.0f) {  // d spec / d ns = spec · ln(cosine)
        const Vec3 by = gw * ks * color;
        dm[15] += static_cast<double>(spec) * std::log(static_cast<double>(cosine)) *
                  (static_cast<double>(by.x) + by.y + by.z);
      }
      Add3(out->lights.data() + 3 * l, gw * unlit * at.spot);
    }
    radiance_at[k] = local;
    material_at[k] = mat;
    w = kr * w;
    // The next level's ray (the forward spawned it where the paths go on).
    if (k + 1 < levels && prim[(k + 1) * stride] != kPathNotTraced) {
      Vec3 reflected = d - 2.0f * Dot(d, nsh) * nsh;
      if (Dot(reflected, ng) <= 0.0f) reflected = d - 2.0f * Dot(d, ng) * ng;
      o = p + s.offset * ng;
      d = Normalize(reflected);
    }
  }
  // kr: the radiance of level k + 1 on is weighted by level k's reflectance; `after` is what
  // follows level k, before its own weight, divided by level k's reflectance (no division).
  Vec3 after{0.0f, 0.0f, 0.0f};
  for (int k = count - 1; k >= 0; --k) {
    if (material_at[k] >= 0 && k + 1 < count) {
      double* dm = out->materials.data() + static_cast<int64_t>(kMaterialStride) * material_at[k];
      Add3(dm + 12, g * weight_at[k] * after);
    }
    if (material_at[k] >= 0) {
      const Vec3 kr = Load3(s.materials + kMaterialStride * material_at[k] + 12);
      after = radiance_at[k] + kr * after;
    } else {
      after = radiance_at[k];
    }
  }
}

ffi::Error WhittedAdjoint(ffi::ThreadPool pool, ffi::Buffer<ffi::F32> origins, ffi::Buffer<ffi::F32> directions,
                          ffi::Buffer<ffi::S32> path_prim, ffi::Buffer<ffi::U32> path_visible,
                          ffi::Buffer<ffi::F32> cotangent, FOVJAX_SCENE_PARAMS,
                          ffi::ResultBuffer<ffi::F32> d_materials, ffi::ResultBuffer<ffi::F32> d_lights,
                          ffi::ResultBuffer<ffi::F32> d_ambient, int32_t specular, int32_t specular_payload,
                          int32_t moving) {
  const int64_t n = static_cast<int64_t>(cotangent.element_count() / 3);
  if (origins.element_count() != 3 * static_cast<size_t>(n) ||
      directions.element_count() != 3 * static_cast<size_t>(n) || n < 1 ||
      path_prim.element_count() % static_cast<size_t>(n) != 0 ||
      path_visible.element_count() != path_prim.element_count()) {
    return ffi::Error::InvalidArgument("fovjax Whitted adjoint: rays, paths and cotangents of different lengths");
  }
  const int64_t levels = static_cast<int64_t>(path_prim.element_count()) / n;
  if (levels < 1 || levels > kMaxLevels || light_kind.element_count() > 32) {
    return ffi::Error::InvalidArgument("fovjax Whitted adjoint: paths of 1 to 64 levels, at most 32 lights");
  }
  HandlerScene scene;
  const Shading shading{specular, specular_payload != 0, 0.0f};
  ffi::Error status = scene.Load(FOVJAX_SCENE_ARGS, static_cast<int32_t>(levels - 1), 1, 1, shading);
  if (status.failure()) return status;
  const ShadeScene& s = scene.s;
  if (d_materials->element_count() != static_cast<size_t>(s.num_materials) * kMaterialStride ||
      d_lights->element_count() != static_cast<size_t>(s.num_lights) * 3 || d_ambient->element_count() != 3) {
    return ffi::Error::InvalidArgument("fovjax Whitted adjoint: gradients of unexpected shapes");
  }
  const float* o = origins.typed_data();
  const float* d = directions.typed_data();
  const float* g = cotangent.typed_data();
  const int32_t* prim = path_prim.typed_data();
  const uint32_t* visible = path_visible.typed_data();
  // At most kParts runs of rays, each with its own sums: the memory is bounded by the scene's
  // materials and lights, not by the rays.
  constexpr int64_t kParts = 64;
  const int64_t parts = std::min<int64_t>(kParts, (n + 4095) / 4096);
  const int64_t per_part = (n + parts - 1) / parts;
  std::vector<AdjointSums> sums(static_cast<size_t>(parts));
  ParallelFor(pool, parts, [&](int64_t part) {
    AdjointSums& out = sums[static_cast<size_t>(part)];
    out.Reset(s.num_materials, s.num_lights);
    const int64_t end = std::min(n, (part + 1) * per_part);
    for (int64_t i = part * per_part; i < end; ++i) {
      if (prim[i] == kPathNotTraced) continue;
      const Vec3 gi = Load3(g + 3 * i);
      if (gi.x == 0.0f && gi.y == 0.0f && gi.z == 0.0f) continue;
      AdjointRay(s, Load3(o + 3 * i), Load3(d + 3 * i), prim + i, visible + i, n, static_cast<int>(levels), gi,
                 moving, &out);
    }
  });
  status = scene.Checked("fovjax Whitted adjoint: a stored face names a vertex or a material out of range");
  if (status.failure()) return status;
  AdjointSums all;
  all.Reset(s.num_materials, s.num_lights);
  for (const AdjointSums& b : sums) {
    for (size_t j = 0; j < all.materials.size(); ++j) all.materials[j] += b.materials[j];
    for (size_t j = 0; j < all.lights.size(); ++j) all.lights[j] += b.lights[j];
    for (int c = 0; c < 3; ++c) all.ambient[c] += b.ambient[c];
  }
  for (size_t j = 0; j < all.materials.size(); ++j) d_materials->typed_data()[j] = static_cast<float>(all.materials[j]);
  for (size_t j = 0; j < all.lights.size(); ++j) d_lights->typed_data()[j] = static_cast<float>(all.lights[j]);
  for (int c = 0; c < 3; ++c) d_ambient->typed_data()[c] = static_cast<float>(all.ambient[c]);
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxWhittedAdjoint, WhittedAdjoint,
                              WithSceneArgs(ffi::Ffi::Bind()
                                                .Ctx<ffi::ThreadPool>()
                                                .Arg<ffi::Buffer<ffi::F32>>()    // origins (N, 3)
                                                .Arg<ffi::Buffer<ffi::F32>>()    // unit directions (N, 3)
                                                .Arg<ffi::Buffer<ffi::S32>>()    // paths' faces (levels x N)
                                                .Arg<ffi::Buffer<ffi::U32>>()    // paths' unblocked lights
                                                .Arg<ffi::Buffer<ffi::F32>>())   // radiance cotangent (N, 3)
                                  .Ret<ffi::Buffer<ffi::F32>>()   // d materials (M, 16)
                                  .Ret<ffi::Buffer<ffi::F32>>()   // d light colours (L, 3)
                                  .Ret<ffi::Buffer<ffi::F32>>()   // d ambient (3)
                                  .Attr<int32_t>("specular")           // kSpecularBlinnPhong, kSpecularPhong
                                  .Attr<int32_t>("specular_payload")  // the specular times n·l too
                                  .Attr<int32_t>("moving"));  // bits: the fields whose gradient is wanted
