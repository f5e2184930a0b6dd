// The foveated frame's reconstruction (its oracle: fovjax/foveate/_frame.py `pixel_means`,
// fovjax/foveate/_fill.py `fill_blanks` and `blur_and_blend`).
#pragma once

#include "native/csrc/thread_pool.h"

namespace {

//
// `fovjax.foveate._frame.pixel_means`, `_fill.fill_blanks` (every block's top-left traced) and
// `_fill.blur_and_blend` (side by side) in one pass per band of rows, on both cores: the same
// operations in the same order. Returns 0 in `complete` where some blank pixel's block top-left
// has no sample either (the caller then runs the JAX path, whose pull-push fills such blocks).

struct FillBlur {
  const float* sums;       // (2·H·W, 3)
  const int32_t* n;        // (2, H, W)
  const bool* bad;         // (2·H·W)
  const int8_t* region;    // (2, H, W)
  const float* ecc;        // (2, H, W)
  float bad_color[3];
  const float* taps;       // (2r + 1)
  int r;
  int64_t h, w;
  int64_t block[3];        // block side per region (fovea 1)
  float fovea_deg, blend_deg;
  bool blur_fovea;
  std::vector<int32_t> column_top_left;  // (3, W): x - x % block, per region
};

inline int64_t Reflect(int64_t i, int64_t n) {  // `_fill._reflect`: the edge not repeated
  i = i < 0 ? -i : i;
  return i > n - 1 ? 2 * (n - 1) - i : i;
}

// A band's rows (`FillBlurRows`), one set per thread (`ThreadLocal`), kept from call to call.
struct FillBandBuffers {
  std::vector<float> means, filled, padded, weight;
  std::vector<int32_t> source;
};

// Row y of eye e's pixel means (`pixel_means`): each pixel's sum over its traced samples (at
// least one), or the bad colour. Divisions, as XLA does them (no reciprocal); the bad pixels
// in a loop of their own (GCC does not vectorise the divisions with that choice in the loop).
FOVJAX_VECTOR_CLONES
void MeansRow(const FillBlur& f, int64_t e, int64_t y, float* __restrict__ out) {
  const int64_t p0 = (e * f.h + y) * f.w;
  const float* __restrict__ sums = f.sums + 3 * p0;
  const int32_t* __restrict__ n = f.n + p0;
  const bool* __restrict__ bad = f.bad + p0;
  const float colour[3] = {f.bad_color[0], f.bad_color[1], f.bad_color[2]};  // locals: see SelectSamples
  const int64_t w = f.w;
  for (int64_t x = 0; x < w; ++x) {
    const float d = static_cast<float>(n[x] > 1 ? n[x] : 1);
    out[3 * x] = sums[3 * x] / d, out[3 * x + 1] = sums[3 * x + 1] / d, out[3 * x + 2] = sums[3 * x + 2] / d;
  }
  for (int64_t x0 = 0; x0 < w; x0 += 8) {  // eight flags at a time: a bad pixel is rare
    const int64_t x1 = std::min<int64_t>(w, x0 + 8);
    uint64_t any = 0;
    if (x1 - x0 == 8) std::memcpy(&any, bad + x0, sizeof any);
    if (x1 - x0 == 8 && any == 0) continue;
    for (int64_t x = x0; x < x1; ++x) {
      if (bad[x]) out[3 * x] = colour[0], out[3 * x + 1] = colour[1], out[3 * x + 2] = colour[2];
    }
  }
}

// sum_t taps[t] * src[t][j] for j < n, summed in order (t = 0 first, as the JAX blur adds its
// terms), into out. One pass for the five taps of the 5×5 Gaussian, the sums in registers; a
// pass per tap otherwise.
FOVJAX_VECTOR_CLONES
void Taps(const float* taps, int k, const float* const* src, int64_t n, float* __restrict__ out) {
  if (k == 5) {
    const float t0 = taps[0], t1 = taps[1], t2 = taps[2], t3 = taps[3], t4 = taps[4];
    const float *__restrict__ a = src[0], *__restrict__ b = src[1], *__restrict__ c = src[2],
                *__restrict__ d = src[3], *__restrict__ e = src[4];
    for (int64_t j = 0; j < n; ++j) out[j] = t0 * a[j] + t1 * b[j] + t2 * c[j] + t3 * d[j] + t4 * e[j];
    return;
  }
  for (int64_t j = 0; j < n; ++j) out[j] = taps[0] * src[0][j];
  for (int t = 1; t < k; ++t) {
    const float tap = taps[t];
    const float* __restrict__ s = src[t];
    for (int64_t j = 0; j < n; ++j) out[j] = out[j] + tap * s[j];
  }
}

// Where each pixel of a row of `fill_blanks` takes its colour from, as an offset into the band's
// means: its own mean (`own` + 3x), or where it is blank (no traced sample) its region's block
// top-left's (`top[c]` + 3·column_top_left[c][x], c its region clamped to 0-2). Returns whether
// some blank pixel's top-left is blank too (`n_eye[top_row[c] + its column]` is 0). Without
// branches, each region's column read whole: GCC vectorises it (the loop that copied blank
// pixels one by one waited on each pixel's chain of loads).
FOVJAX_VECTOR_CLONES
int32_t BlankSources(const int32_t* __restrict__ n, const int8_t* __restrict__ reg,
                     const int32_t* __restrict__ column_top_left, const int32_t* __restrict__ n_eye,
                     const int32_t top_row[3], const int32_t top[3], int32_t own, int32_t w,
                     int32_t* __restrict__ source) {
  const int32_t* __restrict__ t0 = column_top_left;
  const int32_t* __restrict__ t1 = column_top_left + w;
  const int32_t* __restrict__ t2 = column_top_left + 2 * w;
  const int32_t row0 = top_row[0], row1 = top_row[1], row2 = top_row[2];
  const int32_t top0 = top[0], top1 = top[1], top2 = top[2];
  int32_t missing = 0;
  for (int32_t x = 0; x < w; ++x) {
    const int32_t r = reg[x];
    const int32_t fovea = r <= 0, outside = r >= 2;
    const int32_t c0 = t0[x], c1 = t1[x], c2 = t2[x];  // (read whole: a conditional load is a branch)
    const int32_t tx = fovea ? c0 : (outside ? c2 : c1);
    const int32_t at = fovea ? top0 : (outside ? top2 : top1);
    const int32_t top_row_start = fovea ? row0 : (outside ? row2 : row1);
    const int32_t blank = n[x] == 0;
    missing |= blank & (n_eye[top_row_start + tx] == 0);
    source[x] = blank ? at + 3 * tx : own + 3 * x;
  }
  return missing;
}

// The blend with the sharp row by weight, in place.
FOVJAX_VECTOR_CLONES
void Blend(const float* __restrict__ sharp, const float* __restrict__ weight, int64_t n, float* __restrict__ out) {
  for (int64_t j = 0; j < n; ++j) out[j] = sharp[j] * (1.0f - weight[j]) + out[j] * weight[j];
}

// The blend's smoothstep weight per pixel, repeated for its three channels: XLA's clamp (NaN
// stays NaN).
FOVJAX_VECTOR_CLONES
void BlendWeights(const float* __restrict__ ecc, int64_t w, float fovea_deg, float blend_deg,
                  float* __restrict__ out) {
  for (int64_t x = 0; x < w; ++x) {
    float t = (ecc[x] - fovea_deg) / blend_deg;
    t = t < 0.0f ? 0.0f : t;
    t = t > 1.0f ? 1.0f : t;
    const float v = t * t * (3.0f - 2.0f * t);
    out[3 * x] = v, out[3 * x + 1] = v, out[3 * x + 2] = v;
  }
}

// Whether every pixel of a row lies beyond the blend, its smoothstep weight exactly 1 (t >= 1,
// as BlendWeights computes t; NaN is not), and every sharp value of the row is finite: then
// the blend (sharp·0 + blurred·1) leaves the blurred row as it is.
FOVJAX_VECTOR_CLONES
bool BlendKeepsBlur(const float* __restrict__ ecc, int64_t w, float fovea_deg, float blend_deg,
                    const float* __restrict__ sharp, int64_t n) {
  int32_t partly_sharp = 0, not_finite = 0;  // int flags: GCC vectorises int reductions only
  for (int64_t x = 0; x < w; ++x) partly_sharp |= (ecc[x] - fovea_deg) / blend_deg >= 1.0f ? 0 : 1;
  for (int64_t j = 0; j < n; ++j) not_finite |= sharp[j] - sharp[j] == 0.0f ? 0 : 1;
  return (partly_sharp | not_finite) == 0;
}

// Rows [y0, y1) of eye e into the side-by-side image (H, 2W, 3). Rows are 3W floats (pixels'
// channels interleaved): a tap's horizontal neighbour is 3 floats away. False where a blank
// pixel's block top-left is blank too (`fill_blanks` would fill it by pull-push).
bool FillBlurRows(const FillBlur& f, int64_t e, int64_t y0, int64_t y1, float* image) {
  const int r = f.r, k = 2 * r + 1;
  const int64_t w = f.w, rows = y1 - y0, n3 = 3 * w;
  // The means of every row the band reads: its rows, r beyond (reflected) and their blocks'
  // top-left rows.
  int64_t lo = f.h, hi = 0;
  for (int64_t i = 0; i < rows + 2 * r; ++i) {
    const int64_t y = Reflect(y0 - r + i, f.h);
    lo = std::min(lo, y - y % std::max(f.block[1], f.block[2])), hi = std::max(hi, y);
  }
  FillBandBuffers& buffers = ThreadLocal<FillBandBuffers>();
  std::vector<float>&means = buffers.means, &filled = buffers.filled, &padded = buffers.padded,
                     &weight = buffers.weight;
  std::vector<int32_t>& source = buffers.source;
  source.resize(static_cast<size_t>(w));
  means.resize(static_cast<size_t>((hi - lo + 1) * n3));
  filled.resize(static_cast<size_t>((rows + 2 * r) * n3));
  padded.resize(static_cast<size_t>(n3 + 6 * r));
  weight.resize(static_cast<size_t>(n3));
  for (int64_t y = lo; y <= hi; ++y) MeansRow(f, e, y, &means[(y - lo) * n3]);
  bool ok = true;
  const int64_t base = e * f.h * w;
  const int32_t* n_eye = f.n + base;
  for (int64_t i = 0; i < rows + 2 * r; ++i) {  // filled (`fill_blanks`)
    const int64_t y = Reflect(y0 - r + i, f.h);
    // Per region: its blocks' top-left row (where its means start, and its counts).
    int32_t top[3], top_row[3];
    for (int c = 0; c < 3; ++c) {
      const int64_t ty = y - y % f.block[c];
      top[c] = static_cast<int32_t>((ty - lo) * n3), top_row[c] = static_cast<int32_t>(ty * w);
    }
    const int32_t missing = BlankSources(n_eye + y * w, f.region + base + y * w, f.column_top_left.data(), n_eye,
                                         top_row, top, static_cast<int32_t>((y - lo) * n3), static_cast<int32_t>(w),
                                         source.data());
    ok &= missing == 0;
    float* __restrict__ row = &filled[i * n3];
    const float* __restrict__ from = means.data();
    const int32_t* __restrict__ at = source.data();
    for (int64_t x = 0; x < w; ++x) {
      row[3 * x] = from[at[x]], row[3 * x + 1] = from[at[x] + 1], row[3 * x + 2] = from[at[x] + 2];
    }
  }
  const float* window[16];
  for (int64_t i = 0; i < rows; ++i) {
    const int64_t y = y0 + i;
    for (int t = 0; t < k; ++t) window[t] = &filled[(i + t) * n3];
    float* mid = &padded[3 * r];
    Taps(f.taps, k, window, n3, mid);
    for (int64_t x = 1; x <= r; ++x)
      for (int c = 0; c < 3; ++c) {
        padded[3 * (r - x) + c] = mid[3 * Reflect(-x, w) + c];
        padded[3 * (r + w - 1 + x) + c] = mid[3 * Reflect(w - 1 + x, w) + c];
      }
    for (int t = 0; t < k; ++t) window[t] = &padded[3 * t];  // horizontal neighbours: 3 floats apart
    float* out = image + (y * 2 * w + e * w) * 3;
    Taps(f.taps, k, window, n3, out);
    const float* ecc_row = f.ecc + (e * f.h + y) * w;
    const float* sharp = &filled[(i + r) * n3];
    if (!f.blur_fovea && !BlendKeepsBlur(ecc_row, w, f.fovea_deg, f.blend_deg, sharp, n3)) {
      BlendWeights(ecc_row, w, f.fovea_deg, f.blend_deg, weight.data());
      Blend(sharp, weight.data(), n3, out);
    }
  }
  return ok;
}

ffi::Error FillAndBlur(ffi::ThreadPool pool, ffi::Buffer<ffi::F32> sums, ffi::Buffer<ffi::S32> n,
                       ffi::Buffer<ffi::PRED> bad, ffi::Buffer<ffi::S8> region, ffi::Buffer<ffi::F32> ecc,
                       ffi::Buffer<ffi::F32> bad_color, ffi::Buffer<ffi::F32> taps,
                       ffi::Buffer<ffi::F32> fovea_deg, ffi::ResultBuffer<ffi::F32> image,
                       ffi::ResultBuffer<ffi::PRED> complete, int32_t block_periphery, int32_t block_outside,
                       float blend_deg, int32_t blur_fovea) {
  const auto dims = region.dimensions();
  if (dims.size() != 3 || dims[0] != 2) return ffi::Error::InvalidArgument("fill: regions must be (2, H, W)");
  FillBlur f;
  f.h = dims[1], f.w = dims[2];
  const size_t hw2 = static_cast<size_t>(2 * f.h * f.w);
  f.r = static_cast<int>(taps.element_count() / 2);
  if (sums.element_count() != 3 * hw2 || n.element_count() != hw2 || bad.element_count() != hw2 ||
      ecc.element_count() != hw2 || bad_color.element_count() != 3 || taps.element_count() % 2 != 1 ||
      fovea_deg.element_count() != 1 || image->element_count() != 3 * hw2 || block_periphery < 1 ||
      block_outside < 1 || f.h <= f.r || f.w <= f.r || taps.element_count() > 15) {
    return ffi::Error::InvalidArgument("fill: operand shapes do not match the regions");
  }
  if (3 * f.h * f.w >= (int64_t{1} << 31)) {  // `BlankSources`' int32 offsets into an eye's rows
    return ffi::Error::InvalidArgument("fill: an eye's image over 715,827,882 pixels (int32 offsets)");
  }
  f.sums = sums.typed_data(), f.n = n.typed_data(), f.bad = bad.typed_data();
  f.region = region.typed_data(), f.ecc = ecc.typed_data(), f.taps = taps.typed_data();
  for (int c = 0; c < 3; ++c) f.bad_color[c] = bad_color.typed_data()[c];
  f.block[0] = 1, f.block[1] = block_periphery, f.block[2] = block_outside;
  f.fovea_deg = fovea_deg.typed_data()[0], f.blend_deg = blend_deg;
  f.blur_fovea = blur_fovea != 0;
  f.column_top_left.resize(static_cast<size_t>(3 * f.w));
  for (int c = 0; c < 3; ++c)
    for (int64_t x = 0; x < f.w; ++x) f.column_top_left[c * f.w + x] = static_cast<int32_t>(x - x % f.block[c]);
  // Bands of 64 rows: each reads r rows beyond its ends (and the blocks' top-left rows above),
  // a few percent more with 64 rows than its own.
  const int64_t rows = 64, bands = (f.h + rows - 1) / rows;
  std::atomic<bool> ok{true};
  float* out = image->typed_data();
  ParallelFor(pool, 2 * bands, [&](int64_t job) {
    const int64_t e = job / bands, y0 = (job % bands) * rows;
    if (!FillBlurRows(f, e, y0, std::min(f.h, y0 + rows), out)) ok.store(false);
  });
  complete->typed_data()[0] = ok.load();
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxFillAndBlur, FillAndBlur,
                              ffi::Ffi::Bind()
                                  .Ctx<ffi::ThreadPool>()
                                  .Arg<ffi::Buffer<ffi::F32>>()   // per-pixel sums (2·H·W, 3)
                                  .Arg<ffi::Buffer<ffi::S32>>()   // traced samples per pixel (2, H, W)
                                  .Arg<ffi::Buffer<ffi::PRED>>()  // bad pixel (2·H·W)
                                  .Arg<ffi::Buffer<ffi::S8>>()    // regions (2, H, W)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // eccentricity (2, H, W)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the bad pixels' colour (3)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // blur taps (2r + 1)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the fovea's radius, degrees (1)
                                  .Ret<ffi::Buffer<ffi::F32>>()   // the image side by side (H, 2W, 3)
                                  .Ret<ffi::Buffer<ffi::PRED>>()  // every blank pixel filled (1)
                                  .Attr<int32_t>("block_periphery")
                                  .Attr<int32_t>("block_outside")
                                  .Attr<float>("blend_deg")
                                  .Attr<int32_t>("blur_fovea"));
