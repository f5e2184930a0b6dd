// Embree 4 declarations, written from Embree 4.4's documented C API (the library is the one
// inside the `embreex` wheel, opened with dlopen at run time; it ships no headers). The layout
// of the ray structs is checked against the library at init (embree_check.h).
#pragma once

#include "native/csrc/common.h"

namespace {

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

}  // namespace
