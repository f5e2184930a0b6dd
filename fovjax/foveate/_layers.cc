// Guenter 2012's three layers magnified and blended (its oracle: fovjax/foveate/_methods/
// _guenter.py `composite`: `magnify`, `layer_weights` and the blend).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "native/csrc/thread_pool.h"

namespace {

struct Layers {
  const float* pix;  // (2, H, W, 3): each traced pixel's mean
  const float* ecc;  // (2, H, W)
  int64_t h, w;
  int32_t stride[2];  // the middle and outer layers' grids
  float radius[2];    // the inner and middle layers' radii (degrees)
  float blend_deg;
};

// Where a pixel reads a layer of grid `stride` along an axis of `n` pixels: the grid pixels
// before (`lo`) and after (`hi`, the last where there is none), as pixel indices, and the
// fraction between them, as `magnify` computes them (float32 k / stride).
struct Tap {
  int64_t lo, hi;
  float f;
};

inline Tap TapAt(int64_t k, int32_t stride, int64_t n) {
  const float g = static_cast<float>(k) / static_cast<float>(stride);
  const float floor_g = std::floor(g);
  const int64_t cells = (n + stride - 1) / stride;
  const int64_t i0 = static_cast<int64_t>(floor_g);
  const int64_t i1 = std::min<int64_t>(i0 + 1, cells - 1);
  return {i0 * stride, i1 * stride, g - floor_g};
}

// 1 − smoothstep((ecc − radius) / blend): the finer layer's weight at a layer's edge.
inline float FinerWeight(float ecc, float radius, float blend_deg) {
  float t = (ecc - radius) / blend_deg;
  t = t < 0.0f ? 0.0f : (t > 1.0f ? 1.0f : t);
  return 1.0f - t * t * (3.0f - 2.0f * t);
}

// Rows y0..y1 of eye `e`, as `magnify` computes a layer: first the grid's two rows around the
// pixel row blended at each grid column (`below`), then those blended between the two grid
// columns around each pixel (`columns`: per layer, a tap per pixel column).
void LayerRows(const Layers& g, const std::vector<Tap>* columns, int64_t e, int64_t y0, int64_t y1,
               float* out) {
  const int64_t w = g.w;
  const float* img = g.pix + e * g.h * w * 3;
  std::vector<float> below[2] = {std::vector<float>(static_cast<size_t>(3 * w)),
                                 std::vector<float>(static_cast<size_t>(3 * w))};
  std::vector<float> w_inner(static_cast<size_t>(w)), w_middle(static_cast<size_t>(w));
  for (int64_t y = y0; y < y1; ++y) {
    for (int layer = 0; layer < 2; ++layer) {
      const int32_t stride = g.stride[layer];
      if (stride == 1) continue;
      const Tap ty = TapAt(y, stride, g.h);
      const float* top = img + ty.lo * w * 3;
      const float* bottom = img + ty.hi * w * 3;
      float* row = below[layer].data();
      for (int64_t x = 0; x < w; x += stride) {
        for (int c = 0; c < 3; ++c) row[3 * x + c] = top[3 * x + c] * (1.0f - ty.f) + bottom[3 * x + c] * ty.f;
      }
    }
    const float* ecc = g.ecc + (e * g.h + y) * w;
    for (int64_t x = 0; x < w; ++x) {
      w_inner[x] = FinerWeight(ecc[x], g.radius[0], g.blend_deg);
      w_middle[x] = FinerWeight(ecc[x], g.radius[1], g.blend_deg);
    }
    const float* pixel = img + y * w * 3;
    float* dst = out + (y * 2 * w + e * w) * 3;  // both eyes side by side
    for (int64_t x = 0; x < w; ++x) {
      float layer_at[2][3];
      for (int layer = 0; layer < 2; ++layer) {
        const Tap& tx = columns[layer][x];
        const float* row = below[layer].data();
        for (int c = 0; c < 3; ++c) {
          layer_at[layer][c] = g.stride[layer] == 1
                                   ? pixel[3 * x + c]
                                   : row[3 * tx.lo + c] * (1.0f - tx.f) + row[3 * tx.hi + c] * tx.f;
        }
      }
      for (int c = 0; c < 3; ++c) {
        const float inner = pixel[3 * x + c], middle = layer_at[0][c], outer = layer_at[1][c];
        const float coarse = outer * (1.0f - w_middle[x]) + middle * w_middle[x];
        dst[3 * x + c] = coarse * (1.0f - w_inner[x]) + inner * w_inner[x];
      }
    }
  }
}

ffi::Error LayerBlend(ffi::ThreadPool pool, ffi::Buffer<ffi::F32> pix, ffi::Buffer<ffi::F32> ecc,
                      ffi::Buffer<ffi::F32> radii, ffi::ResultBuffer<ffi::F32> out, int32_t middle_stride,
                      int32_t outer_stride, float blend_deg) {
  const auto dims = pix.dimensions();
  if (dims.size() != 4 || dims[0] != 2 || dims[3] != 3) {
    return ffi::Error::InvalidArgument("layers: the layers' pixels must be (2, H, W, 3)");
  }
  Layers g;
  g.pix = pix.typed_data();
  g.ecc = ecc.typed_data();
  g.h = dims[1];
  g.w = dims[2];
  if (g.h < 1 || g.w < 1 || ecc.element_count() != static_cast<size_t>(2 * g.h * g.w) ||
      radii.element_count() != 2 || out->element_count() != pix.element_count() || middle_stride < 1 ||
      outer_stride < 1 || !(blend_deg > 0.0f)) {
    return ffi::Error::InvalidArgument(
        "layers: eccentricities per pixel, two radii, strides >= 1, a blend > 0");
  }
  g.stride[0] = middle_stride;
  g.stride[1] = outer_stride;
  g.radius[0] = radii.typed_data()[0];
  g.radius[1] = radii.typed_data()[1];
  g.blend_deg = blend_deg;
  float* dst = out->typed_data();
  std::vector<Tap> columns[2];
  for (int layer = 0; layer < 2; ++layer) {
    for (int64_t x = 0; x < g.w; ++x) columns[layer].push_back(TapAt(x, g.stride[layer], g.w));
  }
  const int64_t rows = 16, bands = (g.h + rows - 1) / rows;
  ParallelFor(pool, 2 * bands, [&](int64_t job) {
    const int64_t e = job / bands, y0 = (job % bands) * rows;
    LayerRows(g, columns, e, y0, std::min(g.h, y0 + rows), dst);
  });
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxLayerBlend, LayerBlend,
                              ffi::Ffi::Bind()
                                  .Ctx<ffi::ThreadPool>()
                                  .Arg<ffi::Buffer<ffi::F32>>()  // each pixel's mean (2, H, W, 3)
                                  .Arg<ffi::Buffer<ffi::F32>>()  // eccentricities (2, H, W)
                                  .Arg<ffi::Buffer<ffi::F32>>()  // the layers' radii (2,): inner, middle
                                  .Ret<ffi::Buffer<ffi::F32>>()  // both eyes side by side (H, 2W, 3)
                                  .Attr<int32_t>("middle_stride")
                                  .Attr<int32_t>("outer_stride")
                                  .Attr<float>("blend_deg"));
