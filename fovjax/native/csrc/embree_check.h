// The Embree library's struct layout, checked at init by tracing one triangle into structs
// surrounded by guard bytes.
#pragma once

#include "native/csrc/scene_cache.h"

namespace {

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

}  // namespace
