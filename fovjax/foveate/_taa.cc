// Patney 2016's shading rates blended and temporal antialiasing with variance clipping (its
// oracle: fovjax/foveate/_methods/_patney.py `rates_and_history`).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include "native/csrc/thread_pool.h"

namespace {

// Along a row: the nine taps' sum and sum of squares (added in the taps' order, in registers),
// the clip box from them, the history clipped to it and blended. The comparisons are
// jnp.minimum's and jnp.maximum's.
// A band's rows, one set per thread (`ThreadLocal`), kept from call to call.
struct TaaBandBuffers {
  std::vector<float> shaded, middle_row, coarse_row;
};

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

// A rate's row as it shows: each pixel (3 channels) its block's top-left pixel of `src`, the
// blocks `stride` pixels wide.
void HeldRow(const float* __restrict__ src, int64_t stride, int64_t w, float* __restrict__ out) {
  for (int64_t x0 = 0; x0 < w; x0 += stride) {
    const float v0 = src[3 * x0], v1 = src[3 * x0 + 1], v2 = src[3 * x0 + 2];
    for (int64_t x = x0; x < std::min(w, x0 + stride); ++x) out[3 * x] = v0, out[3 * x + 1] = v1, out[3 * x + 2] = v2;
  }
}

// One row of the shading rates' blend (`rate_blend`'s arithmetic in its order) from the rows as
// they show (`HeldRow`): rest = coarse·(1 − w_middle) + middle·w_middle, then rest·(1 − w_inner)
// + fine·w_inner, into `out` with its edge pixels repeated once on either side (the
// neighbourhood's taps are then rows).
FOVJAX_VECTOR_CLONES
void ShadeRow(const float* __restrict__ fine, const float* __restrict__ middle, const float* __restrict__ coarse,
              const float* __restrict__ a, const float* __restrict__ b, int64_t w, float* __restrict__ out) {
  float* __restrict__ row = out + 3;
  for (int64_t x = 0; x < w; ++x) {
    for (int ch = 0; ch < 3; ++ch) {
      const float rest = coarse[3 * x + ch] * (1.0f - b[x]) + middle[3 * x + ch] * b[x];
      row[3 * x + ch] = rest * (1.0f - a[x]) + fine[3 * x + ch] * a[x];
    }
  }
  for (int ch = 0; ch < 3; ++ch) out[ch] = row[ch], row[3 * w + ch] = row[3 * (w - 1) + ch];
}

// Per element: this frame's image, the shading rates' blend of `pixels` (`ShadeRow`), then
// the 3×3 neighbourhood's mean and standard deviation of it (its border pixels repeated), the
// history clipped to mean ± gamma·std widened to the current value, then alpha of the current
// value and `keep` (1 − alpha, as Python rounds it) of the clipped history; where the history
// holds nothing, the current value. The taps are added row by row, left to right, as the JAX
// neighbourhood adds its slices. In bands of rows, one per task: a band blends the rates' rows
// it reads once (one row more on either side), then its rows.
ffi::Error TaaBlend(ffi::ThreadPool pool, ffi::Buffer<ffi::F32> pixels, ffi::Buffer<ffi::F32> w_inner,
                    ffi::Buffer<ffi::F32> w_middle, ffi::Buffer<ffi::F32> history, ffi::Buffer<ffi::PRED> valid,
                    ffi::ResultBuffer<ffi::F32> out, float alpha, float keep, float gamma, int64_t middle_stride,
                    int64_t coarse_stride) {
  const auto dims = pixels.dimensions();
  if (dims.size() != 4 || dims[3] != 3) return ffi::Error::InvalidArgument("taa: the pixels must be (N, H, W, 3)");
  const int64_t n = dims[0], h = dims[1], w = dims[2], c = dims[3];
  const size_t size = pixels.element_count();
  if (history.element_count() != size || valid.element_count() * c != size || out->element_count() != size ||
      w_inner.element_count() * c != size || w_middle.element_count() * c != size || h < 1 || w < 1 || c < 1) {
    return ffi::Error::InvalidArgument("taa: a history of the image's shape, weights and a flag per pixel");
  }
  if (middle_stride < 1 || coarse_stride < 1) return ffi::Error::InvalidArgument("taa: strides of at least 1");
  const float* pix = pixels.typed_data();
  const float* wi = w_inner.typed_data();
  const float* wm = w_middle.typed_data();
  const float* hist = history.typed_data();
  const bool* has = valid.typed_data();
  float* dst = out->typed_data();
  const int64_t row = w * c, span = row + 2 * c, rows = 16, bands = (h + rows - 1) / rows;
  ParallelFor(pool, n * bands, [&](int64_t job) {
    const int64_t e = job / bands, y0 = (job % bands) * rows, y1 = std::min(h, y0 + rows);
    const float* eye = pix + e * h * row;
    // The blended rows y0 − 1 … y1 (clamped to the image), each padded; each rate's row as it
    // shows made once for the rows it serves.
    TaaBandBuffers& buffers = ThreadLocal<TaaBandBuffers>();
    std::vector<float>&shaded = buffers.shaded, &middle_row = buffers.middle_row, &coarse_row = buffers.coarse_row;
    shaded.resize(static_cast<size_t>((rows + 2) * span));
    middle_row.resize(static_cast<size_t>(row)), coarse_row.resize(static_cast<size_t>(row));
    int64_t middle_at = -1, coarse_at = -1;
    for (int64_t y = y0 - 1; y <= y1; ++y) {
      const int64_t at = std::clamp<int64_t>(y, 0, h - 1);
      const int64_t m = at / middle_stride * middle_stride, q = at / coarse_stride * coarse_stride;
      if (m != middle_at) HeldRow(eye + m * row, middle_stride, w, middle_row.data()), middle_at = m;
      if (q != coarse_at) HeldRow(eye + q * row, coarse_stride, w, coarse_row.data()), coarse_at = q;
      ShadeRow(eye + at * row, middle_row.data(), coarse_row.data(), wi + (e * h + at) * w, wm + (e * h + at) * w, w,
               shaded.data() + (y - y0 + 1) * span);
    }
    for (int64_t y = y0; y < y1; ++y) {
      const float* tap[9];
      for (int dy = 0; dy < 3; ++dy) {
        const float* p = shaded.data() + (y - y0 + dy) * span;
        for (int dx = 0; dx < 3; ++dx) tap[3 * dy + dx] = p + dx * c;
      }
      const float* now = shaded.data() + (y - y0 + 1) * span + c;
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
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the traced pixels (N, H, W, 3)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the inner rate's weight (N, H, W)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the middle rate's weight (N, H, W)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the history's colour (N, H, W, 3)
                                  .Arg<ffi::Buffer<ffi::PRED>>()  // whether a pixel holds one (N, H, W)
                                  .Ret<ffi::Buffer<ffi::F32>>()   // blended (N, H, W, 3)
                                  .Attr<float>("alpha")
                                  .Attr<float>("keep")
                                  .Attr<float>("gamma")
                                  .Attr<int64_t>("middle_stride")
                                  .Attr<int64_t>("coarse_stride"));
