// Embree ray queries as an XLA FFI custom call (CPU): fovjax's `backend="embree"`.
//
// One handler answers a batch of rays: the closest hit (face index, distance) or whether anything
// lies on the ray. It runs inside the compiled frame on XLA's own buffers and thread pool: no host
// round trip, no copy. Traversal is not differentiated; the Python side recomputes t, u, v from
// the face index, so gradients do not depend on the backend.
//
// Embree itself is the shared library inside the `embreex` wheel, opened with dlopen at run time.
// This file declares the few Embree 4 calls and ray structs it uses, written from Embree 4.4's
// documented C API; `fovjax_embree_init` checks the struct sizes against the library before any
// query runs (a layout mismatch writes past the structs: see `CheckLayout`).
//
// Scenes are built on first use from the geometry the call receives (one Embree scene per tree of
// a merged level-of-detail BVH) and cached by the BVH's host id, so the frame program needs no
// Python call to set them up; `fovjax_embree_release` frees them.

#include <dlfcn.h>

#include <atomic>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "xla/ffi/api/ffi.h"

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define FOVJAX_AVX512_LANES 1
#endif

namespace ffi = xla::ffi;

// A plain loop over lanes or pixels built for the widest vector unit the CPU has (chosen when
// the library loads), which the compiler vectorises.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define FOVJAX_VECTOR_CLONES __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define FOVJAX_VECTOR_CLONES
#endif

