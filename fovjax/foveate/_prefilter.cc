// Patney 2016's contrast-preserving pre-filters and the blend of the shading rates, both eyes
// side by side (its oracle: fovjax/foveate/_methods/_patney.py `prefilter_and_blend`).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
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


// Four output rows at once, out[q][j] = sum_u taps[u] · rows[q + u][j] for j < n (k + 3 rows
// given), each sum in TapRows's order (so the values are its): a row read once serves the four
// sums it is a term of, held in vector registers, where TapRows reads it once per sum. The
// rows' first and last three reads serve fewer sums (their taps end).
using Floats16 = float __attribute__((vector_size(64)));

FOVJAX_VECTOR_CLONES
void TapRows4(const float* taps, int k, const float* const* rows, int64_t n, float* const* out) {
  constexpr int kOut = 4;
  const float t0 = taps[0];
  int64_t j0 = 0;
  for (; j0 + 16 <= n; j0 += 16) {
    Floats16 acc[kOut];
    for (int q = 0; q < kOut; ++q) {
      Floats16 s;
      __builtin_memcpy(&s, rows[q] + j0, sizeof s);
      acc[q] = t0 * s;
    }
    int u = 1;
    for (; u < kOut; ++u) {  // the first rows: the sums q < u only
      Floats16 s;
      __builtin_memcpy(&s, rows[u] + j0, sizeof s);
      for (int q = 0; q < kOut; ++q) {
        if (q < u) acc[q] = acc[q] + taps[u - q] * s;
      }
    }
    for (; u < k; ++u) {
      Floats16 s;
      __builtin_memcpy(&s, rows[u] + j0, sizeof s);
      for (int q = 0; q < kOut; ++q) acc[q] = acc[q] + taps[u - q] * s;
    }
    for (; u < k + kOut - 1; ++u) {  // the last rows: the sums q > u − k only
      Floats16 s;
      __builtin_memcpy(&s, rows[u] + j0, sizeof s);
      for (int q = 0; q < kOut; ++q) {
        if (q > u - k) acc[q] = acc[q] + taps[u - q] * s;
      }
    }
    for (int q = 0; q < kOut; ++q) __builtin_memcpy(out[q] + j0, &acc[q], sizeof acc[q]);
  }
  for (int64_t j = j0; j < n; ++j) {
    for (int q = 0; q < kOut; ++q) {
      float acc = t0 * rows[q][j];
      for (int u = 1; u < k; ++u) acc = acc + taps[u] * rows[q + u][j];
      out[q][j] = acc;
    }
  }
}

// A rectangle of rows [y0, y1) and columns [x0, x1).
struct Rect {
  int64_t y0 = 0, y1 = 0, x0 = 0, x1 = 0;
  int64_t Rows() const { return y1 - y0; }
  int64_t Cols() const { return x1 - x0; }
  bool Empty() const { return y1 <= y0 || x1 <= x0; }
  Rect Grown(int64_t r, int64_t h, int64_t w) const {
    return {std::max<int64_t>(0, y0 - r), std::min(h, y1 + r), std::max<int64_t>(0, x0 - r), std::min(w, x1 + r)};
  }
};

// The column pass of rows [y0, y1): out(y)[j] = sum_u taps[u] · row(y + u − r)[j] for j < n,
// `row` clamping its index to the image. In strips of kStrip floats across the rows: a strip's
// k rows stay in the first-level cache from one output row to the next (whole rows pass
// through the second level once per tap); four output rows at a time (TapRows4), the rest one.
constexpr int64_t kStrip = 256;

// Per-thread buffers (`ThreadLocal`), kept from call to call: `BlurRows`', `FilterBand`'s and
// a band of `PatneyPrefilter`'s.
struct BlurRowsBuffers {
  std::vector<float> pad;
  std::vector<const float*> reads;
};
struct FilterBandBuffers {
  std::vector<float> blurred, stack, mean, stats;
};
struct PrefilterBandBuffers {
  std::vector<float> filtered[2], rest;
};

