// A separable Gaussian blur, the border pixels repeated (its oracle: fovjax/foveate/_methods/
// _patney.py `gaussian_blur`, Patney 2016's pre-filter and contrast windows).
#pragma once

#include <algorithm>
#include <vector>

#include "native/csrc/thread_pool.h"

namespace {

// out[j] = sum_u taps[u] * rows[u][j] for j < n, summed in order (u = 0 first, as the JAX
// blur adds its terms): kBlock outputs at a time, their sums held in vector registers while
// the k rows are read (a pass over `out` per tap is bound by its loads and stores instead).
constexpr int64_t kBlock = 64;

FOVJAX_VECTOR_CLONES
void TapRows(const float* taps, int k, const float* const* rows, int64_t n, float* __restrict__ out) {
  int64_t j0 = 0;
  for (; j0 + kBlock <= n; j0 += kBlock) {
    float acc[kBlock];
    const float t0 = taps[0];
    const float* __restrict__ s0 = rows[0] + j0;
#pragma GCC unroll 64
    for (int i = 0; i < kBlock; ++i) acc[i] = t0 * s0[i];
    for (int u = 1; u < k; ++u) {
      const float tu = taps[u];
      const float* __restrict__ s = rows[u] + j0;
#pragma GCC unroll 64
      for (int i = 0; i < kBlock; ++i) acc[i] = acc[i] + tu * s[i];
    }
#pragma GCC unroll 64
    for (int i = 0; i < kBlock; ++i) out[j0 + i] = acc[i];
  }
  for (int64_t j = j0; j < n; ++j) {
    float acc = taps[0] * rows[0][j];
    for (int u = 1; u < k; ++u) acc = acc + taps[u] * rows[u][j];
    out[j] = acc;
  }
}

// Each image's rows blurred down the columns, then along the rows: per output row, the column
// pass over the rows it reads (clamped at the image's edges) into a row padded by r pixels of
// its edge values on each side, then the row pass from that.
ffi::Error GaussianBlur(ffi::ThreadPool pool, ffi::Buffer<ffi::F32> image, ffi::Buffer<ffi::F32> taps,
                        ffi::ResultBuffer<ffi::F32> out) {
  const auto dims = image.dimensions();
  if (dims.size() != 4) return ffi::Error::InvalidArgument("blur: the image must be (N, H, W, C)");
  const int64_t n = dims[0], h = dims[1], w = dims[2], c = dims[3];
  const int k = static_cast<int>(taps.element_count());
  const int r = k / 2;
  if (k % 2 != 1 || out->element_count() != image.element_count() || h < 1 || w < 1 || c < 1) {
    return ffi::Error::InvalidArgument("blur: an odd number of taps and an output of the image's shape");
  }
  const float* src = image.typed_data();
  const float* t = taps.typed_data();
  float* dst = out->typed_data();
  const int64_t row = w * c, padded = (w + 2 * r) * c;
  const int64_t rows = 16, bands = (h + rows - 1) / rows;
  ParallelFor(pool, n * bands, [&](int64_t job) {
    const int64_t e = job / bands, y0 = (job % bands) * rows, y1 = std::min(h, y0 + rows);
    const float* img = src + e * h * row;
    std::vector<float> column(static_cast<size_t>(padded));
    std::vector<const float*> reads(static_cast<size_t>(k));
    for (int64_t y = y0; y < y1; ++y) {
      float* mid = column.data() + r * c;
      // The column pass reads rows y - r .. y + r, clamped; the same taps in the same order.
      for (int u = 0; u < k; ++u) {
        const int64_t yy = std::clamp<int64_t>(y + u - r, 0, h - 1);
        reads[u] = img + yy * row;
      }
      TapRows(t, k, reads.data(), row, mid);
      for (int p = 0; p < r; ++p) {
        for (int64_t ch = 0; ch < c; ++ch) {
          column[p * c + ch] = mid[ch];
          column[(r + w + p) * c + ch] = mid[(w - 1) * c + ch];
        }
      }
      for (int u = 0; u < k; ++u) reads[u] = column.data() + u * c;  // the row pass: shifted columns
      TapRows(t, k, reads.data(), row, dst + (e * h + y) * row);
    }
  });
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxGaussianBlur, GaussianBlur,
                              ffi::Ffi::Bind()
                                  .Ctx<ffi::ThreadPool>()
                                  .Arg<ffi::Buffer<ffi::F32>>()  // images (N, H, W, C)
                                  .Arg<ffi::Buffer<ffi::F32>>()  // taps (2r + 1), normalised
                                  .Ret<ffi::Buffer<ffi::F32>>()  // blurred (N, H, W, C)
);
