// Weier et al. 2016's forward projection of the previous frame's samples (its oracle:
// fovjax/foveate/_methods/_weier.py `reproject`, with `Camera.project`).
#pragma once

#include <cmath>
#include <limits>

#include "native/csrc/layout.h"
#include "native/csrc/thread_pool.h"

namespace {

// One eye: every valid sample's world point projected into the eye's camera (`Camera.project`:
// the same operations in the same order, each rounded as XLA rounds it), the nearest per pixel
// kept (a z-buffer), the lowest source index among equal depths, so the result does not depend
// on any order; then the winners' colours and points gathered. Samples behind the camera, off
// the image or of a depth that is not finite land nowhere.
void ReprojectEye(const float* camera, const float* color, const float* point, const bool* valid, int64_t h,
                  int64_t w, float half_width, float half_height, float* out_color, float* out_point,
                  float* out_depth, bool* out_landed, std::vector<float>& zbuf, std::vector<int32_t>& pick) {
  const int64_t n = h * w;
  const float px = camera[0], py = camera[1], pz = camera[2];
  const float* r = camera + 3;  // row-major: r[3 * i + j]
  const float tan_half = camera[12], aspect = camera[13], off_x = camera[14], off_y = camera[15];
  const float inf = std::numeric_limits<float>::infinity();
  const float tan_aspect = tan_half * aspect;
  zbuf.assign(static_cast<size_t>(n), inf);
  pick.assign(static_cast<size_t>(n), static_cast<int32_t>(n));
  std::vector<int32_t> target(static_cast<size_t>(n), -1);
  std::vector<float> depths(static_cast<size_t>(n));
  for (int64_t i = 0; i < n; ++i) {
    if (!valid[i]) continue;
    const float rx = point[3 * i] - px, ry = point[3 * i + 1] - py, rz = point[3 * i + 2] - pz;
    float pc[3];
    for (int j = 0; j < 3; ++j) pc[j] = rx * r[j] + ry * r[3 + j] + rz * r[6 + j];
    const float depth = -pc[2];
    const float sx = pc[0] / depth, sy = pc[1] / depth;
    const float x = half_width * (sx / tan_aspect - off_x + 1.0f);
    const float y = half_height * (1.0f + off_y - sy / tan_half);
    const float col = std::floor(x), row = std::floor(y);
    const bool ok = depth > 0.0f && col >= 0.0f && col < static_cast<float>(w) && row >= 0.0f &&
                    row < static_cast<float>(h) && std::isfinite(depth);
    if (!ok) continue;
    const int32_t t = static_cast<int32_t>(row) * static_cast<int32_t>(w) + static_cast<int32_t>(col);
    target[i] = t, depths[i] = depth;
    if (depth < zbuf[t]) zbuf[t] = depth;
  }
  for (int64_t i = 0; i < n; ++i) {  // ascending: the first winner is the lowest index
    const int32_t t = target[i];
    if (t >= 0 && depths[i] == zbuf[t] && pick[t] == n) pick[t] = static_cast<int32_t>(i);
  }
  for (int64_t p = 0; p < n; ++p) {
    const bool landed = pick[p] < n;
    const int64_t s = landed ? pick[p] : n - 1;
    for (int c = 0; c < 3; ++c) {
      out_color[3 * p + c] = color[3 * s + c];
      out_point[3 * p + c] = point[3 * s + c];
    }
    out_depth[p] = landed ? zbuf[p] : inf;
    out_landed[p] = landed;
  }
}

ffi::Error Reproject(ffi::ThreadPool pool, ffi::Buffer<ffi::F32> color, ffi::Buffer<ffi::F32> point,
                     ffi::Buffer<ffi::PRED> valid, ffi::Buffer<ffi::F32> cameras,
                     ffi::ResultBuffer<ffi::F32> out_color, ffi::ResultBuffer<ffi::F32> out_point,
                     ffi::ResultBuffer<ffi::F32> out_depth, ffi::ResultBuffer<ffi::PRED> out_landed,
                     float half_width, float half_height) {
  const auto dims = valid.dimensions();
  if (dims.size() != 3 || dims[0] != 2) return ffi::Error::InvalidArgument("reproject: valid must be (2, H, W)");
  const int64_t h = dims[1], w = dims[2], n = h * w;
  if (color.element_count() != static_cast<size_t>(6 * n) || point.element_count() != static_cast<size_t>(6 * n) ||
      cameras.element_count() != static_cast<size_t>(2 * kCameraStride) || n >= (int64_t{1} << 31)) {
    return ffi::Error::InvalidArgument("reproject: operand shapes do not match the (2, H, W) mask");
  }
  ParallelFor(pool, 2, [&](int64_t e) {
    std::vector<float> zbuf;
    std::vector<int32_t> pick;
    ReprojectEye(cameras.typed_data() + e * kCameraStride, color.typed_data() + 3 * e * n,
                 point.typed_data() + 3 * e * n, valid.typed_data() + e * n, h, w, half_width, half_height,
                 out_color->typed_data() + 3 * e * n, out_point->typed_data() + 3 * e * n,
                 out_depth->typed_data() + e * n, out_landed->typed_data() + e * n, zbuf, pick);
  });
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxReproject, Reproject,
                              ffi::Ffi::Bind()
                                  .Ctx<ffi::ThreadPool>()
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the history's colours (2, H, W, 3)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the history's points (2, H, W, 3)
                                  .Arg<ffi::Buffer<ffi::PRED>>()  // which pixels hold a sample (2, H, W)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // this frame's cameras (2, kCameraStride)
                                  .Ret<ffi::Buffer<ffi::F32>>()   // colour landed per pixel (2, H, W, 3)
                                  .Ret<ffi::Buffer<ffi::F32>>()   // point landed per pixel (2, H, W, 3)
                                  .Ret<ffi::Buffer<ffi::F32>>()   // its depth, inf where none (2, H, W)
                                  .Ret<ffi::Buffer<ffi::PRED>>()  // whether a sample landed (2, H, W)
                                  .Attr<float>("half_width")
                                  .Attr<float>("half_height"));