template <class Row, class Out>
void ColumnStrips(const std::vector<float>& taps, int64_t y0, int64_t y1, int64_t n, const Row& row, const Out& out,
                  std::vector<const float*>& reads) {
  const int k = static_cast<int>(taps.size()), r = k / 2;
  reads.resize(static_cast<size_t>(k + 3));
  float* outs[4];
  for (int64_t x0 = 0; x0 < n; x0 += kStrip) {
    const int64_t m = std::min(kStrip, n - x0);
    int64_t y = y0;
    for (; y + 4 <= y1; y += 4) {
      for (int u = 0; u < k + 3; ++u) reads[u] = row(y + u - r) + x0;
      for (int q = 0; q < 4; ++q) outs[q] = out(y + q) + x0;
      TapRows4(taps.data(), k, reads.data(), m, outs);
    }
    for (; y < y1; ++y) {
      for (int u = 0; u < k; ++u) reads[u] = row(y + u - r) + x0;
      TapRows(taps.data(), k, reads.data(), m, out(y) + x0);
    }
  }
}

// The Gaussian blur of `gaussian_blur` (columns, then rows, the border pixels repeated) of an
// image of h rows, each `planes` planes of w pixels of c channels (an image (h, w, c): one
// plane; the window's statistics: a plane each, one channel), at the pixels of `at` only, rows
// [y0, y1) of it (on the calling thread, eight rows at a time), into `out` (y1 − y0 rows of
// `planes` planes of at.Cols() pixels): the same taps in the same order as the whole image's
// blur, so the values are that blur's.
void BlurRows(const float* src, int64_t h, int64_t w, int64_t planes, int64_t c, const std::vector<float>& taps,
              const Rect& at, int64_t y0, int64_t y1, float* out) {
  const int k = static_cast<int>(taps.size()), r = k / 2;
  // The column pass over the columns the row pass reads (clamped to the image).
  const int64_t cx0 = std::max<int64_t>(0, at.x0 - r), cx1 = std::min(w, at.x1 + r);
  const int64_t plane = w * c, span = (at.Cols() + 2 * r) * c, out_plane = at.Cols() * c;
  // Columns the row pass reads beyond the image's edges (its edge pixels repeated there).
  const int64_t left = cx0 - (at.x0 - r), right = at.x1 + r - cx1;
  constexpr int64_t kRows = 8;
  BlurRowsBuffers& buffers = ThreadLocal<BlurRowsBuffers>();
  std::vector<float>& pad = buffers.pad;
  std::vector<const float*>& reads = buffers.reads;
  pad.resize(static_cast<size_t>(kRows * planes * span));
  for (int64_t b0 = y0; b0 < y1; b0 += kRows) {
    const int64_t b1 = std::min(y1, b0 + kRows);
    for (int64_t q = 0; q < planes; ++q) {
      auto source = [&](int64_t y) { return src + (std::clamp<int64_t>(y, 0, h - 1) * planes + q) * plane + cx0 * c; };
      auto padded = [&](int64_t y) { return pad.data() + ((y - b0) * planes + q) * span + left * c; };  // in place
      ColumnStrips(taps, b0, b1, (cx1 - cx0) * c, source, padded, reads);
      for (int64_t y = b0; y < b1; ++y) {
        float* column = padded(y);
        for (int64_t p = 0; p < left; ++p) std::copy(column, column + c, column - (left - p) * c);
        const float* last = column + (cx1 - cx0 - 1) * c;
        for (int64_t p = 0; p < right; ++p) std::copy(last, last + c, column + (cx1 - cx0 + p) * c);
        for (int u = 0; u < k; ++u) reads[u] = column - left * c + u * c;
        TapRows(taps.data(), k, reads.data(), out_plane, out + ((y - y0) * planes + q) * out_plane);
      }
    }
  }
}

// The window's luminance planes, each row of the stack holding them one after another (a
// plane per statistic: the loops over a row vectorise with unit strides): L, L², L_B². B's own
// window is its blur as it lies (interleaved); the window's mean of L_B is the luminance of
// its mean of B (the luminance is linear in B; the blur too).
constexpr int64_t kPlanes = 3;