namespace {

// ---- Embree 4 declarations (from the documented C API) ------------------------------------------

using RTCDevice = void*;
using RTCScene = void*;
using RTCGeometry = void*;

constexpr unsigned kInvalidId = 0xffffffffu;
constexpr int kGeometryTriangle = 0;    // RTC_GEOMETRY_TYPE_TRIANGLE
constexpr int kBufferIndex = 0;         // RTC_BUFFER_TYPE_INDEX
constexpr int kBufferVertex = 1;        // RTC_BUFFER_TYPE_VERTEX
constexpr int kFormatUint3 = 0x5003;    // RTC_FORMAT_UINT3
constexpr int kFormatFloat3 = 0x9003;   // RTC_FORMAT_FLOAT3
constexpr int kSceneRobust = 1 << 2;    // RTC_SCENE_FLAG_ROBUST: watertight triangle test
constexpr int kBuildQualityHigh = 2;    // RTC_BUILD_QUALITY_HIGH
constexpr int kQueryCoherent = 1 << 16; // RTC_RAY_QUERY_FLAG_COHERENT
constexpr int kDevicePropertyVersion = 0;

// RTC_MAX_INSTANCE_LEVEL_COUNT is 1 and RTC_GEOMETRY_INSTANCE_ARRAY is on in the wheel's build
// (checked at init: a larger hit struct in the library would write past these).
struct alignas(16) Ray1 {
  float org_x, org_y, org_z, tnear, dir_x, dir_y, dir_z, time, tfar;
  unsigned mask, id, flags;
};
struct alignas(16) Hit1 {
  float ng_x, ng_y, ng_z, u, v;
  unsigned prim_id, geom_id;
  unsigned inst_id[1];
  unsigned inst_prim_id[1];
};
struct RayHit1 {
  Ray1 ray;
  Hit1 hit;
};
// RTCRay4/8/16 and RTCHit4/8/16: W lanes of each field, aligned to 4 W bytes.
template <int W>
struct alignas(4 * W) RayW {
  float org_x[W], org_y[W], org_z[W], tnear[W], dir_x[W], dir_y[W], dir_z[W], time[W], tfar[W];
  unsigned mask[W], id[W], flags[W];
};
template <int W>
struct alignas(4 * W) HitW {
  float ng_x[W], ng_y[W], ng_z[W], u[W], v[W];
  unsigned prim_id[W], geom_id[W];
  unsigned inst_id[1][W];
  unsigned inst_prim_id[1][W];
};
template <int W>
struct RayHitW {
  RayW<W> ray;
  HitW<W> hit;
};
// RTCIntersectArguments / RTCOccludedArguments (same layout): flags, feature mask, context,
// filter, intersect/occluded callback, and minWidthDistanceFactor in builds with RTC_MIN_WIDTH.
struct QueryArgs {
  int flags;
  unsigned feature_mask;
  void* context;
  void* filter;
  void* callback;
  float min_width_distance_factor;
  float reserved[7];  // zero: room for fields a newer minor version may read
};

struct EmbreeApi {
  RTCDevice (*rtcNewDevice)(const char*);
  int (*rtcGetDeviceError)(RTCDevice);
  ptrdiff_t (*rtcGetDeviceProperty)(RTCDevice, int);
  RTCScene (*rtcNewScene)(RTCDevice);
  void (*rtcSetSceneFlags)(RTCScene, int);
  void (*rtcSetSceneBuildQuality)(RTCScene, int);
  unsigned (*rtcAttachGeometry)(RTCScene, RTCGeometry);
  void (*rtcCommitScene)(RTCScene);
  void (*rtcReleaseScene)(RTCScene);
  RTCGeometry (*rtcNewGeometry)(RTCDevice, int);
  void (*rtcSetSharedGeometryBuffer)(RTCGeometry, int, unsigned, int, const void*, size_t, size_t,
                                     size_t);
  void (*rtcCommitGeometry)(RTCGeometry);
  void (*rtcReleaseGeometry)(RTCGeometry);
  void (*rtcIntersect1)(RTCScene, RayHit1*, QueryArgs*);
  void (*rtcOccluded1)(RTCScene, Ray1*, QueryArgs*);
  // Packets of 4, 8 and 16 rays (the same signature, W lanes).
  void (*rtcIntersectW[3])(const int*, RTCScene, void*, QueryArgs*);
  void (*rtcOccludedW[3])(const int*, RTCScene, void*, QueryArgs*);
};

EmbreeApi g_api;

// The packet width this CPU traces natively (Embree emulates wider packets: a 16-ray call on
// an AVX2 machine measured no faster than 16 single rays), set at init.
int g_width = 8;

constexpr int WidthIndex(int w) { return w == 4 ? 0 : (w == 8 ? 1 : 2); }

template <int W>
void IntersectW(const int* valid, RTCScene scene, RayHitW<W>* rh, QueryArgs* args) {
  g_api.rtcIntersectW[WidthIndex(W)](valid, scene, rh, args);
}
template <int W>
void OccludedW(const int* valid, RTCScene scene, RayW<W>* ray, QueryArgs* args) {
  g_api.rtcOccludedW[WidthIndex(W)](valid, scene, ray, args);
}

RTCDevice g_device = nullptr;
std::string g_error;

template <typename F>
bool Load(void* lib, const char* name, F* fn) {
  *fn = reinterpret_cast<F>(dlsym(lib, name));
  if (*fn == nullptr) g_error = std::string("Embree library lacks ") + name;
  return *fn != nullptr;
}

// ---- scenes -------------------------------------------------------------------------------------

struct NativeScene {
  std::vector<float> vertices;  // 3 V floats and padding (Embree reads vertices 16 bytes at a time)
  std::vector<uint32_t> faces;  // 3 F
  std::vector<int32_t> first_face;  // per tree, and the end
  std::vector<RTCScene> trees;
  uint64_t fingerprint = 0;
  ~NativeScene() {
    for (RTCScene s : trees) g_api.rtcReleaseScene(s);
  }
};

std::mutex g_scenes_mutex;
// Keyed by the BVH's host id and whether its trees are robust (`SceneKey`).
std::unordered_map<int64_t, std::shared_ptr<NativeScene>> g_scenes;

int64_t SceneKey(int32_t id, bool robust) { return static_cast<int64_t>(id) * 2 + (robust ? 1 : 0); }

uint64_t Mix(uint64_t h, uint64_t x) {
  h ^= x + 0x9e3779b97f4a7c15ull + (h << 6) + (h >> 2);
  return h;
}

// Sizes and a sample of the geometry: a host id reused for other geometry (another process's
// numbering cannot reach here, but a caller could hand in other arrays) rebuilds the scene.
uint64_t Fingerprint(const float* v, int64_t nv, const int32_t* f, int64_t nf, const int32_t* off,
                     int64_t noff) {
  uint64_t h = Mix(Mix(0, nv), nf);
  for (int64_t i = 0; i < noff; ++i) h = Mix(h, static_cast<uint32_t>(off[i]));
  const int64_t samples = 64;
  for (int64_t k = 0; k < samples && nv > 0; ++k) {
    uint32_t bits;
    std::memcpy(&bits, &v[(k * (3 * nv - 1)) / samples], 4);
    h = Mix(h, bits);
  }
  for (int64_t k = 0; k < samples && nf > 0; ++k) h = Mix(h, static_cast<uint32_t>(f[(k * (3 * nf - 1)) / samples]));
  return h;
}

// `robust`: Embree's robust mode (a watertight triangle test and conservative box tests; a ray
// through a shared edge or vertex hits one of the faces), else its default, faster intersector.
std::shared_ptr<NativeScene> Build(const float* v, int64_t nv, const int32_t* f, int64_t nf,
                                   const int32_t* off, int64_t noff, uint64_t fingerprint, bool robust,
                                   std::string* error) {
  auto scene = std::make_shared<NativeScene>();
  scene->fingerprint = fingerprint;
  scene->vertices.assign(v, v + 3 * nv);
  scene->vertices.resize(3 * nv + 4, 0.0f);
  scene->faces.resize(3 * nf);
  for (int64_t i = 0; i < 3 * nf; ++i) {
    if (f[i] < 0 || f[i] >= nv) {
      *error = "face " + std::to_string(i / 3) + " names vertex " + std::to_string(f[i]) +
               " of " + std::to_string(nv);
      return nullptr;
    }
    scene->faces[i] = static_cast<uint32_t>(f[i]);
  }
  scene->first_face.assign(off, off + noff);
  for (int64_t l = 0; l + 1 < noff; ++l) {
    int64_t first = off[l], count = off[l + 1] - off[l];
    if (first < 0 || count < 0 || first + count > nf) {
      *error = "tree " + std::to_string(l) + " face range is outside the faces";
      return nullptr;
    }
    RTCScene s = g_api.rtcNewScene(g_device);
    g_api.rtcSetSceneFlags(s, robust ? kSceneRobust : 0);
    g_api.rtcSetSceneBuildQuality(s, kBuildQualityHigh);
    if (count > 0) {
      RTCGeometry g = g_api.rtcNewGeometry(g_device, kGeometryTriangle);
      g_api.rtcSetSharedGeometryBuffer(g, kBufferVertex, 0, kFormatFloat3, scene->vertices.data(), 0,
                                       12, nv);
      g_api.rtcSetSharedGeometryBuffer(g, kBufferIndex, 0, kFormatUint3, scene->faces.data(),
                                       12 * first, 12, count);
      g_api.rtcCommitGeometry(g);
      g_api.rtcAttachGeometry(s, g);
      g_api.rtcReleaseGeometry(g);
    }
    g_api.rtcCommitScene(s);
    scene->trees.push_back(s);
    if (int code = g_api.rtcGetDeviceError(g_device)) {
      *error = "Embree error " + std::to_string(code) + " building tree " + std::to_string(l);
      return nullptr;
    }
  }
  return scene;
}

std::shared_ptr<NativeScene> GetScene(int32_t id, bool robust, const float* v, int64_t nv, const int32_t* f,
                                      int64_t nf, const int32_t* off, int64_t noff,
                                      std::string* error) {
  uint64_t fp = Fingerprint(v, nv, f, nf, off, noff);
  const int64_t key = SceneKey(id, robust);
  std::lock_guard<std::mutex> lock(g_scenes_mutex);
  auto it = g_scenes.find(key);
  if (it != g_scenes.end() && it->second->fingerprint == fp) return it->second;
  auto scene = Build(v, nv, f, nf, off, noff, fp, robust, error);
  if (scene) g_scenes[key] = scene;
  return scene;
}

// ---- work split over XLA's CPU thread pool -------------------------------------------------------

// Runs body(block) for every block. The calling thread works too; a pool task that starts after
// every block is claimed returns without touching `body`, so the call never waits for a task
// the pool has not started (no deadlock when the pool is busy).
template <typename Body>
void ParallelFor(ffi::ThreadPool& pool, int64_t blocks, const Body& body) {
  if (blocks <= 0) return;
  struct State {
    std::atomic<int64_t> next{0};
    std::atomic<int64_t> done{0};
    int64_t blocks = 0;
    std::mutex mutex;
    std::condition_variable finished;
  };
  auto state = std::make_shared<State>();
  state->blocks = blocks;
  const Body* shared_body = &body;
  auto run = [state, shared_body]() {
    for (;;) {
      int64_t b = state->next.fetch_add(1);
      if (b >= state->blocks) return;
      (*shared_body)(b);
      if (state->done.fetch_add(1) + 1 == state->blocks) {
        std::lock_guard<std::mutex> lock(state->mutex);
        state->finished.notify_all();
      }
    }
  };
  int64_t helpers = std::min<int64_t>(pool.num_threads(), blocks - 1);
  for (int64_t i = 0; i < helpers; ++i) pool.Schedule([run]() { run(); });
  run();
  std::unique_lock<std::mutex> lock(state->mutex);
  state->finished.wait(lock, [&] { return state->done.load() == state->blocks; });
}

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
  for (int k = 0; k < count; ++k) r.prim[begin + k] = -1;
  if (!any_hit) {  // an occluded ray's t, u, v mean nothing: not written
    for (int k = 0; k < count; ++k) {
      r.t[begin + k] = INFINITY;
      r.u[begin + k] = r.v[begin + k] = 0.0f;
    }
  }
  if (live == 0) return;
  for (int k = 0; k < W; ++k) {
    rh.hit.geom_id[k] = kInvalidId;
    rh.hit.inst_id[0][k] = kInvalidId;
  }
  const int64_t trees = static_cast<int64_t>(s.trees.size());
  int32_t tree[W];
  for (int k = 0; k < W; ++k) tree[k] = valid[k] ? TreeOf(r, begin + k, trees) : -1;
  QueryArgs args{};
  args.flags = kQueryCoherent;
  args.feature_mask = 0xffffffffu;
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

template <int W>
bool CheckPacket(const std::shared_ptr<NativeScene>& s, std::string* error) {
  constexpr size_t kGuard = 256;
  constexpr unsigned char kByte = 0xA5;
  {
    alignas(64) unsigned char buffer[sizeof(RayHitW<W>) + kGuard];
    std::memset(buffer, kByte, sizeof(buffer));
    auto* rh = reinterpret_cast<RayHitW<W>*>(buffer);
    alignas(4 * W) int valid[W];  // aligned as Embree's vector loads need (see PacketW)
    for (int k = 0; k < W; ++k) {
      valid[k] = -1;
      rh->ray.org_x[k] = 0.01f * k - 0.005f * W;
      rh->ray.org_y[k] = 0;
      rh->ray.org_z[k] = 0;
      rh->ray.tnear[k] = 0;
      rh->ray.dir_x[k] = 0;
      rh->ray.dir_y[k] = 0;
      rh->ray.dir_z[k] = 1;
      rh->ray.time[k] = 0;
      rh->ray.tfar[k] = INFINITY;
      rh->ray.mask[k] = 0xffffffffu;
      rh->ray.id[k] = k;
      rh->ray.flags[k] = 0;
      rh->hit.geom_id[k] = kInvalidId;
      rh->hit.inst_id[0][k] = kInvalidId;
    }
    QueryArgs args{};
    args.flags = kQueryCoherent;
    args.feature_mask = 0xffffffffu;
    IntersectW<W>(valid, s->trees[0], rh, &args);
    for (size_t i = sizeof(RayHitW<W>); i < sizeof(buffer); ++i) {
      if (buffer[i] != kByte) {
        *error = "rtcIntersect" + std::to_string(W) + " wrote past the declared RTCRayHit" + std::to_string(W) + " (the library's layout differs)";
        return false;
      }
    }
    for (int k = 0; k < W; ++k) {
      if (rh->hit.geom_id[k] != 0 || rh->hit.prim_id[k] != 0 ||
          std::fabs(rh->ray.tfar[k] - 1.0f) > 1e-6f) {
        *error = "rtcIntersect" + std::to_string(W) + " did not report the test triangle where declared";
        return false;
      }
    }
    for (int k = 0; k < W; ++k) rh->ray.tfar[k] = INFINITY;  // the hits above set tfar to 1
    OccludedW<W>(valid, s->trees[0], &rh->ray, &args);
    for (int k = 0; k < W; ++k) {
      if (rh->ray.tfar[k] != -INFINITY) {
        *error = "rtcOccluded" + std::to_string(W) + " did not mark the test rays occluded";
        return false;
      }
    }
  }
  return true;
}

// Traces one triangle into structs surrounded by guard bytes: the library must write the fields
// this file declares (the hit) and nothing past the end of each struct.
bool CheckLayout(std::string* error) {
  float v[12] = {-1, -1, 1, 1, -1, 1, 0, 1, 1, 0, 0, 0};
  int32_t f[3] = {0, 1, 2};
  int32_t off[2] = {0, 1};
  std::string build_error;
  auto s = Build(v, 3, f, 1, off, 2, 0, true, &build_error);
  if (!s) {
    *error = build_error;
    return false;
  }
  constexpr size_t kGuard = 256;
  constexpr unsigned char kByte = 0xA5;
  // Single ray.
  {
    alignas(64) unsigned char buffer[sizeof(RayHit1) + kGuard];
    std::memset(buffer, kByte, sizeof(buffer));
    auto* rh = reinterpret_cast<RayHit1*>(buffer);
    rh->ray = Ray1{0, 0, 0, 0, 0, 0, 1, 0, INFINITY, 0xffffffffu, 0, 0};
    rh->hit.geom_id = kInvalidId;
    rh->hit.inst_id[0] = kInvalidId;
    g_api.rtcIntersect1(s->trees[0], rh, nullptr);
    for (size_t i = sizeof(RayHit1); i < sizeof(buffer); ++i) {
      if (buffer[i] != kByte) {
        *error = "rtcIntersect1 wrote past the declared RTCRayHit (the library's layout differs)";
        return false;
      }
    }
    if (rh->hit.geom_id != 0 || rh->hit.prim_id != 0 || std::fabs(rh->ray.tfar - 1.0f) > 1e-6f) {
      *error = "rtcIntersect1 did not report the test triangle where declared";
      return false;
    }
  }
  // Packets of every width, every lane aimed at the triangle.
  return CheckPacket<4>(s, error) && CheckPacket<8>(s, error) && CheckPacket<16>(s, error);
}


// ---- the Whitted integrator: the primal of fovjax.render.radiance on the CPU ---------------------
//
// The same arithmetic as the JAX integrator (fovjax/render/_integrator.py), written per ray:
// closest hit, Blinn–Phong with a shadow ray per light, mirror reflections to max_depth. It
// returns each ray's radiance (NaN/inf kept: the caller paints bad samples) and the rays it
// traced; derivatives come from the JAX integrator (a custom JVP on the Python side).

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
  const float* lights;  // (L, 6): position (or direction towards the light), colour
  const int32_t* light_kind;  // 0: point, 1: directional
  int num_lights;
  Vec3 ambient;
  Texture environment;
  float offset;
  int max_depth;
  bool recompute;  // u, v by Möller–Trumbore on `vertices` (RenderConfig.hits "recomputed")
};

constexpr int kMaterialStride = 16;
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

