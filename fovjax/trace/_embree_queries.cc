// Embree ray queries as an XLA FFI custom call (CPU): fovjax's `backend="embree"`
// (fovjax/trace/_embree.py; its oracle the JAX traversal, fovjax/trace/_traverse.py).
//
// One handler answers a batch of rays: the closest hit (face index, distance) or whether anything
// lies on the ray. It runs inside the compiled frame on XLA's own buffers and thread pool: no host
// round trip, no copy. Traversal is not differentiated; the Python side recomputes t, u, v from
// the face index, so gradients do not depend on the backend.
#pragma once

#include "native/csrc/scene_cache.h"
#include "native/csrc/thread_pool.h"

namespace {

// ---- the queries ---------------------------------------------------------------------------------

struct Rays {
  const float* o;
  const float* d;
  const float* tmin;
  const float* tmax;
  const int32_t* level;  // null: tree 0
  float* t;
  int32_t* prim;
  float* u;  // barycentrics of the hit (0 on a miss and for occlusion)
  float* v;
};

inline bool Valid(const Rays& r, int64_t i) {
  const float* o = r.o + 3 * i;
  const float* d = r.d + 3 * i;
  bool finite = std::isfinite(o[0]) && std::isfinite(o[1]) && std::isfinite(o[2]) &&
                std::isfinite(d[0]) && std::isfinite(d[1]) && std::isfinite(d[2]);
  return finite && (d[0] != 0.0f || d[1] != 0.0f || d[2] != 0.0f) && r.tmax[i] > r.tmin[i] &&
         !std::isnan(r.tmin[i]);
}

inline int32_t TreeOf(const Rays& r, int64_t i, int64_t trees) {
  if (r.level == nullptr) return 0;
  int32_t l = r.level[i];
  return l < 0 ? 0 : (l >= trees ? static_cast<int32_t>(trees - 1) : l);
}

inline void SetRay1(Ray1& ray, const Rays& r, int64_t i) {
  ray.org_x = r.o[3 * i];
  ray.org_y = r.o[3 * i + 1];
  ray.org_z = r.o[3 * i + 2];
  ray.tnear = r.tmin[i];
  ray.dir_x = r.d[3 * i];
  ray.dir_y = r.d[3 * i + 1];
  ray.dir_z = r.d[3 * i + 2];
  ray.time = 0.0f;
  ray.tfar = r.tmax[i];
  ray.mask = 0xffffffffu;
  ray.id = 0;
  ray.flags = 0;
}

void Single(const NativeScene& s, const Rays& r, int64_t begin, int64_t end, bool any_hit) {
  const int64_t trees = static_cast<int64_t>(s.trees.size());
  for (int64_t i = begin; i < end; ++i) {
    r.t[i] = INFINITY;
    r.prim[i] = -1;
    r.u[i] = r.v[i] = 0.0f;
    if (!Valid(r, i)) continue;
    int32_t l = TreeOf(r, i, trees);
    if (any_hit) {
      Ray1 ray;
      SetRay1(ray, r, i);
      g_api.rtcOccluded1(s.trees[l], &ray, nullptr);
      if (ray.tfar == -INFINITY) r.prim[i] = 0;
    } else {
      RayHit1 rh;
      SetRay1(rh.ray, r, i);
      rh.hit.geom_id = kInvalidId;
      rh.hit.inst_id[0] = kInvalidId;
      g_api.rtcIntersect1(s.trees[l], &rh, nullptr);
      if (rh.hit.geom_id != kInvalidId) {
        r.t[i] = rh.ray.tfar;
        r.prim[i] = static_cast<int32_t>(rh.hit.prim_id) + s.first_face[l];
        r.u[i] = rh.hit.u;
        r.v[i] = rh.hit.v;
      }
    }
  }
}

// Rays [begin, begin + count) loaded into a packet's lanes (`f`: the RayW fields, each `w` lanes,
// in their order), as `Valid` and `SetRay1` read them: each lane's validity in `valid` (-1 / 0),
// an invalid or missing lane made empty (tfar -inf, a unit direction). Returns the valid lanes.
// One pass with no branch per lane, each ray read once (before, the validity test and the
// coherence test each read every ray and, with the lane set-up, took a third of a shadow-ray
// call). GCC leaves it scalar: the rays' interleaved x, y, z would need a transpose.
int LoadLanes(const float* __restrict__ o, const float* __restrict__ d, const float* __restrict__ tmin,
              const float* __restrict__ tmax, int count, int w, float* __restrict__ f,
              int* __restrict__ valid) {
  float* __restrict__ ox = f;
  float* __restrict__ oy = f + w;
  float* __restrict__ oz = f + 2 * w;
  float* __restrict__ tn = f + 3 * w;
  float* __restrict__ dx = f + 4 * w;
  float* __restrict__ dy = f + 5 * w;
  float* __restrict__ dz = f + 6 * w;
  float* __restrict__ time = f + 7 * w;
  float* __restrict__ tf = f + 8 * w;
  unsigned* __restrict__ mask = reinterpret_cast<unsigned*>(f + 9 * w);
  unsigned* __restrict__ id = mask + w;
  unsigned* __restrict__ flags = mask + 2 * w;
  int live = 0;
  for (int k = 0; k < count; ++k) {
    const float x = o[3 * k], y = o[3 * k + 1], z = o[3 * k + 2];
    const float a = d[3 * k], b = d[3 * k + 1], c = d[3 * k + 2];
    const float lo = tmin[k], hi = tmax[k];
    const bool finite = std::isfinite(x) & std::isfinite(y) & std::isfinite(z) & std::isfinite(a) &
                        std::isfinite(b) & std::isfinite(c);
    const bool ok = finite & ((a != 0.0f) | (b != 0.0f) | (c != 0.0f)) & (hi > lo) & !std::isnan(lo);
    ox[k] = ok ? x : 0.0f;
    oy[k] = ok ? y : 0.0f;
    oz[k] = ok ? z : 0.0f;
    tn[k] = ok ? lo : 0.0f;
    dx[k] = ok ? a : 0.0f;
    dy[k] = ok ? b : 0.0f;
    dz[k] = ok ? c : 1.0f;
    tf[k] = ok ? hi : -INFINITY;
    valid[k] = ok ? -1 : 0;
    live += ok;
  }
  for (int k = count; k < w; ++k) {
    ox[k] = oy[k] = oz[k] = tn[k] = dx[k] = dy[k] = 0.0f;
    dz[k] = 1.0f;
    tf[k] = -INFINITY;
    valid[k] = 0;
  }
  for (int k = 0; k < w; ++k) {
    time[k] = 0.0f;
    mask[k] = 0xffffffffu;
    id[k] = static_cast<unsigned>(k);
    flags[k] = 0;
  }
  return live;
}

#ifdef FOVJAX_AVX512_LANES
// Lane k of x, y, z: float 3k, 3k + 1, 3k + 2 of the 48 (16 rays' x, y, z); those below 32 come
// from the first two vectors, the rest from the third (after the first permute, lanes 16..31).
__attribute__((target("avx512f"))) inline void Deinterleave(const float* src, __m512 out[3]) {
  alignas(64) static const int kFirst[3][16] = {
      {0, 3, 6, 9, 12, 15, 18, 21, 24, 27, 30, 0, 0, 0, 0, 0},
      {1, 4, 7, 10, 13, 16, 19, 22, 25, 28, 31, 0, 0, 0, 0, 0},
      {2, 5, 8, 11, 14, 17, 20, 23, 26, 29, 0, 0, 0, 0, 0, 0}};
  alignas(64) static const int kSecond[3][16] = {
      {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 17, 20, 23, 26, 29},
      {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 18, 21, 24, 27, 30},
      {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 16, 19, 22, 25, 28, 31}};
  const __m512 a0 = _mm512_loadu_ps(src), a1 = _mm512_loadu_ps(src + 16), a2 = _mm512_loadu_ps(src + 32);
  for (int c = 0; c < 3; ++c) {
    const __m512 t = _mm512_permutex2var_ps(a0, _mm512_load_si512(kFirst[c]), a1);
    out[c] = _mm512_permutex2var_ps(t, _mm512_load_si512(kSecond[c]), a2);
  }
}

// `LoadLanes` of 16 rays (a full packet) with AVX-512, which Embree's 16-wide packets imply: the
// rays' interleaved x, y, z deinterleaved by permutes, the tests as vector compares (x - x == 0:
// finite; ordered compares are false on NaN, as the scalar tests are). A partial packet (the
// last of a list) takes the scalar `LoadLanes`, so both stay in use.
__attribute__((target("avx512f"))) int LoadLanes16(const float* o, const float* d, const float* tmin,
                                                   const float* tmax, float* f, int* valid) {
  __m512 org[3], dir[3];
  Deinterleave(o, org);
  Deinterleave(d, dir);
  const __m512 lo = _mm512_loadu_ps(tmin), hi = _mm512_loadu_ps(tmax);
  const __m512 zero = _mm512_setzero_ps();
  __mmask16 ok = 0xffff;
  for (int c = 0; c < 3; ++c) {
    ok &= _mm512_cmp_ps_mask(_mm512_sub_ps(org[c], org[c]), zero, _CMP_EQ_OQ);
    ok &= _mm512_cmp_ps_mask(_mm512_sub_ps(dir[c], dir[c]), zero, _CMP_EQ_OQ);
  }
  ok &= _mm512_cmp_ps_mask(dir[0], zero, _CMP_NEQ_UQ) | _mm512_cmp_ps_mask(dir[1], zero, _CMP_NEQ_UQ) |
        _mm512_cmp_ps_mask(dir[2], zero, _CMP_NEQ_UQ);
  ok &= _mm512_cmp_ps_mask(hi, lo, _CMP_GT_OQ) & _mm512_cmp_ps_mask(lo, lo, _CMP_EQ_OQ);
  // RayW<16>'s fields in order: org x, y, z, tnear, dir x, y, z, time, tfar, mask, id, flags.
  _mm512_store_ps(f, _mm512_maskz_mov_ps(ok, org[0]));
  _mm512_store_ps(f + 16, _mm512_maskz_mov_ps(ok, org[1]));
  _mm512_store_ps(f + 32, _mm512_maskz_mov_ps(ok, org[2]));
  _mm512_store_ps(f + 48, _mm512_maskz_mov_ps(ok, lo));
  _mm512_store_ps(f + 64, _mm512_maskz_mov_ps(ok, dir[0]));
  _mm512_store_ps(f + 80, _mm512_maskz_mov_ps(ok, dir[1]));
  _mm512_store_ps(f + 96, _mm512_mask_blend_ps(ok, _mm512_set1_ps(1.0f), dir[2]));
  _mm512_store_ps(f + 112, zero);
  _mm512_store_ps(f + 128, _mm512_mask_blend_ps(ok, _mm512_set1_ps(-INFINITY), hi));
  _mm512_store_si512(f + 144, _mm512_set1_epi32(-1));
  _mm512_store_si512(f + 160, _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15));
  _mm512_store_si512(f + 176, _mm512_setzero_si512());
  _mm512_storeu_si512(valid, _mm512_mask_set1_epi32(_mm512_setzero_si512(), ok, -1));
  return __builtin_popcount(static_cast<unsigned>(ok));
}
bool g_avx512 = __builtin_cpu_supports("avx512f");
#endif