// One row of the window's planes from the image's and B's (restrict-qualified and free of
// branches, so that GCC vectorises it).
FOVJAX_VECTOR_CLONES
void StackRow(const float* __restrict__ im, const float* __restrict__ b, int64_t n, float l0, float l1, float l2,
              float* __restrict__ s) {
  float* __restrict__ l = s;
  float* __restrict__ l_squared = s + n;
  float* __restrict__ lb_squared = s + 2 * n;
  for (int64_t j = 0; j < n; ++j) {  // (one interleaved source per loop: GCC vectorises each)
    const float lb = b[3 * j] * l0 + b[3 * j + 1] * l1 + b[3 * j + 2] * l2;
    lb_squared[j] = lb * lb;
  }
  for (int64_t j = 0; j < n; ++j) {
    const float li = im[3 * j] * l0 + im[3 * j + 1] * l1 + im[3 * j + 2] * l2;
    l[j] = li, l_squared[j] = li * li;
  }
}

// One row of the filter from the window's mean of B `m`, its means of the luminance planes
// `stats` and B: the contrast gain (1 where B is flat), then m + (B − m)·gain, clipped at 0.
FOVJAX_VECTOR_CLONES
void GainRow(const float* __restrict__ m, const float* __restrict__ stats, const float* __restrict__ b, int64_t n,
             float l0, float l1, float l2, float flat_std, float max_gain, float* __restrict__ o) {
  const float* __restrict__ mean_l = stats;
  const float* __restrict__ mean_l2 = stats + n;
  const float* __restrict__ mean_lb2 = stats + 2 * n;
  for (int64_t j = 0; j < n; ++j) {
    const float m0 = m[3 * j], m1 = m[3 * j + 1], m2 = m[3 * j + 2];
    const float mean_lb = m0 * l0 + m1 * l1 + m2 * l2;
    const float s_image = std::sqrt(std::max(mean_l2[j] - mean_l[j] * mean_l[j], 0.0f));
    const float s_blurred = std::sqrt(std::max(mean_lb2[j] - mean_lb * mean_lb, 0.0f));
    const float clipped = std::min(std::max(s_image / std::max(s_blurred, flat_std), 1.0f), max_gain);
    const float gain = s_blurred > flat_std ? clipped : 1.0f;
    o[3 * j] = std::max(m0 + (b[3 * j] - m0) * gain, 0.0f);
    o[3 * j + 1] = std::max(m1 + (b[3 * j + 1] - m1) * gain, 0.0f);
    o[3 * j + 2] = std::max(m2 + (b[3 * j + 2] - m2) * gain, 0.0f);
  }
}

struct FilterParams {
  std::vector<float> blur, window;  // the taps of σ and of the contrast window
  float luminance[3];
  float max_gain, flat_std;
};