// One block's work buffers, kept per thread across blocks and calls.
struct WhittedBuffers {
  std::vector<float> o, d, weight, tmin, tmax, t, u, v;
  std::vector<int32_t> prim, pixel;
  std::vector<float> point, n_geo, n_shade, kd;
  std::vector<int32_t> material;
  std::vector<float> so, sd, stmin, stmax, st, su, sv, n_dot_l;
  std::vector<int32_t> sprim;
  void Reserve(int64_t n, int lights) {
    for (auto* x : {&o, &d, &weight, &point, &n_geo, &n_shade, &kd}) x->resize(3 * n);
    for (auto* x : {&tmin, &tmax, &t, &u, &v}) x->resize(n);
    prim.resize(n);
    pixel.resize(n);
    material.resize(n);
    const int64_t ns = n * std::max(lights, 1);
    for (auto* x : {&so, &sd}) x->resize(3 * ns);
    for (auto* x : {&stmin, &stmax, &st, &su, &sv, &n_dot_l}) x->resize(ns);
    sprim.resize(ns);
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
  int64_t Index(int64_t i) const {
    if (width == 0) return begin + i;
    const int64_t tile = i / 16, within = i % 16;
    return (row0 + within / 4) * width + col0 + 4 * tile + within % 4;
  }
};

// `sparse`: the rays are samples scattered over the screen (a foveated frame's), whose hits'
// faces and vertices are seldom in the cache from a neighbour's: they are prefetched a few rays
// ahead of the shading (a foveated frame 4-6% faster, measured in one process; a full frame's
// neighbouring rays share their faces, and it measured 1-2% slower with it).
void WhittedBlock(const NativeScene& tree, const ShadeScene& s, const float* o_in, const float* d_in,
                  const bool* active, const BlockRays& block, float* total, int32_t* traced,
                  bool packets, bool sparse) {
  thread_local WhittedBuffers b;
  const int64_t n = block.n;
  const int nl = s.num_lights;
  b.Reserve(n, nl);
  int64_t m = 0;
  for (int64_t i = 0; i < n; ++i) {
    const int64_t g = block.Index(i);
    total[3 * g] = total[3 * g + 1] = total[3 * g + 2] = 0.0f;
    traced[g] = 0;
    if (!active[g]) continue;
    b.pixel[m] = static_cast<int32_t>(g);
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
    Rays rays{b.o.data(), b.d.data(), b.tmin.data(), b.tmax.data(), nullptr,
              b.t.data(), b.prim.data(), b.u.data(), b.v.data()};
    TraceList(tree, rays, m, false, packets);
    // Surfaces and their shadow rays.
    int64_t ns = 0;
    for (int64_t k = 0; k < m; ++k) {
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
      Vec3 c0 = Load3(s.vertices + 3 * face[0]), c1 = Load3(s.vertices + 3 * face[1]),
           c2 = Load3(s.vertices + 3 * face[2]);
      Vec3 d = Load3(&b.d[3 * k]);
      float u = b.u[k], v = b.v[k];
      if (s.recompute) {  // hit_geometry
        Vec3 e1 = c1 - c0, e2 = c2 - c0;
        Vec3 pvec = Cross(d, e2);
        float det = Dot(e1, pvec);
        if (det != 0.0f) {
          float inv_det = 1.0f / det;
          Vec3 tvec = Load3(&b.o[3 * k]) - c0;
          Vec3 qvec = Cross(tvec, e1);
          u = Dot(tvec, pvec) * inv_det;
          v = Dot(d, qvec) * inv_det;
        } else {
          u = v = 0.0f;
        }
      }
      const float b0 = 1.0f - u - v;
      Vec3 p = Interpolate(b0, u, v, c0, c1, c2);
      Vec3 ng = Normalize(Cross(c1 - c0, c2 - c0));
      const float sign = Dot(ng, d) > 0.0f ? -1.0f : 1.0f;
      ng = ng * sign;
      Vec3 nsh = ng;
      if (s.normals != nullptr) {
        Vec3 ni = Normalize(Interpolate(b0, u, v, Load3(s.normals + 3 * face[0]),
                                        Load3(s.normals + 3 * face[1]), Load3(s.normals + 3 * face[2])));
        if (!(ni.x == 0.0f && ni.y == 0.0f && ni.z == 0.0f)) nsh = ni * sign;
      }
      const float* row = s.materials + kMaterialStride * mat;
      Vec3 kd = Load3(row + 3);
      if (!s.textures.empty()) {
        const int32_t ti = s.texture[mat];
        if (ti >= 0 && ti < static_cast<int32_t>(s.textures.size())) {
          float tu = 0.0f, tv = 0.0f;
          if (s.uvs != nullptr) {
            const float* a = s.uvs + 2 * face[0];
            const float* bb = s.uvs + 2 * face[1];
            const float* c = s.uvs + 2 * face[2];
            tu = a[0] * b0 + bb[0] * u + c[0] * v;
            tv = a[1] * b0 + bb[1] * u + c[1] * v;
          }
          kd = kd * Bilinear(s.textures[ti], tu, tv);
        }
      }
      for (int c = 0; c < 3; ++c) {
        b.point[3 * k + c] = (&p.x)[c];
        b.n_geo[3 * k + c] = (&ng.x)[c];
        b.n_shade[3 * k + c] = (&nsh.x)[c];
        b.kd[3 * k + c] = (&kd.x)[c];
      }
      b.material[k] = mat;
      Vec3 origin = p + s.offset * ng;
      for (int l = 0; l < nl; ++l) {
        Vec3 position = Load3(s.lights + 6 * l);
        const bool point_light = s.light_kind[l] == 0;
        Vec3 to_light = point_light ? position - p : position;
        float n2 = Dot(to_light, to_light);
        float distance = n2 > 0.0f ? std::sqrt(n2) : 0.0f;
        Vec3 dir = Normalize(to_light);
        float ndl = Dot(nsh, dir);
        if (!(ndl > 0.0f && Dot(ng, dir) > 0.0f)) continue;
        const int64_t j = ns++;
        for (int c = 0; c < 3; ++c) {
          b.so[3 * j + c] = (&origin.x)[c];
          b.sd[3 * j + c] = (&dir.x)[c];
        }
        b.stmin[j] = 0.0f;
        b.stmax[j] = point_light ? distance : INFINITY;
        b.n_dot_l[j] = ndl;
      }
    }
    Rays shadow{b.so.data(), b.sd.data(), b.stmin.data(), b.stmax.data(), nullptr,
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
      const float shininess = row[15];
      Vec3 p = Load3(&b.point[3 * k]), ng = Load3(&b.n_geo[3 * k]), nsh = Load3(&b.n_shade[3 * k]);
      Vec3 local = ka * s.ambient + ke;
      if (nl > 0) {
        Vec3 kd = Load3(&b.kd[3 * k]);
        Vec3 sum{0.0f, 0.0f, 0.0f};
        bool first = true;
        for (int l = 0; l < nl; ++l) {
          Vec3 position = Load3(s.lights + 6 * l);
          const bool point_light = s.light_kind[l] == 0;
          Vec3 dir = Normalize(point_light ? position - p : position);
          float ndl = Dot(nsh, dir);
          if (!(ndl > 0.0f && Dot(ng, dir) > 0.0f)) continue;  // not wanted: no ray, no light
          const int64_t j = js++;
          traced[px] += 1 << 8;
          if (b.sprim[j] >= 0) continue;  // blocked
          Vec3 half = Normalize(dir - d);
          float ndh = Dot(nsh, half);
          float spec = ndh > 0.0f ? std::exp2(shininess * std::log2(ndh)) : 0.0f;
          Vec3 term = (kd * b.n_dot_l[j] + ks * spec) * Load3(s.lights + 6 * l + 3);
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
      Vec3 reflected = d - 2.0f * Dot(d, nsh) * nsh;
      if (Dot(reflected, ng) <= 0.0f) reflected = d - 2.0f * Dot(d, ng) * ng;
      Vec3 o2 = p + s.offset * ng, d2 = Normalize(reflected);
      for (int c2 = 0; c2 < 3; ++c2) {
        b.o[3 * next + c2] = (&o2.x)[c2];
        b.d[3 * next + c2] = (&d2.x)[c2];
        b.weight[3 * next + c2] = (&w.x)[c2];
      }
      b.pixel[next] = px;
      traced[px] += 1;
      ++next;
    }
    m = next;
  }
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
                     std::atomic<int>* out_of_range, ShadeScene* scene,
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
      lights.element_count() != 6 * static_cast<size_t>(nl) || ambient.element_count() != 3 ||
      env_dims.size() != 3 || env_dims[2] != 3 || env_dims[0] < 1 || env_dims[1] < 1 ||
      offset.element_count() != 1 || texture_shape.element_count() % 2 != 0 ||
      scene_id.element_count() != 1 || first_face.element_count() < 2) {
    return ffi::Error::InvalidArgument("fovjax Whitted: scene arrays of unexpected shapes");
  }
  // Faces and their materials are checked where a ray hits them (a pass over every face on
  // every call measured ~0.7 ms on the atrium, seven calls a foveated frame).
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
  s.ambient = Load3(ambient.typed_data());
  s.environment = Texture{environment.typed_data(), env_dims[0], env_dims[1]};
  s.offset = offset.typed_data()[0];
  s.max_depth = max_depth;
  s.recompute = recompute != 0;
  std::string error;
  *tree_out = GetScene(scene_id.typed_data()[0], robust != 0, bvh_vertices.typed_data(),
                       static_cast<int64_t>(bvh_vertices.element_count() / 3), bvh_faces.typed_data(),
                       static_cast<int64_t>(bvh_faces.element_count() / 3), first_face.typed_data(),
                       static_cast<int64_t>(first_face.element_count()), &error);
  if (!*tree_out) return ffi::Error::InvalidArgument("fovjax Embree scene: " + error);
  return ffi::Error::Success();
}

ffi::Error Whitted(ffi::ThreadPool pool, ffi::Buffer<ffi::F32> origins, ffi::Buffer<ffi::F32> directions,
                   ffi::Buffer<ffi::PRED> active, FOVJAX_SCENE_PARAMS, ffi::ResultBuffer<ffi::F32> total,
                   ffi::ResultBuffer<ffi::S32> traced, int32_t max_depth, int32_t recompute,
                   int32_t packets, int32_t tile_width, int32_t robust) {
  if (g_device == nullptr) return ffi::Error::Internal("fovjax Embree backend used before init");
  const int64_t n = static_cast<int64_t>(active.element_count());
  if (origins.element_count() != 3 * static_cast<size_t>(n) ||
      directions.element_count() != 3 * static_cast<size_t>(n) ||
      total->element_count() != 3 * static_cast<size_t>(n) ||
      traced->element_count() != static_cast<size_t>(n)) {
    return ffi::Error::InvalidArgument("fovjax Whitted: ray arrays of different lengths");
  }
  std::atomic<int> out_of_range{0};
  ShadeScene s;
  std::shared_ptr<NativeScene> tree;
  ffi::Error status = SceneFrom(FOVJAX_SCENE_ARGS, max_depth, recompute, robust, &out_of_range, &s, &tree);
  if (status.failure()) return status;
  const NativeScene& t = *tree;
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
      WhittedBlock(t, s, o, d, a, block, out, counts, packets != 0, false);
    });
  } else {
    ParallelFor(pool, (n + per_block - 1) / per_block, [&](int64_t blk) {
      BlockRays block;
      block.begin = blk * per_block;
      block.n = std::min(n, (blk + 1) * per_block) - block.begin;
      WhittedBlock(t, s, o, d, a, block, out, counts, packets != 0, false);
    });
  }
  if (out_of_range.load() != 0) {
    return ffi::Error::InvalidArgument(
        "fovjax Whitted: a hit face names a vertex or a material out of range");
  }
  return ffi::Error::Success();
}