// Whether a packet's lanes are worth tracing as one: at least w / 4 valid lanes whose directions
// lie within about 25 degrees of the first valid lane's (camera, shadow and flat-mirror rays of
// neighbouring pixels): d·first >= 0.9 |d| |first|, compared squared. Packets of scattered rays
// trace slower than the rays one by one.
FOVJAX_VECTOR_CLONES
bool CoherentLanes(const float* __restrict__ dx, const float* __restrict__ dy, const float* __restrict__ dz,
                   const int* __restrict__ valid, int w, int live) {
  if (live < w / 4) return false;
  int first = 0;
  while (first < w && !valid[first]) ++first;
  const float fx = dx[first], fy = dy[first], fz = dz[first];
  const float first_len2 = fx * fx + fy * fy + fz * fz;
  int apart = 0;
  for (int k = 0; k < w; ++k) {
    const float dot = dx[k] * fx + dy[k] * fy + dz[k] * fz;
    const float len2 = dx[k] * dx[k] + dy[k] * dy[k] + dz[k] * dz[k];
    apart |= (valid[k] != 0) & ((dot < 0.0f) | (dot * dot < 0.81f * len2 * first_len2));
  }
  return apart == 0;
}

// Rays [begin, min(begin + W, end)) as one packet (lanes past `end` or invalid are masked off),
// or, unless `always`, one by one where they are not coherent (`CoherentLanes`). A packet whose
// rays use several trees is traced once per tree, each time with that tree's lanes.
template <int W>
void PacketW(const NativeScene& s, const Rays& r, int64_t begin, int64_t end, bool any_hit, bool always) {
  const int count = static_cast<int>(std::min<int64_t>(W, end - begin));
  RayHitW<W> rh;
  // Embree reads the valid mask with aligned vector loads (the packet's width in bytes): an
  // unaligned mask crashes its 16-wide path on AVX-512 machines.
  alignas(4 * W) int valid[W];
  int live;
#ifdef FOVJAX_AVX512_LANES
  if (W == 16 && count == 16 && g_avx512) {
    live = LoadLanes16(r.o + 3 * begin, r.d + 3 * begin, r.tmin + begin, r.tmax + begin, rh.ray.org_x,
                       valid);
  } else
#endif
  {
    live = LoadLanes(r.o + 3 * begin, r.d + 3 * begin, r.tmin + begin, r.tmax + begin, count, W,
                     rh.ray.org_x, valid);
  }
  if (!always && !CoherentLanes(rh.ray.dir_x, rh.ray.dir_y, rh.ray.dir_z, valid, W, live)) {
    Single(s, r, begin, begin + count, any_hit);
    return;
  }
  const int64_t trees = static_cast<int64_t>(s.trees.size());
  QueryArgs args{};
  args.flags = kQueryCoherent;
  args.feature_mask = 0xffffffffu;
  if (live > 0) {
    for (int k = 0; k < W; ++k) {
      rh.hit.geom_id[k] = kInvalidId;
      rh.hit.inst_id[0][k] = kInvalidId;
    }
  }
  if (live > 0 && (r.level == nullptr || trees == 1)) {
    // Every lane in tree 0 (`TreeOf`): one query, then each lane's result (a miss's or an
    // invalid lane's as below) in a loop without branches.
    const int32_t first_face = s.first_face[0];
    int32_t* __restrict__ prim = r.prim + begin;
    if (any_hit) {
      OccludedW<W>(valid, s.trees[0], &rh.ray, &args);
      for (int k = 0; k < count; ++k) prim[k] = valid[k] != 0 && rh.ray.tfar[k] == -INFINITY ? 0 : -1;
      return;
    }
    IntersectW<W>(valid, s.trees[0], &rh, &args);
    float *__restrict__ t = r.t + begin, *__restrict__ u = r.u + begin, *__restrict__ v = r.v + begin;
    for (int k = 0; k < count; ++k) {
      const bool hit = valid[k] != 0 && rh.hit.geom_id[k] != kInvalidId;
      prim[k] = hit ? static_cast<int32_t>(rh.hit.prim_id[k]) + first_face : -1;
      t[k] = hit ? rh.ray.tfar[k] : INFINITY;
      u[k] = hit ? rh.hit.u[k] : 0.0f;
      v[k] = hit ? rh.hit.v[k] : 0.0f;
    }
    return;
  }
  for (int k = 0; k < count; ++k) r.prim[begin + k] = -1;
  if (!any_hit) {  // an occluded ray's t, u, v mean nothing: not written
    for (int k = 0; k < count; ++k) {
      r.t[begin + k] = INFINITY;
      r.u[begin + k] = r.v[begin + k] = 0.0f;
    }
  }
  if (live == 0) return;
  int32_t tree[W];
  for (int k = 0; k < W; ++k) tree[k] = valid[k] ? TreeOf(r, begin + k, trees) : -1;
  int32_t done_tree = -1;
  for (int k = 0; k < W; ++k) {
    if (tree[k] < 0 || tree[k] == done_tree) continue;
    int32_t l = tree[k];
    alignas(4 * W) int lanes[W];
    for (int j = 0; j < W; ++j) lanes[j] = tree[j] == l ? -1 : 0;
    if (any_hit) {
      OccludedW<W>(lanes, s.trees[l], &rh.ray, &args);
    } else {
      IntersectW<W>(lanes, s.trees[l], &rh, &args);
    }
    for (int j = 0; j < W; ++j) {
      if (tree[j] == l) tree[j] = -2 - l;  // traced
    }
    done_tree = l;
  }
  for (int k = 0; k < count; ++k) {
    int64_t i = begin + k;
    if (!valid[k]) continue;
    int32_t l = -2 - tree[k];
    if (any_hit) {
      if (rh.ray.tfar[k] == -INFINITY) r.prim[i] = 0;
    } else if (rh.hit.geom_id[k] != kInvalidId) {
      r.t[i] = rh.ray.tfar[k];
      r.prim[i] = static_cast<int32_t>(rh.hit.prim_id[k]) + s.first_face[l];
      r.u[i] = rh.hit.u[k];
      r.v[i] = rh.hit.v[k];
    }
  }
}

