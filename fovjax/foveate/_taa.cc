// Temporal antialiasing with variance clipping (its oracle: fovjax/foveate/_methods/_patney.py
// `taa_blend`, Patney 2016's history blend).
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

// Per element: the 3×3 neighbourhood's mean and standard deviation of `current` (its border
// pixels repeated), the history clipped to mean ± gamma·std widened to the current value, then
// alpha of the current value and `keep` (1 − alpha, as Python rounds it) of the clipped history;
// where the history holds nothing, the current value. The taps are added row by row, left to
// right, as the JAX neighbourhood adds its slices.
ffi::Error TaaBlend(ffi::ThreadPool pool, ffi::Buffer<ffi::F32> current, ffi::Buffer<ffi::F32> history,
                    ffi::Buffer<ffi::PRED> valid, ffi::ResultBuffer<ffi::F32> out, float alpha, float keep,
                    float gamma) {
  const auto dims = current.dimensions();
  if (dims.size() != 4) return ffi::Error::InvalidArgument("taa: the image must be (N, H, W, C)");
  const int64_t n = dims[0], h = dims[1], w = dims[2], c = dims[3];
  const size_t size = current.element_count();
  if (history.element_count() != size || valid.element_count() * c != size || out->element_count() != size ||
      h < 1 || w < 1 || c < 1) {
    return ffi::Error::InvalidArgument("taa: a history of the image's shape and a flag per pixel");
  }
  const float* img = current.typed_data();
  const float* hist = history.typed_data();
  const bool* has = valid.typed_data();
  float* dst = out->typed_data();
  const int64_t row = w * c, rows = 16, bands = (h + rows - 1) / rows;
  ParallelFor(pool, n * bands, [&](int64_t job) {
    const int64_t e = job / bands, y0 = (job % bands) * rows, y1 = std::min(h, y0 + rows);
    const float* image = img + e * h * row;
    // The three rows a row reads, each with its edge pixels repeated once on either side: the
    // nine taps are then rows, and the blend a loop along them that vectorises.
    std::vector<float> padded(static_cast<size_t>(3 * (row + 2 * c)));
    for (int64_t y = y0; y < y1; ++y) {
      const float* tap[9];
      for (int dy = 0; dy < 3; ++dy) {
        const float* line = image + std::clamp<int64_t>(y + dy - 1, 0, h - 1) * row;
        float* p = padded.data() + dy * (row + 2 * c);
        std::copy(line, line + c, p);
        std::copy(line, line + row, p + c);
        std::copy(line + row - c, line + row, p + c + row);
        for (int dx = 0; dx < 3; ++dx) tap[3 * dy + dx] = p + dx * c;
      }
      const int64_t at = (e * h + y) * row;
      BlendRow(tap, img + at, hist + at, row, alpha, keep, gamma, dst + at);
      // The current value where the pixel holds no history (eight flags at a time: most hold one).
      const bool* held = has + (e * h + y) * w;
      for (int64_t x0 = 0; x0 < w; x0 += 8) {
        const int64_t x1 = std::min<int64_t>(w, x0 + 8);
        uint64_t all = 0;
        if (x1 - x0 == 8) std::memcpy(&all, held + x0, sizeof all);
        if (x1 - x0 == 8 && all == 0x0101010101010101ull) continue;
        for (int64_t x = x0; x < x1; ++x) {
          if (!held[x]) std::copy(img + at + x * c, img + at + (x + 1) * c, dst + at + x * c);
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
                                  .Arg<ffi::Buffer<ffi::F32>>()   // this frame (N, H, W, C)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the history's colour (N, H, W, C)
                                  .Arg<ffi::Buffer<ffi::PRED>>()  // whether a pixel holds one (N, H, W)
                                  .Ret<ffi::Buffer<ffi::F32>>()   // blended (N, H, W, C)
                                  .Attr<float>("alpha")
                                  .Attr<float>("keep")
                                  .Attr<float>("gamma"));