// ---- the foveated frame's sample selection ----------------------------------------------------
//
// `fovjax.foveate._frame.select_samples` (no image tiles), its traced mask and per-pixel counts
// in one pass over the screen on both cores, with the same results to the bit: the classes of
// every sub-sample (`_sampling.sample_classes`: block top-lefts, the P(ω) draw of JAX's
// threefry2x32 uniform for the sub-sample's flat index, the rule, each region's samples per
// pixel), their stable compaction in locality order (`compaction_order`), and which samples the
// budget keeps. The regions and P(ω) come from the program (JAX computes both).

// One lane's threefry2x32 (see UniformRun): the uniform float of counter `c`.
inline float UniformOne(const uint32_t ks[3], uint32_t c) {
  static constexpr int kRotations[2][4] = {{13, 15, 26, 6}, {17, 29, 16, 24}};
  uint32_t x0 = ks[0], x1 = c + ks[1];
  for (int group = 0; group < 5; ++group) {
    for (int j = 0; j < 4; ++j) {
      const int r = kRotations[group % 2][j];
      x0 += x1;
      x1 = (x1 << r) | (x1 >> (32 - r));
      x1 ^= x0;
    }
    x0 += ks[(group + 1) % 3];
    x1 += ks[(group + 2) % 3] + static_cast<uint32_t>(group + 1);
  }
  const uint32_t mantissa = ((x0 ^ x1) >> 9) | 0x3F800000u;
  float f;
  std::memcpy(&f, &mantissa, sizeof f);
  f -= 1.0f;
  return f > 0.0f ? f : 0.0f;
}

// The uniforms of n counters, `first + i` or `index[i]`: 64 lanes at a time, each round a
// loop over the lanes that the compiler vectorises. Each vector of lanes is one long chain of
// dependent rounds; 64 lanes keep several chains in flight on the vector unit.
template <bool kIndexed>
inline __attribute__((always_inline)) void UniformLanes(uint32_t k0, uint32_t k1, uint32_t first,
                                                        const uint32_t* __restrict__ index, int64_t n,
                                                        float* __restrict__ out) {
  static constexpr int kRotations[2][4] = {{13, 15, 26, 6}, {17, 29, 16, 24}};
  constexpr int kLanes = 64;
  const uint32_t ks[3] = {k0, k1, k0 ^ k1 ^ 0x1BD11BDAu};
  int64_t i = 0;
  for (; i + kLanes <= n; i += kLanes) {
    uint32_t x0[kLanes], x1[kLanes];
    for (int j = 0; j < kLanes; ++j) {
      x0[j] = ks[0];
      x1[j] = (kIndexed ? index[i + j] : first + static_cast<uint32_t>(i + j)) + ks[1];
    }
#pragma GCC unroll 5
    for (int group = 0; group < 5; ++group) {
#pragma GCC unroll 4
      for (int r4 = 0; r4 < 4; ++r4) {
        const int r = kRotations[group % 2][r4];
        for (int j = 0; j < kLanes; ++j) {
          x0[j] += x1[j];
          x1[j] = (x1[j] << r) | (x1[j] >> (32 - r));
          x1[j] ^= x0[j];
        }
      }
      const uint32_t a = ks[(group + 1) % 3], b = ks[(group + 2) % 3] + static_cast<uint32_t>(group + 1);
      for (int j = 0; j < kLanes; ++j) {
        x0[j] += a;
        x1[j] += b;
      }
    }
    for (int j = 0; j < kLanes; ++j) {
      const uint32_t mantissa = ((x0[j] ^ x1[j]) >> 9) | 0x3F800000u;
      float f;
      std::memcpy(&f, &mantissa, sizeof f);
      f -= 1.0f;
      out[i + j] = f > 0.0f ? f : 0.0f;
    }
  }
  for (; i < n; ++i) out[i] = UniformOne(ks, kIndexed ? index[i] : first + static_cast<uint32_t>(i));
}

// JAX's uniform float32 in [0, 1) at flat indices first..first+n-1 of the key (k0, k1):
// threefry2x32 of each 64-bit counter (hi 0, index), its two words xor-ed, the top 23 bits as a
// mantissa in [1, 2), minus 1. A plain loop over lanes that the compiler vectorises, built for
// the widest vector unit the CPU has (chosen when the library loads).
FOVJAX_VECTOR_CLONES
void UniformRun(uint32_t k0, uint32_t k1, uint32_t first, int64_t n, float* out) {
  UniformLanes<false>(k0, k1, first, nullptr, n, out);
}

constexpr int kFovea = 0, kOutside = 2;
constexpr int8_t kMandatory = 0, kOptional = 1, kSkipped = 2;

// One row of one sub-sample's classes (`_sampling.sample_classes`), branch-free so that the
// compiler vectorises it: class = 2 - 2·mandatory - optional (the two exclude each other),
// skipped beyond the region's samples per pixel (`allowed` per region code). Adds the traced
// samples to `n`.
template <int kRule>
void ClassRow(const int32_t* __restrict__ row, const uint8_t* __restrict__ top_left,
              const float* __restrict__ u, const float* __restrict__ prob, const uint8_t* allowed,
              uint8_t first, int64_t w, int8_t* __restrict__ cls, uint8_t* __restrict__ traced,
              int32_t* __restrict__ n) {
  // int32 lanes throughout: GCC vectorises the loop only when its values share one width.
  const int32_t a0 = allowed[0], a1 = allowed[1], a2 = allowed[2], f = first;
  for (int64_t x = 0; x < w; ++x) {
    const int32_t r = row[x];
    const int32_t fovea = r == kFovea, tl = top_left[x], kept = u[x] < prob[x];
    int32_t mandatory, optional;
    if (kRule == 0) {  // either
      mandatory = fovea | tl;
      optional = (mandatory ^ 1) & kept;
    } else if (kRule == 1) {  // strict
      mandatory = fovea;
      optional = (mandatory ^ 1) & tl & kept;
    } else {  // thesis-measured
      mandatory = (r != kOutside) | f;
      optional = 0;
    }
    const int32_t ok = (fovea & a0) | ((r == 1) & a1) | ((r == kOutside) & a2);
    const int32_t live = ok & (mandatory | optional);
    cls[x] = static_cast<int8_t>(2 - live * (2 * mandatory + optional));
    traced[x] = static_cast<uint8_t>(live);
    n[x] += live;
  }
}

// Pass 1 of `SelectSamples` for one band of rows of one eye (`job`): its operands.
struct SelectBand {
  const int32_t* region;
  const float* p;
  const uint32_t* key;
  const int32_t* rspp;
  const int32_t* srank;
  int8_t* cls;
  bool* traced;
  int32_t* per_pixel;
  int64_t* band_sums;
  int64_t h, w, hw, spp, rows, bands;
  int32_t rule, block_periphery, block_outside;
};

// Built for the widest vector unit the CPU has, as UniformRun (the row loops are byte- and
// int-wide lanes; ClassRow is inlined into each build).
FOVJAX_VECTOR_CLONES
void SelectBandRows(const SelectBand& a, int64_t job) {
  const int32_t* region = a.region;
  const float* p = a.p;
  const uint32_t* key = a.key;
  const int32_t* rspp = a.rspp;
  const int32_t* srank = a.srank;
  int8_t* cls = a.cls;
  bool* traced = a.traced;
  int32_t* per_pixel = a.per_pixel;
  int64_t* band_sums = a.band_sums;
  const int64_t h = a.h, w = a.w, hw = a.hw, spp = a.spp, rows = a.rows, bands = a.bands;
  const int32_t rule = a.rule, block_periphery = a.block_periphery, block_outside = a.block_outside;
  // The sizes as locals: the byte-wide stores below may alias anything the lambda captures by
  // reference, which would be reloaded after each of them.
  const int64_t W = w, H = h;
  const int64_t eye = job / bands, y0 = (job % bands) * rows, y1 = std::min(H, y0 + rows);
  const int32_t* reg = region + eye * hw;
  std::vector<float> u(static_cast<size_t>(W * spp));
  std::vector<uint8_t> top_left(static_cast<size_t>(W)), in_block(static_cast<size_t>(W));
  const int32_t codes[2] = {1, 2}, sizes[2] = {block_periphery, block_outside};
  for (int64_t y = y0; y < y1; ++y) {
    const int32_t* row = reg + y * W;
    // `_sampling.block_top_lefts`: the fovea's pixels; a region's pixels where its blocks are
    // one pixel; else the top-left of every aligned block holding a pixel of that region.
    uint8_t* tl = top_left.data();
    for (int64_t x = 0; x < W; ++x) tl[x] = row[x] == kFovea;
    for (int c = 0; c < 2; ++c) {
      const int64_t b = sizes[c];
      const int32_t code = codes[c];
      if (b == 1) {
        for (int64_t x = 0; x < W; ++x) tl[x] |= row[x] == code;
        continue;
      }
      if (y % b != 0) continue;
      uint8_t* any = in_block.data();  // per column: a pixel of the region in the block's rows
      for (int64_t x = 0; x < W; ++x) any[x] = row[x] == code;
      for (int64_t yy = y + 1; yy < std::min(H, y + b); ++yy) {
        const int32_t* below = reg + yy * W;
        for (int64_t x = 0; x < W; ++x) any[x] |= below[x] == code;
      }
      for (int64_t xb = 0; xb < W; xb += b) {
        uint8_t found = 0;
        for (int64_t xx = xb; xx < std::min(W, xb + b); ++xx) found |= any[xx];
        tl[xb] |= found;
      }
    }
    for (int64_t s = 0; s < spp; ++s)
      UniformRun(key[2 * eye], key[2 * eye + 1], static_cast<uint32_t>((s * H + y) * W), W, &u[s * W]);
    const float* prow = p + eye * hw + y * W;
    int32_t* n = per_pixel + eye * hw + y * W;
    std::fill(n, n + W, 0);
    for (int64_t s = 0; s < spp; ++s) {
      const float* us = &u[s * W];
      int8_t* c_row = cls + (eye * spp + s) * hw + y * W;
      uint8_t* t_row = reinterpret_cast<uint8_t*>(traced) + (eye * spp + s) * hw + y * W;
      const uint8_t allowed[3] = {srank[s] < rspp[0], srank[s] < rspp[1], srank[s] < rspp[2]};
      const uint8_t first = s == 0;
      if (rule == 0) ClassRow<0>(row, top_left.data(), us, prow, allowed, first, W, c_row, t_row, n);
      else if (rule == 1) ClassRow<1>(row, top_left.data(), us, prow, allowed, first, W, c_row, t_row, n);
      else ClassRow<2>(row, top_left.data(), us, prow, allowed, first, W, c_row, t_row, n);
    }
    // Per region, in registers (a sum through memory would wait on each previous add).
    int32_t fovea = 0, periphery = 0, outside = 0;
    for (int64_t x = 0; x < W; ++x) {
      const int32_t r = row[x], v = n[x];
      fovea += r == 0 ? v : 0;
      periphery += r == 1 ? v : 0;
      outside += r == 2 ? v : 0;
    }
    band_sums[3 * job] += fovea, band_sums[3 * job + 1] += periphery, band_sums[3 * job + 2] += outside;
  }
}