template <int W>
void Packets(ffi::ThreadPool& pool, const NativeScene& s, const Rays& r, int64_t n, bool occlusion,
             bool always) {
  const int64_t packets = (n + W - 1) / W;
  const int64_t per_block = 1024 / W;  // 1024 rays: small next to a frame, large next to a task's cost
  ParallelFor(pool, (packets + per_block - 1) / per_block, [&](int64_t b) {
    int64_t last = std::min(packets, (b + 1) * per_block);
    for (int64_t p = b * per_block; p < last; ++p) {
      PacketW<W>(s, r, W * p, n, occlusion, always);
    }
  });
}

ffi::Error Query(ffi::ThreadPool pool, ffi::Buffer<ffi::F32> origins, ffi::Buffer<ffi::F32> directions,
                 ffi::Buffer<ffi::F32> tmin, ffi::Buffer<ffi::F32> tmax, ffi::Buffer<ffi::S32> level,
                 ffi::Buffer<ffi::S32> scene_id, ffi::Buffer<ffi::F32> vertices,
                 ffi::Buffer<ffi::S32> faces, ffi::Buffer<ffi::S32> first_face,
                 ffi::ResultBuffer<ffi::F32> t, ffi::ResultBuffer<ffi::S32> prim,
                 ffi::ResultBuffer<ffi::F32> u, ffi::ResultBuffer<ffi::F32> v, int32_t any_hit,
                 int32_t packet, int32_t robust) {
  if (g_device == nullptr) return ffi::Error::Internal("fovjax Embree backend used before init");
  // Every array is read flat, so a batch under vmap ("expand_dims") is one call for all frames.
  const int64_t n = static_cast<int64_t>(tmin.element_count());
  if (origins.element_count() != 3 * static_cast<size_t>(n) ||
      directions.element_count() != 3 * static_cast<size_t>(n) ||
      tmax.element_count() != static_cast<size_t>(n) || t->element_count() != static_cast<size_t>(n) ||
      prim->element_count() != static_cast<size_t>(n) || u->element_count() != static_cast<size_t>(n) ||
      v->element_count() != static_cast<size_t>(n) ||
      (level.element_count() != 0 && level.element_count() != static_cast<size_t>(n))) {
    return ffi::Error::InvalidArgument("fovjax Embree query: ray arrays of different lengths");
  }
  if (scene_id.element_count() != 1 || first_face.element_count() < 2 ||
      vertices.element_count() % 3 != 0 || faces.element_count() % 3 != 0) {
    return ffi::Error::InvalidArgument(
        "fovjax Embree query: one scene per call (a BVH batched under vmap is not supported)");
  }
  std::string error;
  auto scene = GetScene(scene_id.typed_data()[0], robust != 0, vertices.typed_data(),
                        static_cast<int64_t>(vertices.element_count() / 3), faces.typed_data(),
                        static_cast<int64_t>(faces.element_count() / 3), first_face.typed_data(),
                        static_cast<int64_t>(first_face.element_count()), &error);
  if (!scene) return ffi::Error::InvalidArgument("fovjax Embree scene: " + error);
  Rays r{origins.typed_data(), directions.typed_data(), tmin.typed_data(), tmax.typed_data(),
         level.element_count() ? level.typed_data() : nullptr, t->typed_data(), prim->typed_data(),
         u->typed_data(), v->typed_data()};
  const bool occlusion = any_hit != 0;
  const NativeScene& s = *scene;
  if (packet != 0) {
    // 1: every run of W consecutive rays is a packet (W: the CPU's native width); -1: where the
    // run is coherent, else its rays one by one.
    const bool always = packet == 1;
    if (g_width == 16) {
      Packets<16>(pool, s, r, n, occlusion, always);
    } else if (g_width == 8) {
      Packets<8>(pool, s, r, n, occlusion, always);
    } else {
      Packets<4>(pool, s, r, n, occlusion, always);
    }
  } else {
    const int64_t per_block = 1024;
    ParallelFor(pool, (n + per_block - 1) / per_block, [&](int64_t b) {
      Single(s, r, b * per_block, std::min(n, (b + 1) * per_block), occlusion);
    });
  }
  return ffi::Error::Success();
}