// `contrast_preserving_filter` of one eye's image (h, w, 3) at the pixels of `at`, rows [y0,
// y1) of it, into `out` (y1 − y0 rows of at.Cols() pixels of 3): B the blur, then in the window
// around each pixel the mean of B and the standard deviations of the luminances of the image
// and of B: B and the window's planes (L, L², L_B²) blurred once each. The rows of B and of
// the planes the windows read (the window's radius more on either side, which the neighbouring
// bands make again) are made first, then the windows eight rows at a time, so that what the
// band makes stays in the cache until it is read. The values do not depend on the band.
void FilterBand(const float* image, int64_t h, int64_t w, const FilterParams& f, const Rect& at, int64_t y0,
                int64_t y1, float* out) {
  const int64_t rw = static_cast<int64_t>(f.window.size()) / 2;
  const Rect around = at.Grown(rw, h, w);  // where the window reads (clamped as the image is)
  const int64_t cols = around.Cols();
  const float l0 = f.luminance[0], l1 = f.luminance[1], l2 = f.luminance[2];
  constexpr int64_t kRows = 8;
  // The rows of B and of the planes the band's windows read: beyond them the window's rows
  // are clamped to the image, as they are to these rows (`around` ends where the image does).
  const int64_t r0 = std::max(around.y0, y0 - rw), r1 = std::min(around.y1, y1 + rw), n = r1 - r0;
  FilterBandBuffers& buffers = ThreadLocal<FilterBandBuffers>();
  std::vector<float>&blurred = buffers.blurred, &stack = buffers.stack, &mean = buffers.mean, &stats = buffers.stats;
  blurred.resize(static_cast<size_t>(n * cols * 3));
  stack.resize(static_cast<size_t>(n * cols * kPlanes));
  mean.resize(static_cast<size_t>(kRows * at.Cols() * 3));
  stats.resize(static_cast<size_t>(kRows * at.Cols() * kPlanes));
  BlurRows(image, h, w, 1, 3, f.blur, Rect{r0, r1, around.x0, around.x1}, r0, r1, blurred.data());
  for (int64_t i = 0; i < n; ++i) {
    StackRow(image + ((r0 + i) * w + around.x0) * 3, blurred.data() + i * cols * 3, cols, l0, l1, l2,
             stack.data() + i * cols * kPlanes);
  }
  // The windows, B and the planes taken as images of the band's rows (n) of `around`'s columns.
  const Rect inside{y0 - r0, y1 - r0, at.x0 - around.x0, at.x1 - around.x0};
  for (int64_t b0 = inside.y0; b0 < inside.y1; b0 += kRows) {
    const int64_t b1 = std::min(inside.y1, b0 + kRows);
    BlurRows(blurred.data(), n, cols, 1, 3, f.window, inside, b0, b1, mean.data());
    BlurRows(stack.data(), n, cols, kPlanes, 1, f.window, inside, b0, b1, stats.data());
    for (int64_t y = b0; y < b1; ++y) {
      GainRow(mean.data() + (y - b0) * at.Cols() * 3, stats.data() + (y - b0) * at.Cols() * kPlanes,
              blurred.data() + (y * cols + inside.x0) * 3, at.Cols(), l0, l1, l2, f.flat_std, f.max_gain,
              out + (y + r0 - y0) * at.Cols() * 3);
    }
  }
}

// The rates' blend along a row (`rate_blend`'s arithmetic in its order): rest = coarse·(1 −
// w_middle), rest += middle·w_middle, then out = rest·(1 − w_inner) + image·w_inner.
FOVJAX_VECTOR_CLONES
void CoarseTerm(const float* __restrict__ v, const float* __restrict__ b, int64_t n, float* __restrict__ rest) {
  for (int64_t j = 0; j < n; ++j) {
    for (int ch = 0; ch < 3; ++ch) rest[3 * j + ch] = v[3 * j + ch] * (1.0f - b[j]);
  }
}

FOVJAX_VECTOR_CLONES
void MiddleTerm(const float* __restrict__ v, const float* __restrict__ b, int64_t n, float* __restrict__ rest) {
  for (int64_t j = 0; j < n; ++j) {
    for (int ch = 0; ch < 3; ++ch) rest[3 * j + ch] = rest[3 * j + ch] + v[3 * j + ch] * b[j];
  }
}

FOVJAX_VECTOR_CLONES
void InnerOver(const float* __restrict__ rest, const float* __restrict__ image, const float* __restrict__ a, int64_t n,
               float* __restrict__ out) {
  for (int64_t j = 0; j < n; ++j) {
    for (int ch = 0; ch < 3; ++ch) out[3 * j + ch] = rest[3 * j + ch] * (1.0f - a[j]) + image[3 * j + ch] * a[j];
  }
}

// One row's column spans [first, end) where the middle and the coarse rate's filters have a
// weight in the blend that is not 0: w_middle·(1 − w_inner) and (1 − w_middle)·(1 − w_inner)
// (first ≥ end: nowhere). Branch-free minima and maxima, so that GCC vectorises the row.
FOVJAX_VECTOR_CLONES
void RowSpans(const float* __restrict__ a, const float* __restrict__ b, int32_t w, int32_t span[4]) {
  int32_t middle_first = w, middle_last = -1, coarse_first = w, coarse_last = -1;
  for (int32_t x = 0; x < w; ++x) {
    // (integer masks and plain selects: GCC vectorises neither `&&` nor std::min here)
    const int32_t outer = a[x] != 1.0f;
    const int32_t middle = outer & (b[x] != 0.0f), coarse = outer & (b[x] != 1.0f);
    const int32_t mf = middle ? x : w, ml = middle ? x : -1, cf = coarse ? x : w, cl = coarse ? x : -1;
    middle_first = mf < middle_first ? mf : middle_first;
    middle_last = ml > middle_last ? ml : middle_last;
    coarse_first = cf < coarse_first ? cf : coarse_first;
    coarse_last = cl > coarse_last ? cl : coarse_last;
  }
  span[0] = middle_first, span[1] = middle_last + 1, span[2] = coarse_first, span[3] = coarse_last + 1;
}

