// Embree scenes built from the geometry a call receives (one scene per tree of a merged
// level-of-detail BVH), cached by the BVH's host id: the frame program needs no Python call to
// set them up; `fovjax_embree_release` frees them.
#pragma once

#include "native/csrc/embree.h"

namespace {

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

}  // namespace
