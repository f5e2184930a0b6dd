// fovjax's native handlers: one shared library, built as one translation unit from the sources of
// the packages that own each stage (fovjax/native/_library.py compiles this file with the package
// directory on the include path). Each stage's JAX implementation is its oracle and its derivative:
//
//   native/csrc/     Embree declarations and their layout check, the scene cache, the thread pool,
//                    JAX's threefry2x32 uniforms (threefry.h),
//                    the layout shared with Python (layout.h), and the library's C entry points
//   trace/           ray queries (_embree_queries.cc)
//   render/          the Whitted integrator and its shading (_whitted.cc), its adjoint in the
//                    shading parameters (_whitted_adjoint.cc), the full frame from its cameras
//                    (_frame.cc)
//   foveate/         sample selection with JAX's threefry (_select.cc), the slots integrator
//                    (_slots.cc), pixel means, fill and blur (_fill.cc), Patney 2016's history
//                    blend (_taa.cc) and pre-filters with the rates' blend (_prefilter.cc),
//                    Guenter 2012's layers (_layers.cc)
//
// Embree itself is the shared library inside the `embreex` wheel, opened with dlopen at run time.

#include "native/csrc/common.h"
#include "native/csrc/embree.h"
#include "native/csrc/embree_check.h"
#include "native/csrc/layout.h"
#include "native/csrc/scene_cache.h"
#include "native/csrc/thread_pool.h"

#include "trace/_embree_queries.cc"
#include "render/_whitted.cc"
#include "render/_whitted_adjoint.cc"
#include "render/_frame.cc"
#include "foveate/_select.cc"
#include "foveate/_slots.cc"
#include "foveate/_fill.cc"
#include "foveate/_taa.cc"
#include "foveate/_prefilter.cc"
#include "foveate/_layers.cc"

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


// The layout of layout.h as `name=value` pairs separated by ";", for the loader to compare with
// the Python side's (fovjax/native/_layout.py).
const char* fovjax_native_layout() {
  static const std::string text =
      "material_stride=" + std::to_string(kMaterialStride) + ";light_stride=" + std::to_string(kLightStride) +
      ";light_point=" + std::to_string(kLightPoint) + ";light_directional=" + std::to_string(kLightDirectional) +
      ";light_spot=" + std::to_string(kLightSpot) + ";specular_blinn_phong=" + std::to_string(kSpecularBlinnPhong) +
      ";specular_phong=" + std::to_string(kSpecularPhong) +
      ";camera_stride=" + std::to_string(kCameraStride) + ";region_fovea=" + std::to_string(kFovea) +
      ";region_periphery=" + std::to_string(kPeriphery) + ";region_outside=" + std::to_string(kOutside) +
      ";class_mandatory=" + std::to_string(kMandatory) + ";class_optional=" + std::to_string(kOptional) +
      ";class_skipped=" + std::to_string(kSkipped) + ";rule_either=" + std::to_string(kRuleEither) +
      ";rule_strict=" + std::to_string(kRuleStrict) +
      ";rule_thesis_measured=" + std::to_string(kRuleThesisMeasured) +
      ";rule_pixel_mask=" + std::to_string(kRulePixelMask) +
      ";shadows_all=" + std::to_string(kShadowsAll) + ";shadows_brightest=" + std::to_string(kShadowsBrightest) +
      ";shadows_none=" + std::to_string(kShadowsNone) + ";adjoint_ka=" + std::to_string(kAdjointKa) +
      ";adjoint_kd=" + std::to_string(kAdjointKd) + ";adjoint_ks=" + std::to_string(kAdjointKs) +
      ";adjoint_ke=" + std::to_string(kAdjointKe) + ";adjoint_kr=" + std::to_string(kAdjointKr) +
      ";adjoint_ns=" + std::to_string(kAdjointNs) + ";adjoint_light_color=" + std::to_string(kAdjointLightColor) +
      ";adjoint_ambient=" + std::to_string(kAdjointAmbient) + ";path_not_traced=" + std::to_string(kPathNotTraced) + ";scene_operands=" + kSceneOperands;
  return text.c_str();
}

}  // extern "C"