// Per eye, the bounding rectangles of the pixels where the middle and the coarse rate's
// filters show (`RowSpans`): the rows' spans in bands of rows in parallel, then merged.
void ShownRects(ffi::ThreadPool& pool, const float* inner, const float* middle, int64_t h, int64_t w, Rect out[2][2]) {
  std::vector<int32_t> span(static_cast<size_t>(4 * 2 * h));
  constexpr int64_t kRows = 32;
  const int64_t bands = (2 * h + kRows - 1) / kRows;
  ParallelFor(pool, bands, [&](int64_t band) {
    for (int64_t row = band * kRows; row < std::min(2 * h, (band + 1) * kRows); ++row) {
      RowSpans(inner + row * w, middle + row * w, static_cast<int32_t>(w), span.data() + 4 * row);
    }
  });
  for (int64_t e = 0; e < 2; ++e) {
    for (int f = 0; f < 2; ++f) {
      Rect box{h, 0, w, 0};
      for (int64_t y = 0; y < h; ++y) {
        const int64_t first = span[4 * (e * h + y) + 2 * f], end = span[4 * (e * h + y) + 2 * f + 1];
        if (end <= first) continue;
        box.y0 = std::min(box.y0, y), box.y1 = y + 1;
        box.x0 = std::min(box.x0, first), box.x1 = std::max(box.x1, end);
      }
      out[e][f] = box.Empty() ? Rect{} : box;
    }
  }
}