ffi::Error SelectSamples(ffi::ThreadPool pool, ffi::Buffer<ffi::S32> region_buf,
                         ffi::Buffer<ffi::F32> probability, ffi::Buffer<ffi::U32> keys,
                         ffi::Buffer<ffi::S32> locality, ffi::Buffer<ffi::S32> region_spp,
                         ffi::Buffer<ffi::S32> subsample_rank, ffi::ResultBuffer<ffi::S8> classes_out,
                         ffi::ResultBuffer<ffi::S32> order_out, ffi::ResultBuffer<ffi::S32> counts_out,
                         ffi::ResultBuffer<ffi::PRED> traced_out, ffi::ResultBuffer<ffi::S32> per_pixel_out,
                         ffi::ResultBuffer<ffi::S32> by_region_out, int32_t spp, int32_t rule, int32_t block_periphery, int32_t block_outside,
                         int64_t budget) {
  const auto dims = region_buf.dimensions();
  if (dims.size() != 3 || dims[0] != 2) return ffi::Error::InvalidArgument("select: regions must be (2, H, W)");
  const int64_t h = dims[1], w = dims[2], hw = h * w, per_eye = hw * spp;
  if (probability.element_count() != static_cast<size_t>(2 * hw) || keys.element_count() != 4 ||
      locality.element_count() != static_cast<size_t>(hw) || region_spp.element_count() != 3 ||
      subsample_rank.element_count() != static_cast<size_t>(spp) || block_periphery < 1 || block_outside < 1) {
    return ffi::Error::InvalidArgument("select: operand shapes do not match the regions");
  }
  const int32_t* region = region_buf.typed_data();
  const float* p = probability.typed_data();
  const uint32_t* key = keys.typed_data();
  const int32_t* perm = locality.typed_data();
  const int32_t* rspp = region_spp.typed_data();
  const int32_t* srank = subsample_rank.typed_data();
  int8_t* cls = classes_out->typed_data();           // (2, S, H, W)
  int32_t* order = order_out->typed_data();          // (2 · H·W · S), locality order
  int32_t* counts = counts_out->typed_data();        // (3)
  bool* traced = traced_out->typed_data();           // (2, S, H, W)
  int32_t* per_pixel = per_pixel_out->typed_data();  // (2, H, W)
  int32_t* by_region = by_region_out->typed_data();  // (3): traced samples per region

  // Pass 1, rows in bands: each sub-sample's class, whether it is wanted, and the wanted
  // samples per pixel (the budget's drops are taken off in pass 2).
  const int64_t rows = 16;
  const int64_t bands = (h + rows - 1) / rows;
  std::vector<int64_t> band_sums(3 * 2 * bands, 0);  // wanted samples per region, per band
  const SelectBand band{region, p, key, rspp, srank, cls, traced, per_pixel, band_sums.data(), h, w, hw, spp,
                        rows, bands, rule, block_periphery, block_outside};
  ParallelFor(pool, 2 * bands, [&](int64_t job) { SelectBandRows(band, job); });

  // Pass 2, the locality-ordered samples in chunks: each chunk lists its mandatory and its
  // optional samples (the stable partition of `compaction_order`), then the lists go to their
  // places. Slots past the traced samples (`order` beyond the wanted ones) are never read as
  // live rays: zeros.
  const int64_t pixels_per_chunk = 8192;
  const int64_t chunks_per_eye = (hw + pixels_per_chunk - 1) / pixels_per_chunk;
  const int64_t chunks = 2 * chunks_per_eye;
  // Each chunk's two lists, allocated uninitialised (zeroing them cost more than filling them).
  std::vector<std::unique_ptr<int32_t[]>> listed(2 * chunks);
  std::vector<int64_t> listed_size(2 * chunks, 0);
  ParallelFor(pool, chunks, [&](int64_t c) {
    const int64_t eye = c / chunks_per_eye, j0 = (c % chunks_per_eye) * pixels_per_chunk;
    const int64_t j1 = std::min(hw, j0 + pixels_per_chunk);
    const int64_t S = spp, HW = hw, first = eye * per_eye;  // locals: see pass 1
    listed[2 * c].reset(new int32_t[static_cast<size_t>((j1 - j0) * S)]);
    listed[2 * c + 1].reset(new int32_t[static_cast<size_t>((j1 - j0) * S)]);
    int32_t* m = listed[2 * c].get();
    int32_t* o = listed[2 * c + 1].get();
    int64_t nm = 0, no = 0;  // written unconditionally, kept by the counts (no branch)
    const int8_t* classes = cls + eye * S * HW;
    for (int64_t j = j0; j < j1; ++j) {
      const int64_t pix = perm[j];
      for (int64_t s = 0; s < S; ++s) {
        const int8_t k = classes[s * HW + pix];
        const int32_t slot = static_cast<int32_t>(first + j * S + s);
        m[nm] = slot, o[no] = slot;
        nm += k == kMandatory, no += k == kOptional;
      }
    }
    listed_size[2 * c] = nm, listed_size[2 * c + 1] = no;
  });
  int64_t total[2] = {0, 0};
  std::vector<int64_t> offset(2 * chunks);
  for (int k = 0; k < 2; ++k)
    for (int64_t c = 0; c < chunks; ++c) {
      offset[2 * c + k] = total[k];
      total[k] += listed_size[2 * c + k];
    }
  const int64_t wanted = total[0] + total[1];
  for (int64_t c = 0; c < chunks; ++c) offset[2 * c + 1] += total[0];
  ParallelFor(pool, chunks + 1, [&](int64_t c) {
    if (c == chunks) {  // the rest of the list
      std::fill(order + wanted, order + 2 * per_eye, 0);
      return;
    }
    for (int k = 0; k < 2; ++k) {
      const int64_t size = listed_size[2 * c + k];
      if (size > 0) std::memcpy(order + offset[2 * c + k], listed[2 * c + k].get(), size * sizeof(int32_t));
    }
  });
  // Beyond the budget (`traced_mask`'s drops): the listed samples past it are not traced.
  for (int64_t rank = std::min(budget, wanted); rank < wanted; ++rank) {
    const int64_t slot = order[rank], eye = slot / per_eye, j = (slot % per_eye) / spp, s = slot % spp;
    const int64_t pix = perm[j];
    traced[(eye * spp + s) * hw + pix] = false;
    --per_pixel[eye * hw + pix];
    const int32_t r = region[eye * hw + pix];
    if (r >= 0 && r < 3) --band_sums[r];  // any band's sum: only the total is read
  }
  for (int r = 0; r < 3; ++r) {
    int64_t sum = 0;
    for (int64_t b = 0; b < 2 * bands; ++b) sum += band_sums[3 * b + r];
    by_region[r] = static_cast<int32_t>(sum);
  }
  counts[0] = static_cast<int32_t>(total[0]);
  counts[1] = static_cast<int32_t>(total[1]);
  counts[2] = static_cast<int32_t>(2 * per_eye - wanted);
  return ffi::Error::Success();
}

// ---- the foveated frame's slots: rays made, traced and summed into their pixels --------------
//
// `fovjax.foveate._frame.trace_selection` through the native integrator with `sample_adder`
// consuming its chunks, in one call: each live slot's primary ray from its index
// (`_slot_samples`, `positions_at`, `Camera.ray_directions`, `normalize`: the same operations
// in the same order), its Whitted radiance (`WhittedBlock`), then every slot's radiance added to
// its pixel in slot order, as the chunks add them. Its work is the live slots' (the chunk loop's
// per-chunk operations around the integrator are gone).

// JAX's threefry2x32 uniform (see UniformRun) at each of n counters.
FOVJAX_VECTOR_CLONES
void UniformAt(uint32_t k0, uint32_t k1, const uint32_t* __restrict__ index, int64_t n,
               float* __restrict__ out) {
  UniformLanes<true>(k0, k1, 0, index, n, out);
}

constexpr int kCameraStride = 16;  // position (3), rotation (3×3, row-major), tan(vfov/2), aspect, offset (2)

struct SlotLayout {
  const int32_t* order;
  const int32_t* locality;  // (H·W): pixel of each locality rank
  const float* grid;        // (S, 2): the sub-samples' cell centres
  const float* cameras;     // (2, kCameraStride)
  uint32_t key[2];
  bool jitter;
  int64_t spp, h, w, per_eye, cells;  // cells: the strata per row, sqrt(spp)
};

// Per-block scratch of `SlotRays`.
struct SlotScratch {
  std::vector<float> x, y, jitter;
  std::vector<uint32_t> counter;
  std::vector<int32_t> eye, sample;
  void Reserve(int64_t n) {
    for (auto* v : {&x, &y}) v->resize(n);
    jitter.resize(2 * n), counter.resize(2 * n);
    for (auto* v : {&eye, &sample}) v->resize(n);
  }
};