// Closest hits (or occlusion) of rays [0, n) of `r`: W-ray packets where a run of W rays is
// coherent, the rest one by one.
void TraceList(const NativeScene& s, const Rays& r, int64_t n, bool any_hit, bool packets) {
  if (!packets) {
    Single(s, r, 0, n, any_hit);
    return;
  }
  const int w = g_width;
  for (int64_t p = 0; p < n; p += w) {
    if (w == 16) {
      PacketW<16>(s, r, p, n, any_hit, false);
    } else if (w == 8) {
      PacketW<8>(s, r, p, n, any_hit, false);
    } else {
      PacketW<4>(s, r, p, n, any_hit, false);
    }
  }
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxEmbreeQuery, Query,
                              ffi::Ffi::Bind()
                                  .Ctx<ffi::ThreadPool>()
                                  .Arg<ffi::Buffer<ffi::F32>>()  // origins (..., 3)
                                  .Arg<ffi::Buffer<ffi::F32>>()  // directions (..., 3)
                                  .Arg<ffi::Buffer<ffi::F32>>()  // tmin
                                  .Arg<ffi::Buffer<ffi::F32>>()  // tmax
                                  .Arg<ffi::Buffer<ffi::S32>>()  // tree per ray, or empty
                                  .Arg<ffi::Buffer<ffi::S32>>()  // the BVH's host id
                                  .Arg<ffi::Buffer<ffi::F32>>()  // vertices (V, 3)
                                  .Arg<ffi::Buffer<ffi::S32>>()  // faces (F, 3)
                                  .Arg<ffi::Buffer<ffi::S32>>()  // first face of each tree, and F
                                  .Ret<ffi::Buffer<ffi::F32>>()  // t (inf: miss)
                                  .Ret<ffi::Buffer<ffi::S32>>()  // face, -1: miss (0: occluded)
                                  .Ret<ffi::Buffer<ffi::F32>>()  // u
                                  .Ret<ffi::Buffer<ffi::F32>>()  // v
                                  .Attr<int32_t>("any_hit")
                                  .Attr<int32_t>("packet")  // 0, 1 or -1 (where coherent)
                                  .Attr<int32_t>("robust"));