// Per eye: each shading rate's pre-filter where that rate shows (its bounding rectangle: a
// filter is computed only where its weight in the blend is not 0), then the blend
// rest = coarse·(1 − w_middle) + middle·w_middle, out = rest·(1 − w_inner) + image·w_inner,
// written side by side. A term left out is one whose product is 0 there (the filters are
// finite where the image is), so the values are the whole images' blend. Both eyes in bands of
// rows, one per task: a band's filtered rows are blended while they are in the cache.
ffi::Error PatneyPrefilter(ffi::ThreadPool pool, ffi::Buffer<ffi::F32> image, ffi::Buffer<ffi::F32> w_inner,
                           ffi::Buffer<ffi::F32> w_middle, ffi::Buffer<ffi::F32> middle_blur,
                           ffi::Buffer<ffi::F32> middle_window, ffi::Buffer<ffi::F32> coarse_blur,
                           ffi::Buffer<ffi::F32> coarse_window, ffi::Buffer<ffi::F32> luminance,
                           ffi::ResultBuffer<ffi::F32> out, float max_gain, float flat_std) {
  const auto dims = image.dimensions();
  if (dims.size() != 4 || dims[0] != 2 || dims[3] != 3) {
    return ffi::Error::InvalidArgument("prefilter: the image must be (2, H, W, 3)");
  }
  const int64_t h = dims[1], w = dims[2], hw = h * w;
  if (w_inner.element_count() != static_cast<size_t>(2 * hw) || w_middle.element_count() != static_cast<size_t>(2 * hw) ||
      out->element_count() != static_cast<size_t>(6 * hw) || luminance.element_count() != 3) {
    return ffi::Error::InvalidArgument("prefilter: the weights are (2, H, W) and the output (H, 2W, 3)");
  }
  if (w >= (int64_t{1} << 30)) return ffi::Error::InvalidArgument("prefilter: the image is too wide");
  FilterParams filters[2];
  const ffi::Buffer<ffi::F32>* taps[2][2] = {{&middle_blur, &middle_window}, {&coarse_blur, &coarse_window}};
  for (int f = 0; f < 2; ++f) {
    for (int t = 0; t < 2; ++t) {
      const ffi::Buffer<ffi::F32>& b = *taps[f][t];
      if (b.element_count() % 2 != 1) return ffi::Error::InvalidArgument("prefilter: an odd number of taps");
      std::vector<float>& v = t == 0 ? filters[f].blur : filters[f].window;
      v.assign(b.typed_data(), b.typed_data() + b.element_count());
    }
    std::copy(luminance.typed_data(), luminance.typed_data() + 3, filters[f].luminance);
    filters[f].max_gain = max_gain, filters[f].flat_std = flat_std;
  }
  const float* src = image.typed_data();
  const float* wi = w_inner.typed_data();
  const float* wm = w_middle.typed_data();
  float* dst = out->typed_data();
  Rect shown[2][2];  // per eye: the middle and the coarse rate's
  ShownRects(pool, wi, wm, h, w, shown);
  constexpr int64_t kBand = 48;
  const int64_t per_eye = (h + kBand - 1) / kBand;
  ParallelFor(pool, 2 * per_eye, [&](int64_t band) {
    const int64_t e = band / per_eye, y0 = band % per_eye * kBand, y1 = std::min(h, y0 + kBand);
    const float* img = src + e * hw * 3;
    const float* inner = wi + e * hw;
    const float* middle = wm + e * hw;
    // Each filter's rows of the band that lie in its rectangle.
    PrefilterBandBuffers& buffers = ThreadLocal<PrefilterBandBuffers>();
    std::vector<float>* filtered = buffers.filtered;
    int64_t f0[2], f1[2];
    for (int f = 0; f < 2; ++f) {
      const Rect& at = shown[e][f];
      f0[f] = std::max(y0, at.y0), f1[f] = std::min(y1, at.y1);
      if (at.Empty() || f1[f] <= f0[f]) continue;
      filtered[f].resize(static_cast<size_t>((f1[f] - f0[f]) * at.Cols() * 3));
      FilterBand(img, h, w, filters[f], at, f0[f], f1[f], filtered[f].data());
    }
    // Per row: rest = coarse·(1 − w_middle) + middle·w_middle where each filter was computed
    // (elsewhere its weight is 0, or w_inner is 1 and rest·0 is 0), then the image over it.
    std::vector<float>& rest = buffers.rest;
    for (int64_t y = y0; y < y1; ++y) {
      rest.assign(static_cast<size_t>(3 * w), 0.0f);
      const float* a = inner + y * w;
      const float* b = middle + y * w;
      const Rect& c = shown[e][1];
      if (y >= f0[1] && y < f1[1]) {
        CoarseTerm(filtered[1].data() + (y - f0[1]) * c.Cols() * 3, b + c.x0, c.Cols(), rest.data() + 3 * c.x0);
      }
      const Rect& m = shown[e][0];
      if (y >= f0[0] && y < f1[0]) {
        MiddleTerm(filtered[0].data() + (y - f0[0]) * m.Cols() * 3, b + m.x0, m.Cols(), rest.data() + 3 * m.x0);
      }
      InnerOver(rest.data(), img + y * w * 3, a, w, dst + (y * 2 * w + e * w) * 3);
    }
  });
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxPatneyPrefilter, PatneyPrefilter,
                              ffi::Ffi::Bind()
                                  .Ctx<ffi::ThreadPool>()
                                  .Arg<ffi::Buffer<ffi::F32>>()  // the image (2, H, W, 3)
                                  .Arg<ffi::Buffer<ffi::F32>>()  // the inner rate's weight (2, H, W)
                                  .Arg<ffi::Buffer<ffi::F32>>()  // the middle rate's weight (2, H, W)
                                  .Arg<ffi::Buffer<ffi::F32>>()  // the middle rate's blur taps
                                  .Arg<ffi::Buffer<ffi::F32>>()  // the middle rate's window taps
                                  .Arg<ffi::Buffer<ffi::F32>>()  // the coarse rate's blur taps
                                  .Arg<ffi::Buffer<ffi::F32>>()  // the coarse rate's window taps
                                  .Arg<ffi::Buffer<ffi::F32>>()  // the luminance weights (3)
                                  .Ret<ffi::Buffer<ffi::F32>>()  // both eyes side by side (H, 2W, 3)
                                  .Attr<float>("max_gain")
                                  .Attr<float>("flat_std"));