// Slots [begin, begin + n) as rays (o, d, active) and whether each is valid (a primary ray
// `radiance` counts); the pixel each goes to in `target`. The index arithmetic in 32 bits (the
// caller checks the sizes), then the positions and directions in loops over lanes.
void SlotRays(const SlotLayout& L, const int32_t* position, int64_t begin, int64_t n, float* o, float* d,
              bool* active, bool* valid, int32_t* target, SlotScratch& t) {
  const uint32_t S = static_cast<uint32_t>(L.spp), W = static_cast<uint32_t>(L.w);
  const uint32_t H = static_cast<uint32_t>(L.h), per_eye = static_cast<uint32_t>(L.per_eye);
  const uint32_t hw = H * W;
  for (int64_t i = 0; i < n; ++i) {
    const uint32_t slot = static_cast<uint32_t>(L.order[position[begin + i]]);
    const uint32_t eye = slot >= per_eye, within = slot - eye * per_eye;  // two eyes
    const uint32_t rank = S == 1 ? within : within / S, sample = within - rank * S;
    const uint32_t pixel = static_cast<uint32_t>(L.locality[rank]);
    const uint32_t y = pixel / W, x = pixel - y * W;
    target[i] = static_cast<int32_t>(eye * hw + pixel);
    t.counter[2 * i] = ((sample * H + y) * W + x) * 2;
    t.counter[2 * i + 1] = t.counter[2 * i] + 1;
    t.eye[i] = static_cast<int32_t>(eye), t.sample[i] = static_cast<int32_t>(sample);
    t.x[i] = static_cast<float>(x), t.y[i] = static_cast<float>(y);
  }
  if (L.jitter) UniformAt(L.key[0], L.key[1], t.counter.data(), 2 * n, t.jitter.data());
  const float cells = static_cast<float>(L.cells), width = static_cast<float>(W),
              height = static_cast<float>(H);
  const float* c0 = L.cameras;
  const float* c1 = L.cameras + kCameraStride;
  for (int64_t i = 0; i < n; ++i) {
    const float* cell = L.grid + 2 * t.sample[i];
    float x = t.x[i], y = t.y[i];
    if (L.jitter) {
      x = x + (cell[0] + (t.jitter[2 * i] - 0.5f) / cells);
      y = y + (cell[1] + (t.jitter[2 * i + 1] - 0.5f) / cells);
    } else {
      x = x + cell[0];
      y = y + cell[1];
    }
    const float* c = t.eye[i] ? c1 : c0;
    const float* r = c + 3;
    const float tan_half = c[12], aspect = c[13];
    const float sx = ((2.0f * x / width - 1.0f + c[14]) * tan_half) * aspect;
    const float sy = (1.0f - 2.0f * y / height + c[15]) * tan_half;
    float raw[3];
    for (int k = 0; k < 3; ++k) raw[k] = sx * r[3 * k] + sy * r[3 * k + 1] - r[3 * k + 2];
    const float scale = 1.0f / std::sqrt(raw[0] * raw[0] + raw[1] * raw[1] + raw[2] * raw[2]);
    for (int k = 0; k < 3; ++k) raw[k] = raw[k] * scale;  // `ray_direction_components`
    const float n2 = raw[0] * raw[0] + raw[1] * raw[1] + raw[2] * raw[2];  // `normalize`
    const float inv = n2 > 0.0f ? 1.0f / std::sqrt(n2) : 0.0f;
    bool finite = true, nonzero = false;
    for (int k = 0; k < 3; ++k) {
      o[3 * i + k] = c[k];
      d[3 * i + k] = raw[k] * inv;
      finite = finite && std::isfinite(c[k]) && std::isfinite(raw[k]);
      nonzero = nonzero || d[3 * i + k] != 0.0f;
    }
    active[i] = true;
    valid[i] = finite && nonzero;
  }
}

ffi::Error WhittedSlots(ffi::ThreadPool pool, ffi::Buffer<ffi::S32> order, ffi::Buffer<ffi::S32> n_live,
                        ffi::Buffer<ffi::U32> key, ffi::Buffer<ffi::S32> locality,
                        ffi::Buffer<ffi::F32> grid, ffi::Buffer<ffi::F32> cameras, FOVJAX_SCENE_PARAMS,
                        ffi::ResultBuffer<ffi::F32> sums_out, ffi::ResultBuffer<ffi::PRED> bad_out,
                        ffi::ResultBuffer<ffi::S32> counts_out, int32_t spp, int32_t height,
                        int32_t width, int32_t jitter, int32_t max_depth, int32_t recompute,
                        int32_t packets, int32_t robust) {
  if (g_device == nullptr) return ffi::Error::Internal("fovjax Embree backend used before init");
  const int64_t hw = static_cast<int64_t>(height) * width, per_eye = hw * spp;
  int64_t cells = 1;
  while (cells * cells < spp) ++cells;
  if (spp < 1 || cells * cells != spp || height < 1 || width < 1 || 2 * per_eye >= (int64_t{1} << 31) ||
      n_live.element_count() != 1 || key.element_count() != 2 ||
      locality.element_count() != static_cast<size_t>(hw) ||
      grid.element_count() != 2 * static_cast<size_t>(spp) ||
      cameras.element_count() != 2 * static_cast<size_t>(kCameraStride) ||
      sums_out->element_count() != 6 * static_cast<size_t>(hw) ||
      bad_out->element_count() != 2 * static_cast<size_t>(hw) || counts_out->element_count() != 4) {
    return ffi::Error::InvalidArgument("fovjax slots: operand shapes do not match the image");
  }
  std::atomic<int> out_of_range{0};
  ShadeScene s;
  std::shared_ptr<NativeScene> tree;
  ffi::Error status = SceneFrom(FOVJAX_SCENE_ARGS, max_depth, recompute, robust, &out_of_range, &s, &tree);
  if (status.failure()) return status;
  const int64_t n = std::max<int64_t>(
      0, std::min<int64_t>(n_live.typed_data()[0], static_cast<int64_t>(order.element_count())));
  SlotLayout L{order.typed_data(), locality.typed_data(), grid.typed_data(), cameras.typed_data(),
               {key.typed_data()[0], key.typed_data()[1]}, jitter != 0, spp, height, width, per_eye, cells};
  for (int64_t i = 0; i < n; ++i) {
    if (L.order[i] < 0 || L.order[i] >= 2 * per_eye) {
      return ffi::Error::InvalidArgument("fovjax slots: a live slot is outside the image's samples");
    }
  }
  // Each live slot's radiance, rays traced, valid flag and pixel (scratch for the sums below).
  std::unique_ptr<float[]> radiance(new float[3 * std::max<int64_t>(n, 1)]);
  std::unique_ptr<int32_t[]> traced(new int32_t[std::max<int64_t>(n, 1)]);
  std::unique_ptr<int32_t[]> target(new int32_t[std::max<int64_t>(n, 1)]);
  std::unique_ptr<bool[]> valid(new bool[std::max<int64_t>(n, 1)]);
  // The order the slots are traced in: the live slots are two ascending runs (the mandatory
  // samples, then the optional ones, each in locality order), merged so that neighbouring
  // samples of both classes share packets; `traced_at[i]`: where slot i was traced. The sums
  // below still go in slot order.
  std::unique_ptr<int32_t[]> position(new int32_t[std::max<int64_t>(n, 1)]);
  std::unique_ptr<int32_t[]> traced_at(new int32_t[std::max<int64_t>(n, 1)]);
  {
    const int32_t* o = L.order;
    int64_t split = 1;
    while (split < n && o[split] > o[split - 1]) ++split;
    int64_t end = split + 1;
    while (end < n && o[end] > o[end - 1]) ++end;
    int64_t k = 0;
    if (split < n && end >= n) {
      int64_t a = 0, b = split;
      while (a < split && b < n) position[k++] = static_cast<int32_t>(o[a] < o[b] ? a++ : b++);
      while (a < split) position[k++] = static_cast<int32_t>(a++);
      while (b < n) position[k++] = static_cast<int32_t>(b++);
    } else {
      for (; k < n; ++k) position[k] = static_cast<int32_t>(k);
    }
    for (int64_t i = 0; i < n; ++i) traced_at[position[i]] = static_cast<int32_t>(i);
  }
  const NativeScene& t = *tree;
  const int64_t per_block = 1024;
  ParallelFor(pool, (n + per_block - 1) / per_block, [&](int64_t blk) {
    thread_local std::vector<float> o, d;
    thread_local SlotScratch scratch;
    thread_local std::unique_ptr<bool[]> active;
    o.resize(3 * per_block), d.resize(3 * per_block);
    scratch.Reserve(per_block);
    if (!active) active.reset(new bool[per_block]);
    const int64_t begin = blk * per_block, m = std::min(n, begin + per_block) - begin;
    SlotRays(L, position.get(), begin, m, o.data(), d.data(), active.get(), valid.get() + begin,
             target.get() + begin, scratch);
    BlockRays block;
    block.n = m;
    WhittedBlock(t, s, o.data(), d.data(), active.get(), block, radiance.get() + 3 * begin,
                 traced.get() + begin, packets != 0, true);
  });
  if (out_of_range.load() != 0) {
    return ffi::Error::InvalidArgument(
        "fovjax Whitted: a hit face names a vertex or a material out of range");
  }
  // The sums, per eye on its own task: every slot's radiance added to its pixel in slot order
  // (`sample_adder`: a sample whose radiance is not finite adds nothing and marks its pixel).
  float* sums = sums_out->typed_data();
  bool* bad = bad_out->typed_data();
  int64_t eye_counts[2][4] = {{0, 0, 0, 0}, {0, 0, 0, 0}};
  ParallelFor(pool, 2, [&](int64_t eye) {
    float* eye_sums = sums + 3 * eye * hw;
    bool* eye_bad = bad + eye * hw;
    std::fill(eye_sums, eye_sums + 3 * hw, 0.0f);
    std::fill(eye_bad, eye_bad + hw, false);
    const int32_t first = static_cast<int32_t>(eye * hw), last = static_cast<int32_t>(first + hw);
    int64_t primary = 0, shadow = 0, reflection = 0, n_bad = 0;
    for (int64_t i = 0; i < n; ++i) {
      const int64_t k = traced_at[i];
      const int32_t px = target[k];
      if (px < first || px >= last) continue;
      const float* rgb = radiance.get() + 3 * k;
      primary += valid[k];
      shadow += traced[k] >> 8;
      reflection += traced[k] & 255;
      if (!(std::isfinite(rgb[0]) && std::isfinite(rgb[1]) && std::isfinite(rgb[2]))) {
        eye_bad[px - first] = true;
        ++n_bad;
        continue;
      }
      float* out = sums + 3 * static_cast<int64_t>(px);
      out[0] += rgb[0], out[1] += rgb[1], out[2] += rgb[2];
    }
    eye_counts[eye][0] = primary, eye_counts[eye][1] = shadow;
    eye_counts[eye][2] = reflection, eye_counts[eye][3] = n_bad;
  });
  for (int k = 0; k < 4; ++k) counts_out->typed_data()[k] = static_cast<int32_t>(eye_counts[0][k] + eye_counts[1][k]);
  return ffi::Error::Success();
}

