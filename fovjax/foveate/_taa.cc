// Temporal antialiasing with variance clipping (its oracle: fovjax/foveate/_methods/_patney.py
// `taa_blend`, Patney 2016's history blend), of an image or of the shading rates' blend of a
// frame's pixels (`shade_and_blend_history`: `rate_blend` of `hold`'s images, then `taa_blend`).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "native/csrc/thread_pool.h"

namespace {

// Along a row: the nine taps' sum and sum of squares (added in the taps' order, in registers),
// the clip box from them, the history clipped to it and blended. The comparisons are
// jnp.minimum's and jnp.maximum's.
FOVJAX_VECTOR_CLONES
void BlendRow(const float* const* tap, const float* __restrict__ now, const float* __restrict__ before, int64_t n,
              float alpha, float keep, float gamma, float* __restrict__ result) {
  const float *__restrict__ t0 = tap[0], *__restrict__ t1 = tap[1], *__restrict__ t2 = tap[2];
  const float *__restrict__ t3 = tap[3], *__restrict__ t4 = tap[4], *__restrict__ t5 = tap[5];
  const float *__restrict__ t6 = tap[6], *__restrict__ t7 = tap[7], *__restrict__ t8 = tap[8];
  for (int64_t j = 0; j < n; ++j) {
    float sum = t0[j], squares = t0[j] * t0[j];
    sum = sum + t1[j], squares = squares + t1[j] * t1[j];
    sum = sum + t2[j], squares = squares + t2[j] * t2[j];
    sum = sum + t3[j], squares = squares + t3[j] * t3[j];
    sum = sum + t4[j], squares = squares + t4[j] * t4[j];
    sum = sum + t5[j], squares = squares + t5[j] * t5[j];
    sum = sum + t6[j], squares = squares + t6[j] * t6[j];
    sum = sum + t7[j], squares = squares + t7[j] * t7[j];
    sum = sum + t8[j], squares = squares + t8[j] * t8[j];
    const float mean = sum / 9.0f;
    const float var = squares / 9.0f - mean * mean;
    const float std = std::sqrt(var > 0.0f ? var : 0.0f);
    const float x = now[j], low = mean - gamma * std, high = mean + gamma * std;
    const float lo = low < x ? low : x;
    const float hi = high > x ? high : x;
    const float above = before[j] > lo ? before[j] : lo;
    const float clipped = above < hi ? above : hi;
    result[j] = alpha * x + keep * clipped;
  }
}

// Row y of the shaded image (`rate_blend` of `hold`'s images, in its order): per pixel its own
// value (fine), its middle block's and its outer block's top-left's (middle, coarse), rest =
// coarse·(1 − w_middle) + middle·w_middle, then rest·(1 − w_inner) + fine·w_inner.
struct RateShading {
  const float* pix;                        // (N, H, W, C)
  const float *w_inner, *w_middle;         // (N, H, W)
  int64_t h, w, c, middle_stride, outer_stride;
  std::vector<int32_t> middle_x, outer_x;  // per column: its blocks' left column
};

void ShadeRow(const RateShading& s, int64_t e, int64_t y, float* __restrict__ out) {
  const int64_t w = s.w, c = s.c;
  const float* fine = s.pix + (e * s.h + y) * w * c;
  const float* middle = s.pix + (e * s.h + y - y % s.middle_stride) * w * c;
  const float* coarse = s.pix + (e * s.h + y - y % s.outer_stride) * w * c;
  const float* a = s.w_inner + (e * s.h + y) * w;
  const float* b = s.w_middle + (e * s.h + y) * w;
  const int32_t* mx = s.middle_x.data();
  const int32_t* ox = s.outer_x.data();
  for (int64_t x = 0; x < w; ++x) {
    for (int64_t ch = 0; ch < c; ++ch) {
      const float rest = coarse[ox[x] * c + ch] * (1.0f - b[x]) + middle[mx[x] * c + ch] * b[x];
      out[x * c + ch] = rest * (1.0f - a[x]) + fine[x * c + ch] * a[x];
    }
  }
}

// Per element: the 3×3 neighbourhood's mean and standard deviation of the current image (its
// border pixels repeated), the history clipped to mean ± gamma·std widened to the current value,
// then alpha of the current value and `keep` (1 − alpha, as Python rounds it) of the clipped
// history; where the history holds nothing, the current value. The taps are added row by row,
// left to right, as the JAX neighbourhood adds its slices. The current image is `current`, or
// with the rates' weights given (not empty), the shaded image of `current`'s pixels
// (`ShadeRow`), each of its rows made once per band.
ffi::Error TaaBlend(ffi::ThreadPool pool, ffi::Buffer<ffi::F32> current, ffi::Buffer<ffi::F32> w_inner,
                    ffi::Buffer<ffi::F32> w_middle, ffi::Buffer<ffi::F32> history, ffi::Buffer<ffi::PRED> valid,
                    ffi::ResultBuffer<ffi::F32> out, float alpha, float keep, float gamma, int32_t middle_stride,
                    int32_t outer_stride) {
  const auto dims = current.dimensions();
  if (dims.size() != 4) return ffi::Error::InvalidArgument("taa: the image must be (N, H, W, C)");
  const int64_t n = dims[0], h = dims[1], w = dims[2], c = dims[3];
  const size_t size = current.element_count();
  if (history.element_count() != size || valid.element_count() * c != size || out->element_count() != size ||
      h < 1 || w < 1 || c < 1) {
    return ffi::Error::InvalidArgument("taa: a history of the image's shape and a flag per pixel");
  }
  const bool shade = w_inner.element_count() != 0;
  if (shade && (w_inner.element_count() != valid.element_count() ||
                w_middle.element_count() != valid.element_count() || middle_stride < 1 || outer_stride < 1)) {
    return ffi::Error::InvalidArgument("taa: the rates' weights are (N, H, W) and their strides positive");
  }
  RateShading shading{current.typed_data(), w_inner.typed_data(), w_middle.typed_data(), h, w, c,
                  middle_stride, outer_stride, {}, {}};
  if (shade) {
    shading.middle_x.resize(static_cast<size_t>(w)), shading.outer_x.resize(static_cast<size_t>(w));
    for (int64_t x = 0; x < w; ++x) {
      shading.middle_x[x] = static_cast<int32_t>(x - x % middle_stride);
      shading.outer_x[x] = static_cast<int32_t>(x - x % outer_stride);
    }
  }
  const float* img = current.typed_data();
  const float* hist = history.typed_data();
  const bool* has = valid.typed_data();
  float* dst = out->typed_data();
  const int64_t row = w * c, padded_row = row + 2 * c, rows = 16, bands = (h + rows - 1) / rows;
  ParallelFor(pool, n * bands, [&](int64_t job) {
    const int64_t e = job / bands, y0 = (job % bands) * rows, y1 = std::min(h, y0 + rows);
    // The current image's rows the band reads (its own and one on either side, clamped), each
    // with its edge pixels repeated once on either side: the nine taps are then rows, and the
    // blend a loop along them that vectorises.
    const int64_t r0 = std::max<int64_t>(0, y0 - 1), r1 = std::min(h, y1 + 1);
    std::vector<float> padded(static_cast<size_t>((r1 - r0) * padded_row));
    for (int64_t y = r0; y < r1; ++y) {
      float* p = padded.data() + (y - r0) * padded_row;
      if (shade) {
        ShadeRow(shading, e, y, p + c);
      } else {
        const float* line = img + (e * h + y) * row;
        std::copy(line, line + row, p + c);
      }
      std::copy(p + c, p + 2 * c, p);
      std::copy(p + row, p + c + row, p + c + row);
    }
    for (int64_t y = y0; y < y1; ++y) {
      const float* tap[9];
      for (int dy = 0; dy < 3; ++dy) {
        const float* p = padded.data() + (std::clamp<int64_t>(y + dy - 1, 0, h - 1) - r0) * padded_row;
        for (int dx = 0; dx < 3; ++dx) tap[3 * dy + dx] = p + dx * c;
      }
      const float* now = tap[4];
      const int64_t at = (e * h + y) * row;
      BlendRow(tap, now, hist + at, row, alpha, keep, gamma, dst + at);
      // The current value where the pixel holds no history (eight flags at a time: most hold one).
      const bool* held = has + (e * h + y) * w;
      for (int64_t x0 = 0; x0 < w; x0 += 8) {
        const int64_t x1 = std::min<int64_t>(w, x0 + 8);
        uint64_t all = 0;
        if (x1 - x0 == 8) std::memcpy(&all, held + x0, sizeof all);
        if (x1 - x0 == 8 && all == 0x0101010101010101ull) continue;
        for (int64_t x = x0; x < x1; ++x) {
          if (!held[x]) std::copy(now + x * c, now + (x + 1) * c, dst + at + x * c);
        }
      }
    }
  });
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxTaaBlend, TaaBlend,
                              ffi::Ffi::Bind()
                                  .Ctx<ffi::ThreadPool>()
                                  .Arg<ffi::Buffer<ffi::F32>>()   // this frame, or its pixels to shade (N, H, W, C)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the inner rate's weight (N, H, W), or empty
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the middle rate's weight (N, H, W), or empty
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the history's colour (N, H, W, C)
                                  .Arg<ffi::Buffer<ffi::PRED>>()  // whether a pixel holds one (N, H, W)
                                  .Ret<ffi::Buffer<ffi::F32>>()   // blended (N, H, W, C)
                                  .Attr<float>("alpha")
                                  .Attr<float>("keep")
                                  .Attr<float>("gamma")
                                  .Attr<int32_t>("middle_stride")
                                  .Attr<int32_t>("outer_stride"));
