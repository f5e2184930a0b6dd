// Temporal antialiasing with variance clipping (its oracle: fovjax/foveate/_methods/_patney.py
// `taa_blend`, Patney 2016's history blend).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "native/csrc/thread_pool.h"

namespace {

// sum += t and squares += t·t along a row (restrict-qualified parameters: GCC vectorises the
// loop only where it knows the rows apart).
inline void AddTap(const float* __restrict__ t, int64_t n, float* __restrict__ sum,
                   float* __restrict__ squares) {
  for (int64_t j = 0; j < n; ++j) {
    sum[j] = sum[j] + t[j];
    squares[j] = squares[j] + t[j] * t[j];
  }
}

// The sums of the nine taps and of their squares along a row, added in the taps' order.
FOVJAX_VECTOR_CLONES
void NeighbourhoodRow(const float* const* tap, int64_t n, float* __restrict__ sum,
                      float* __restrict__ squares) {
  const float* __restrict__ t0 = tap[0];
  for (int64_t j = 0; j < n; ++j) {
    sum[j] = t0[j];
    squares[j] = t0[j] * t0[j];
  }
  for (int u = 1; u < 9; ++u) AddTap(tap[u], n, sum, squares);
}

// The clip box from the sums, the history clipped to it and blended, along a row; then the
// current value where the pixel holds no history (a loop of its own: GCC does not vectorise
// the first with that choice in it). The comparisons are jnp.minimum's and jnp.maximum's.
FOVJAX_VECTOR_CLONES
void BlendRow(const float* __restrict__ sum, const float* __restrict__ squares, const float* __restrict__ now,
              const float* __restrict__ before, const uint8_t* __restrict__ held, int64_t n, float alpha,
              float keep, float gamma, float* __restrict__ result) {
  for (int64_t j = 0; j < n; ++j) {
    const float mean = sum[j] / 9.0f;
    const float var = squares[j] / 9.0f - mean * mean;
    const float std = std::sqrt(var > 0.0f ? var : 0.0f);
    const float x = now[j], low = mean - gamma * std, high = mean + gamma * std;
    const float lo = low < x ? low : x;
    const float hi = high > x ? high : x;
    const float above = before[j] > lo ? before[j] : lo;
    const float clipped = above < hi ? above : hi;
    result[j] = alpha * x + keep * clipped;
  }
  for (int64_t j = 0; j < n; ++j) {
    if (!held[j]) result[j] = now[j];
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
    // The three rows a row reads, each with its edge pixels repeated once on either side, and
    // per element whether its pixel holds a history: loops along the row that vectorise.
    std::vector<float> padded(static_cast<size_t>(3 * (row + 2 * c)));
    std::vector<float> sum(static_cast<size_t>(row)), squares(static_cast<size_t>(row));
    std::vector<uint8_t> held(static_cast<size_t>(row));
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
      NeighbourhoodRow(tap, row, sum.data(), squares.data());
      const int64_t at = (e * h + y) * row;
      for (int64_t x = 0; x < w; ++x) {
        for (int64_t ch = 0; ch < c; ++ch) held[x * c + ch] = has[(e * h + y) * w + x];
      }
      BlendRow(sum.data(), squares.data(), img + at, hist + at, held.data(), row, alpha, keep, gamma, dst + at);
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