// ---- the foveated frame's reconstruction: pixel means, fill and blur --------------------------
//
// `fovjax.foveate._frame.pixel_means`, `_fill.fill_blanks` (every block's top-left traced) and
// `_fill.blur_and_blend` (side by side) in one pass per band of rows, on both cores: the same
// operations in the same order. Returns 0 in `complete` where some blank pixel's block top-left
// has no sample either (the caller then runs the JAX path, whose pull-push fills such blocks).

struct FillBlur {
  const float* sums;       // (2·H·W, 3)
  const int32_t* n;        // (2, H, W)
  const bool* bad;         // (2·H·W)
  const int32_t* region;   // (2, H, W)
  const float* ecc;        // (2, H, W)
  float bad_color[3];
  const float* taps;       // (2r + 1)
  int r;
  int64_t h, w;
  int64_t block[3];        // block side per region (fovea 1)
  float fovea_deg, blend_deg;
  bool blur_fovea;
  std::vector<int32_t> column_top_left;  // (3, W): x - x % block, per region
};

inline int64_t Reflect(int64_t i, int64_t n) {  // `_fill._reflect`: the edge not repeated
  i = i < 0 ? -i : i;
  return i > n - 1 ? 2 * (n - 1) - i : i;
}

// Row y of eye e's pixel means (`pixel_means`): each pixel's sum over its traced samples (at
// least one), or the bad colour. Divisions, as XLA does them (no reciprocal).
FOVJAX_VECTOR_CLONES
void MeansRow(const FillBlur& f, int64_t e, int64_t y, float* __restrict__ out) {
  const int64_t p0 = (e * f.h + y) * f.w;
  const float* __restrict__ sums = f.sums + 3 * p0;
  const int32_t* __restrict__ n = f.n + p0;
  const bool* __restrict__ bad = f.bad + p0;
  const float colour[3] = {f.bad_color[0], f.bad_color[1], f.bad_color[2]};  // locals: see SelectSamples
  const int64_t w = f.w;
  for (int64_t x = 0; x < w; ++x) {
    const float d = static_cast<float>(n[x] > 1 ? n[x] : 1);
    for (int c = 0; c < 3; ++c) out[3 * x + c] = bad[x] ? colour[c] : sums[3 * x + c] / d;
  }
}

// sum_t taps[t] * src[t][j] for j < n, summed in order (t = 0 first, as the JAX blur adds its
// terms), into out. One pass for the five taps of the 5×5 Gaussian, the sums in registers; a
// pass per tap otherwise.
FOVJAX_VECTOR_CLONES
void Taps(const float* taps, int k, const float* const* src, int64_t n, float* __restrict__ out) {
  if (k == 5) {
    const float t0 = taps[0], t1 = taps[1], t2 = taps[2], t3 = taps[3], t4 = taps[4];
    const float *__restrict__ a = src[0], *__restrict__ b = src[1], *__restrict__ c = src[2],
                *__restrict__ d = src[3], *__restrict__ e = src[4];
    for (int64_t j = 0; j < n; ++j) out[j] = t0 * a[j] + t1 * b[j] + t2 * c[j] + t3 * d[j] + t4 * e[j];
    return;
  }
  for (int64_t j = 0; j < n; ++j) out[j] = taps[0] * src[0][j];
  for (int t = 1; t < k; ++t) {
    const float tap = taps[t];
    const float* __restrict__ s = src[t];
    for (int64_t j = 0; j < n; ++j) out[j] = out[j] + tap * s[j];
  }
}

// The blend with the sharp row by weight, in place.
FOVJAX_VECTOR_CLONES
void Blend(const float* __restrict__ sharp, const float* __restrict__ weight, int64_t n, float* __restrict__ out) {
  for (int64_t j = 0; j < n; ++j) out[j] = sharp[j] * (1.0f - weight[j]) + out[j] * weight[j];
}

// The blend's smoothstep weight per pixel, repeated for its three channels: XLA's clamp (NaN
// stays NaN).
FOVJAX_VECTOR_CLONES
void BlendWeights(const float* __restrict__ ecc, int64_t w, float fovea_deg, float blend_deg,
                  float* __restrict__ out) {
  for (int64_t x = 0; x < w; ++x) {
    float t = (ecc[x] - fovea_deg) / blend_deg;
    t = t < 0.0f ? 0.0f : t;
    t = t > 1.0f ? 1.0f : t;
    const float v = t * t * (3.0f - 2.0f * t);
    out[3 * x] = v, out[3 * x + 1] = v, out[3 * x + 2] = v;
  }
}

// Rows [y0, y1) of eye e into the side-by-side image (H, 2W, 3). Rows are 3W floats (pixels'
// channels interleaved): a tap's horizontal neighbour is 3 floats away. False where a blank
// pixel's block top-left is blank too (`fill_blanks` would fill it by pull-push).
bool FillBlurRows(const FillBlur& f, int64_t e, int64_t y0, int64_t y1, float* image) {
  const int r = f.r, k = 2 * r + 1;
  const int64_t w = f.w, rows = y1 - y0, n3 = 3 * w;
  // The means of every row the band reads: its rows, r beyond (reflected) and their blocks'
  // top-left rows.
  int64_t lo = f.h, hi = 0;
  for (int64_t i = 0; i < rows + 2 * r; ++i) {
    const int64_t y = Reflect(y0 - r + i, f.h);
    lo = std::min(lo, y - y % std::max(f.block[1], f.block[2])), hi = std::max(hi, y);
  }
  thread_local std::vector<float> means, filled, padded, weight;
  means.resize(static_cast<size_t>((hi - lo + 1) * n3));
  filled.resize(static_cast<size_t>((rows + 2 * r) * n3));
  padded.resize(static_cast<size_t>(n3 + 6 * r));
  weight.resize(static_cast<size_t>(n3));
  for (int64_t y = lo; y <= hi; ++y) MeansRow(f, e, y, &means[(y - lo) * n3]);
  bool ok = true;
  const int64_t base = e * f.h * w;
  for (int64_t i = 0; i < rows + 2 * r; ++i) {  // filled (`fill_blanks`)
    const int64_t y = Reflect(y0 - r + i, f.h);
    float* row = &filled[i * n3];
    std::memcpy(row, &means[(y - lo) * n3], static_cast<size_t>(n3) * sizeof(float));
    const int32_t* n = f.n + base + y * w;
    const int32_t* reg = f.region + base + y * w;
    const int64_t top_row[3] = {y, y - y % f.block[1], y - y % f.block[2]};
    for (int64_t x = 0; x < w; ++x) {
      if (n[x] != 0) continue;
      const int c = reg[x] < 0 ? 0 : (reg[x] > 2 ? 2 : reg[x]);
      const int64_t ty = top_row[c], tx = f.column_top_left[c * w + x];
      ok &= f.n[base + ty * w + tx] != 0;
      const float* top_left = &means[(ty - lo) * n3 + 3 * tx];
      row[3 * x] = top_left[0], row[3 * x + 1] = top_left[1], row[3 * x + 2] = top_left[2];
    }
  }
  const float* window[16];
  for (int64_t i = 0; i < rows; ++i) {
    const int64_t y = y0 + i;
    for (int t = 0; t < k; ++t) window[t] = &filled[(i + t) * n3];
    float* mid = &padded[3 * r];
    Taps(f.taps, k, window, n3, mid);
    for (int64_t x = 1; x <= r; ++x)
      for (int c = 0; c < 3; ++c) {
        padded[3 * (r - x) + c] = mid[3 * Reflect(-x, w) + c];
        padded[3 * (r + w - 1 + x) + c] = mid[3 * Reflect(w - 1 + x, w) + c];
      }
    for (int t = 0; t < k; ++t) window[t] = &padded[3 * t];  // horizontal neighbours: 3 floats apart
    float* out = image + (y * 2 * w + e * w) * 3;
    Taps(f.taps, k, window, n3, out);
    if (!f.blur_fovea) {
      BlendWeights(f.ecc + (e * f.h + y) * w, w, f.fovea_deg, f.blend_deg, weight.data());
      Blend(&filled[(i + r) * n3], weight.data(), n3, out);
    }
  }
  return ok;
}

ffi::Error FillAndBlur(ffi::ThreadPool pool, ffi::Buffer<ffi::F32> sums, ffi::Buffer<ffi::S32> n,
                       ffi::Buffer<ffi::PRED> bad, ffi::Buffer<ffi::S32> region, ffi::Buffer<ffi::F32> ecc,
                       ffi::Buffer<ffi::F32> bad_color, ffi::Buffer<ffi::F32> taps,
                       ffi::Buffer<ffi::F32> fovea_deg, ffi::ResultBuffer<ffi::F32> image,
                       ffi::ResultBuffer<ffi::PRED> complete, int32_t block_periphery, int32_t block_outside,
                       float blend_deg, int32_t blur_fovea) {
  const auto dims = region.dimensions();
  if (dims.size() != 3 || dims[0] != 2) return ffi::Error::InvalidArgument("fill: regions must be (2, H, W)");
  FillBlur f;
  f.h = dims[1], f.w = dims[2];
  const size_t hw2 = static_cast<size_t>(2 * f.h * f.w);
  f.r = static_cast<int>(taps.element_count() / 2);
  if (sums.element_count() != 3 * hw2 || n.element_count() != hw2 || bad.element_count() != hw2 ||
      ecc.element_count() != hw2 || bad_color.element_count() != 3 || taps.element_count() % 2 != 1 ||
      fovea_deg.element_count() != 1 || image->element_count() != 3 * hw2 || block_periphery < 1 ||
      block_outside < 1 || f.h <= f.r || f.w <= f.r || taps.element_count() > 15) {
    return ffi::Error::InvalidArgument("fill: operand shapes do not match the regions");
  }
  f.sums = sums.typed_data(), f.n = n.typed_data(), f.bad = bad.typed_data();
  f.region = region.typed_data(), f.ecc = ecc.typed_data(), f.taps = taps.typed_data();
  for (int c = 0; c < 3; ++c) f.bad_color[c] = bad_color.typed_data()[c];
  f.block[0] = 1, f.block[1] = block_periphery, f.block[2] = block_outside;
  f.fovea_deg = fovea_deg.typed_data()[0], f.blend_deg = blend_deg;
  f.blur_fovea = blur_fovea != 0;
  f.column_top_left.resize(static_cast<size_t>(3 * f.w));
  for (int c = 0; c < 3; ++c)
    for (int64_t x = 0; x < f.w; ++x) f.column_top_left[c * f.w + x] = static_cast<int32_t>(x - x % f.block[c]);
  // Bands of 64 rows: each reads r rows beyond its ends (and the blocks' top-left rows above),
  // a few percent more with 64 rows than its own.
  const int64_t rows = 64, bands = (f.h + rows - 1) / rows;
  std::atomic<bool> ok{true};
  float* out = image->typed_data();
  ParallelFor(pool, 2 * bands, [&](int64_t job) {
    const int64_t e = job / bands, y0 = (job % bands) * rows;
    if (!FillBlurRows(f, e, y0, std::min(f.h, y0 + rows), out)) ok.store(false);
  });
  complete->typed_data()[0] = ok.load();
  return ffi::Error::Success();
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
      .template Arg<ffi::Buffer<ffi::F32>>()   // lights (L, 6)
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
                                  .Attr<int32_t>("max_depth")
                                  .Attr<int32_t>("recompute")
                                  .Attr<int32_t>("packets")
                                  .Attr<int32_t>("tile_width")  // rays an image this wide, 0
                                  .Attr<int32_t>("robust"));

XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxSelectSamples, SelectSamples,
                              ffi::Ffi::Bind()
                                  .Ctx<ffi::ThreadPool>()
                                  .Arg<ffi::Buffer<ffi::S32>>()   // regions (2, H, W)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // P(ω) per pixel (2, H, W)
                                  .Arg<ffi::Buffer<ffi::U32>>()   // each eye's key data (2, 2)
                                  .Arg<ffi::Buffer<ffi::S32>>()   // locality order of the pixels (H·W)
                                  .Arg<ffi::Buffer<ffi::S32>>()   // samples per pixel per region (3)
                                  .Arg<ffi::Buffer<ffi::S32>>()   // each sub-sample's rank (S)
                                  .Ret<ffi::Buffer<ffi::S8>>()    // classes (2, S, H, W)
                                  .Ret<ffi::Buffer<ffi::S32>>()   // compaction order (2·H·W·S)
                                  .Ret<ffi::Buffer<ffi::S32>>()   // count per class (3)
                                  .Ret<ffi::Buffer<ffi::PRED>>()  // traced (2, S, H, W)
                                  .Ret<ffi::Buffer<ffi::S32>>()   // traced per pixel (2, H, W)
                                  .Ret<ffi::Buffer<ffi::S32>>()   // traced per region (3)
                                  .Attr<int32_t>("spp")
                                  .Attr<int32_t>("rule")  // 0 either, 1 strict, 2 thesis-measured
                                  .Attr<int32_t>("block_periphery")
                                  .Attr<int32_t>("block_outside")
                                  .Attr<int64_t>("budget"));

XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxWhittedSlots, WhittedSlots,
                              WithSceneArgs(ffi::Ffi::Bind()
                                                .Ctx<ffi::ThreadPool>()
                                                .Arg<ffi::Buffer<ffi::S32>>()   // slots in compaction order (P)
                                                .Arg<ffi::Buffer<ffi::S32>>()   // live slots (1)
                                                .Arg<ffi::Buffer<ffi::U32>>()   // the frame key's data (2)
                                                .Arg<ffi::Buffer<ffi::S32>>()   // locality order (H·W)
                                                .Arg<ffi::Buffer<ffi::F32>>()   // sub-sample cell centres (S, 2)
                                                .Arg<ffi::Buffer<ffi::F32>>())  // the eyes' cameras (2, 16)
                                  .Ret<ffi::Buffer<ffi::F32>>()   // per-pixel sums (2·H·W, 3)
                                  .Ret<ffi::Buffer<ffi::PRED>>()  // bad pixel (2·H·W)
                                  .Ret<ffi::Buffer<ffi::S32>>()   // primary, shadow, reflection rays, bad samples
                                  .Attr<int32_t>("spp")
                                  .Attr<int32_t>("height")
                                  .Attr<int32_t>("width")
                                  .Attr<int32_t>("jitter")
                                  .Attr<int32_t>("max_depth")
                                  .Attr<int32_t>("recompute")
                                  .Attr<int32_t>("packets")
                                  .Attr<int32_t>("robust"));

XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxFillAndBlur, FillAndBlur,
                              ffi::Ffi::Bind()
                                  .Ctx<ffi::ThreadPool>()
                                  .Arg<ffi::Buffer<ffi::F32>>()   // per-pixel sums (2·H·W, 3)
                                  .Arg<ffi::Buffer<ffi::S32>>()   // traced samples per pixel (2, H, W)
                                  .Arg<ffi::Buffer<ffi::PRED>>()  // bad pixel (2·H·W)
                                  .Arg<ffi::Buffer<ffi::S32>>()   // regions (2, H, W)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // eccentricity (2, H, W)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the bad pixels' colour (3)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // blur taps (2r + 1)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the fovea's radius, degrees (1)
                                  .Ret<ffi::Buffer<ffi::F32>>()   // the image side by side (H, 2W, 3)
                                  .Ret<ffi::Buffer<ffi::PRED>>()  // every blank pixel filled (1)
                                  .Attr<int32_t>("block_periphery")
                                  .Attr<int32_t>("block_outside")
                                  .Attr<float>("blend_deg")
                                  .Attr<int32_t>("blur_fovea"));

extern "C" {

// Opens the Embree library at `path`, makes the device and checks the struct layout.
// Returns 0, or -1 with the reason in fovjax_embree_error().
int fovjax_embree_init(const char* path) {
  if (g_device != nullptr) return 0;
  void* lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
  if (lib == nullptr) {
    const char* why = dlerror();
    g_error = std::string("cannot open ") + path + ": " + (why ? why : "unknown error");
    return -1;
  }
  EmbreeApi api{};
  bool ok = Load(lib, "rtcNewDevice", &api.rtcNewDevice) &&
            Load(lib, "rtcGetDeviceError", &api.rtcGetDeviceError) &&
            Load(lib, "rtcGetDeviceProperty", &api.rtcGetDeviceProperty) &&
            Load(lib, "rtcNewScene", &api.rtcNewScene) &&
            Load(lib, "rtcSetSceneFlags", &api.rtcSetSceneFlags) &&
            Load(lib, "rtcSetSceneBuildQuality", &api.rtcSetSceneBuildQuality) &&
            Load(lib, "rtcAttachGeometry", &api.rtcAttachGeometry) &&
            Load(lib, "rtcCommitScene", &api.rtcCommitScene) &&
            Load(lib, "rtcReleaseScene", &api.rtcReleaseScene) &&
            Load(lib, "rtcNewGeometry", &api.rtcNewGeometry) &&
            Load(lib, "rtcSetSharedGeometryBuffer", &api.rtcSetSharedGeometryBuffer) &&
            Load(lib, "rtcCommitGeometry", &api.rtcCommitGeometry) &&
            Load(lib, "rtcReleaseGeometry", &api.rtcReleaseGeometry) &&
            Load(lib, "rtcIntersect1", &api.rtcIntersect1) &&
            Load(lib, "rtcOccluded1", &api.rtcOccluded1) &&
            Load(lib, "rtcIntersect4", &api.rtcIntersectW[0]) &&
            Load(lib, "rtcIntersect8", &api.rtcIntersectW[1]) &&
            Load(lib, "rtcIntersect16", &api.rtcIntersectW[2]) &&
            Load(lib, "rtcOccluded4", &api.rtcOccludedW[0]) &&
            Load(lib, "rtcOccluded8", &api.rtcOccludedW[1]) &&
            Load(lib, "rtcOccluded16", &api.rtcOccludedW[2]);
  if (!ok) return -1;
  g_api = api;
  RTCDevice device = g_api.rtcNewDevice(nullptr);
  if (device == nullptr) {
    g_error = "rtcNewDevice failed";
    return -1;
  }
  ptrdiff_t version = g_api.rtcGetDeviceProperty(device, kDevicePropertyVersion);
  if (version < 40000 || version >= 50000) {
    g_error = "need Embree 4, the library is version " + std::to_string(version);
    return -1;
  }
  g_device = device;
  // RTC_DEVICE_PROPERTY_NATIVE_RAY16/8/4_SUPPORTED
  g_width = g_api.rtcGetDeviceProperty(device, 34) ? 16 : g_api.rtcGetDeviceProperty(device, 33) ? 8 : 4;
  std::string why;
  if (!CheckLayout(&why)) {
    g_device = nullptr;
    g_error = why;
    return -1;
  }
  return 0;
}

const char* fovjax_embree_error() { return g_error.c_str(); }

int fovjax_embree_packet_width() { return g_width; }

long fovjax_embree_version() {
  return g_device ? static_cast<long>(g_api.rtcGetDeviceProperty(g_device, kDevicePropertyVersion)) : 0;
}

// Frees the cached scene of one BVH host id (all of them with -1). Returns how many were freed.
int fovjax_embree_release(int32_t id) {
  std::lock_guard<std::mutex> lock(g_scenes_mutex);
  if (id < 0) {
    int n = static_cast<int>(g_scenes.size());
    g_scenes.clear();
    return n;
  }
  return static_cast<int>(g_scenes.erase(SceneKey(id, true)) + g_scenes.erase(SceneKey(id, false)));
}

int fovjax_embree_cached_scenes() {
  std::lock_guard<std::mutex> lock(g_scenes_mutex);
  return static_cast<int>(g_scenes.size());
}

}  // extern "C"
