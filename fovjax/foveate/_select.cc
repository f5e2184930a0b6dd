// The foveated frame's sample selection (its oracle: fovjax/foveate/_frame.py, `select_samples`).
#pragma once

#include "native/csrc/layout.h"
#include "native/csrc/thread_pool.h"
#include "native/csrc/threefry.h"

namespace {

//
// `fovjax.foveate._frame.select_samples` (no image tiles), its traced mask and per-pixel counts
// in one pass over the screen on both cores, with the same results to the bit: the classes of
// every sub-sample (`_sampling.sample_classes`: block top-lefts, the P(ω) draw of JAX's
// threefry2x32 uniform for the sub-sample's flat index, the rule, each region's samples per
// pixel), their stable compaction in locality order (`compaction_order`), and which samples the
// budget keeps. P(ω) comes from the program (JAX computes it), an eye per buffer; the regions
// are made here from the eccentricities (`_sampling.regions`: two comparisons, the same codes).

// One row of one sub-sample's classes (`_sampling.sample_classes`), branch-free so that the
// compiler vectorises it: class = 2 - 2·mandatory - optional (the two exclude each other),
// skipped beyond the region's samples per pixel (`allowed` per region code). Adds the traced
// samples to `n`.
template <int kRule>
void ClassRow(const int32_t* __restrict__ row, const uint8_t* __restrict__ top_left,
              const float* __restrict__ u, const float* __restrict__ prob, const uint8_t* allowed,
              uint8_t first, int64_t w, int8_t* __restrict__ cls, uint8_t* __restrict__ traced,
              int32_t* __restrict__ n) {
  // int32 lanes throughout: GCC vectorises the loop only when its values share one width.
  const int32_t a0 = allowed[0], a1 = allowed[1], a2 = allowed[2], f = first;
  for (int64_t x = 0; x < w; ++x) {
    const int32_t r = row[x];
    const int32_t fovea = r == kFovea, tl = top_left[x], kept = u[x] < prob[x];
    int32_t mandatory, optional;
    if (kRule == kRuleEither) {
      mandatory = fovea | tl;
      optional = (mandatory ^ 1) & kept;
    } else if (kRule == kRuleStrict) {
      mandatory = fovea;
      optional = (mandatory ^ 1) & tl & kept;
    } else if (kRule == kRulePixelMask) {  // P is 1 at the pixels to trace, else 0
      mandatory = prob[x] >= 1.0f;
      optional = 0;
    } else {  // thesis-measured
      mandatory = (r != kOutside) | f;
      optional = 0;
    }
    const int32_t ok = (fovea & a0) | ((r == kPeriphery) & a1) | ((r == kOutside) & a2);
    const int32_t live = ok & (mandatory | optional);
    cls[x] = static_cast<int8_t>(2 - live * (2 * mandatory + optional));
    traced[x] = static_cast<uint8_t>(live);
    n[x] += live;
  }
}

// Marks in `tl` each aligned block of `kSide` columns (`side` where kSide is 0) that holds a
// pixel flagged in `any`, at the block's first column. The sides the thesis's blocks take are
// built with the block's loop unrolled: a loop of two to four bytes per block ran as a
// vectorised loop's set-up and its scalar tail, about a third of the selection's first pass.
template <int kSide>
inline void BlockTopLefts(const uint8_t* __restrict__ any, int64_t w, uint8_t* __restrict__ tl, int64_t side = kSide) {
  const int64_t b = kSide > 0 ? kSide : side, whole = w - w % b;
  for (int64_t xb = 0; xb < whole; xb += b) {
    uint8_t found = 0;
    for (int64_t k = 0; k < b; ++k) found |= any[xb + k];
    tl[xb] |= found;
  }
  if (whole < w) {  // the last block, cut by the image's edge
    uint8_t found = 0;
    for (int64_t x = whole; x < w; ++x) found |= any[x];
    tl[whole] |= found;
  }
}

// The first and the last column of a row whose P lies strictly between 0 and 1 (w and -1 where
// none does), as min and max reductions over masks: GCC vectorises these.
inline void DrawnSpan(const float* __restrict__ p, int32_t w, int32_t* first, int32_t* last) {
  int32_t f = w, l = -1;
  for (int32_t x = 0; x < w; ++x) {
    const int32_t keep = -((p[x] > 0.0f) & (p[x] < 1.0f));  // all ones where drawn
    f = std::min(f, (x & keep) | (w & ~keep));
    l = std::max(l, (x & keep) | ~keep);
  }
  *first = f, *last = l;
}

// `_sampling.regions`: 0 fovea (ω ≤ ω0), 1 periphery (ω ≤ ω1), 2 outside (NaN too).
inline int32_t RegionCode(float ecc, float fovea_deg, float periphery_deg) {
  return ecc <= fovea_deg ? kFovea : (ecc <= periphery_deg ? kPeriphery : kOutside);
}

// Pass 1 of `SelectSamples` for one band of rows of one eye (`job`): its operands.
struct SelectBand {
  const float* ecc;
  const float* p[2];
  float fovea_deg, periphery_deg;
  int8_t* region;
  const uint32_t* key;
  const int32_t* rspp;
  const int32_t* srank;
  int8_t* cls;
  bool* traced;
  int32_t* per_pixel;
  int64_t* band_sums;
  int64_t h, w, hw, spp, rows, bands;
  int32_t rule, block_periphery, block_outside;
};

// Built for the widest vector unit the CPU has, as UniformRun (the row loops are byte- and
// int-wide lanes; ClassRow is inlined into each build).
FOVJAX_VECTOR_CLONES
void SelectBandRows(const SelectBand& a, int64_t job) {
  int8_t* region = a.region;
  const uint32_t* key = a.key;
  const int32_t* rspp = a.rspp;
  const int32_t* srank = a.srank;
  int8_t* cls = a.cls;
  bool* traced = a.traced;
  int32_t* per_pixel = a.per_pixel;
  int64_t* band_sums = a.band_sums;
  const int64_t h = a.h, w = a.w, hw = a.hw, spp = a.spp, rows = a.rows, bands = a.bands;
  const int32_t rule = a.rule, block_periphery = a.block_periphery, block_outside = a.block_outside;
  // The sizes as locals: the byte-wide stores below may alias anything the lambda captures by
  // reference, which would be reloaded after each of them.
  const int64_t W = w, H = h;
  const int64_t eye = job / bands, y0 = (job % bands) * rows, y1 = std::min(H, y0 + rows);
  const float* ecc = a.ecc + eye * hw;
  const float fovea_deg = a.fovea_deg, periphery_deg = a.periphery_deg;
  std::vector<float> u(static_cast<size_t>(W * spp));
  std::vector<uint8_t> top_left(static_cast<size_t>(W)), in_block(static_cast<size_t>(W));
  std::vector<int32_t> row_codes(static_cast<size_t>(W));
  const int32_t codes[2] = {1, 2}, sizes[2] = {block_periphery, block_outside};
  for (int64_t y = y0; y < y1; ++y) {
    // The row's region codes as int32 (`ClassRow`'s lanes are), and as the bytes of the output.
    const float* ecc_row = ecc + y * W;
    int8_t* codes_row = region + eye * hw + y * W;
    int32_t* row = row_codes.data();
    for (int64_t x = 0; x < W; ++x) row[x] = RegionCode(ecc_row[x], fovea_deg, periphery_deg);
    for (int64_t x = 0; x < W; ++x) codes_row[x] = static_cast<int8_t>(row[x]);
    // `_sampling.block_top_lefts`: the fovea's pixels; a region's pixels where its blocks are
    // one pixel; else the top-left of every aligned block holding a pixel of that region.
    uint8_t* tl = top_left.data();
    for (int64_t x = 0; x < W; ++x) tl[x] = row[x] == kFovea;
    for (int c = 0; c < 2; ++c) {
      const int64_t b = sizes[c];
      const int32_t code = codes[c];
      if (b == 1) {
        for (int64_t x = 0; x < W; ++x) tl[x] |= row[x] == code;
        continue;
      }
      if (y % b != 0) continue;
      uint8_t* any = in_block.data();  // per column: a pixel of the region in the block's rows
      for (int64_t x = 0; x < W; ++x) any[x] = row[x] == code;
      for (int64_t yy = y + 1; yy < std::min(H, y + b); ++yy) {
        const float* below = ecc + yy * W;  // (rows another band may own: their codes anew)
        for (int64_t x = 0; x < W; ++x) any[x] |= RegionCode(below[x], fovea_deg, periphery_deg) == code;
      }
      if (b == 2) BlockTopLefts<2>(any, W, tl);
      else if (b == 3) BlockTopLefts<3>(any, W, tl);
      else if (b == 4) BlockTopLefts<4>(any, W, tl);
      else BlockTopLefts<0>(any, W, tl, b);
    }
    const float* prow = a.p[eye] + y * W;
    // A draw decides a class only where P is strictly between 0 and 1 (below, none is kept;
    // above, every one): only the row's columns from the first such P to the last are drawn
    // (a row without one, as the methods' pixel masks and the fovea's rows, none), and any
    // draw in [0, 1) gives the other columns' classes. The thesis-measured rule and the pixel
    // masks draw none.
    int32_t first_drawn, last_drawn;
    DrawnSpan(prow, static_cast<int32_t>(W), &first_drawn, &last_drawn);
    const bool draws = last_drawn >= 0 && rule != kRuleThesisMeasured && rule != kRulePixelMask;
    for (int64_t s = 0; s < spp; ++s) {
      float* us = &u[s * W];
      if (!draws) {
        std::fill(us, us + W, 0.0f);
        continue;
      }
      std::fill(us, us + first_drawn, 0.0f);
      UniformRun(key[2 * eye], key[2 * eye + 1], static_cast<uint32_t>((s * H + y) * W + first_drawn),
                 last_drawn + 1 - first_drawn, us + first_drawn);
      std::fill(us + last_drawn + 1, us + W, 0.0f);
    }
    int32_t* n = per_pixel + eye * hw + y * W;
    std::fill(n, n + W, 0);
    for (int64_t s = 0; s < spp; ++s) {
      const float* us = &u[s * W];
      int8_t* c_row = cls + (eye * spp + s) * hw + y * W;
      uint8_t* t_row = reinterpret_cast<uint8_t*>(traced) + (eye * spp + s) * hw + y * W;
      const uint8_t allowed[3] = {srank[s] < rspp[0], srank[s] < rspp[1], srank[s] < rspp[2]};
      const uint8_t first = s == 0;
      if (rule == kRuleEither) ClassRow<kRuleEither>(row, top_left.data(), us, prow, allowed, first, W, c_row, t_row, n);
      else if (rule == kRuleStrict) ClassRow<kRuleStrict>(row, top_left.data(), us, prow, allowed, first, W, c_row, t_row, n);
      else if (rule == kRuleThesisMeasured) ClassRow<kRuleThesisMeasured>(row, top_left.data(), us, prow, allowed, first, W, c_row, t_row, n);
      else ClassRow<kRulePixelMask>(row, top_left.data(), us, prow, allowed, first, W, c_row, t_row, n);
    }
    // Per region, in registers (a sum through memory would wait on each previous add).
    int32_t fovea = 0, periphery = 0, outside = 0;
    for (int64_t x = 0; x < W; ++x) {
      const int32_t r = row[x], v = n[x];
      fovea += r == 0 ? v : 0;
      periphery += r == 1 ? v : 0;
      outside += r == 2 ? v : 0;
    }
    band_sums[3 * job] += fovea, band_sums[3 * job + 1] += periphery, band_sums[3 * job + 2] += outside;
  }
}

// Pass 2 of `SelectSamples` over locality ranks [j0, j1) of one eye: the ranks' mandatory and
// optional samples listed apart (slot first + j·S + s), in rank order. The locality order is a
// Morton curve, so the 64 pixels of an aligned 8×8 tile inside the image are 64 consecutive
// ranks, in the tile's own Morton order: such a tile is read as eight rows of eight classes,
// made into bit masks and listed by its set bits (about one pixel in ten is traced), where one
// rank at a time waited on each rank's pixel and then its class. Other ranks (tiles cut by the
// image's edge) one at a time.
struct ListedSamples {
  const int8_t* classes;  // the eye's (S, H, W)
  const int32_t* perm;    // pixel of each locality rank
  int32_t first;          // the eye's first slot
  int64_t spp, hw, w, h;

  // The mask of a "delta swap" that exchanges index bits a < b of a 64-bit word's bits: those
  // whose index has bit a set and bit b clear, each swapped with the bit 2^b - 2^a above it.
  static constexpr uint64_t SwapMask(int a, int b) {
    uint64_t mask = 0;
    for (int j = 0; j < 64; ++j) mask |= static_cast<uint64_t>(((j >> a) & 1) && !((j >> b) & 1)) << j;
    return mask;
  }
  static inline uint64_t SwapIndexBits(uint64_t x, uint64_t mask, int shift) {
    const uint64_t t = ((x >> shift) ^ x) & mask;
    return x ^ t ^ (t << shift);
  }

  // A tile's row-major bit mask (bit y·8 + x: index bits y2 y1 y0 x2 x1 x0) in Morton order
  // (index bits y2 x2 y1 x1 y0 x0, `locality_order`'s code): three swaps of index bits.
  static inline uint64_t ToMorton(uint64_t row_major) {
    uint64_t x = SwapIndexBits(row_major, SwapMask(2, 3), 4);  // y2 y1 x2 y0 x1 x0
    x = SwapIndexBits(x, SwapMask(3, 4), 8);                    // y2 x2 y1 y0 x1 x0
    return SwapIndexBits(x, SwapMask(1, 2), 2);                 // y2 x2 y1 x1 y0 x0
  }

  // Bit x set where byte x of `v` has its lowest bit set (the other bits clear). Byte x of a
  // row's eight classes read as one word is column x on a little-endian CPU.
  static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "the tile masks read rows as little-endian words");
  static inline uint32_t LowBits(uint64_t v) {
    return static_cast<uint32_t>(((v & 0x0101010101010101ull) * 0x0102040810204080ull) >> 56);
  }

  // The tile at (x0, y0), sub-sample s: its mandatory and optional pixels as Morton-ordered bit masks.
  void TileMasks(int64_t x0, int64_t y0, int64_t s, uint64_t* mandatory, uint64_t* optional) const {
    uint64_t m = 0, o = 0;
    for (int64_t r = 0; r < 8; ++r) {
      uint64_t v;  // eight classes: 0 mandatory, 1 optional, 2 skipped
      std::memcpy(&v, classes + s * hw + (y0 + r) * w + x0, sizeof v);
      m |= static_cast<uint64_t>(LowBits(~(v | (v >> 1)))) << (8 * r);
      o |= static_cast<uint64_t>(LowBits(v)) << (8 * r);
    }
    *mandatory = ToMorton(m), *optional = ToMorton(o);
  }

  void Run(int64_t j0, int64_t j1, int32_t* m, int32_t* o, int64_t sizes[2]) const {
    const int64_t S = spp, HW = hw, W = w, H = h;  // locals: see pass 1
    int64_t nm = 0, no = 0;  // written unconditionally, kept by the counts (no branch)
    constexpr int64_t kMaxSpp = 64;
    for (int64_t j = j0; j < j1;) {
      const int64_t pix = perm[j];
      const int64_t y = pix / W, x = pix - y * W;
      if (S <= kMaxSpp && j + 64 <= j1 && (x & 7) == 0 && (y & 7) == 0 && x + 8 <= W && y + 8 <= H) {
        uint64_t mandatory[kMaxSpp], optional[kMaxSpp], live = 0;
        for (int64_t s = 0; s < S; ++s) {
          TileMasks(x, y, s, &mandatory[s], &optional[s]);
          live |= mandatory[s] | optional[s];
        }
        for (; live != 0; live &= live - 1) {
          const int k = __builtin_ctzll(live);
          for (int64_t s = 0; s < S; ++s) {
            const int32_t slot = static_cast<int32_t>(first + (j + k) * S + s);
            m[nm] = slot, o[no] = slot;
            nm += (mandatory[s] >> k) & 1, no += (optional[s] >> k) & 1;
          }
        }
        j += 64;
        continue;
      }
      for (int64_t s = 0; s < S; ++s) {
        const int8_t k = classes[s * HW + pix];
        const int32_t slot = static_cast<int32_t>(first + j * S + s);
        m[nm] = slot, o[no] = slot;
        nm += k == kMandatory, no += k == kOptional;
      }
      ++j;
    }
    sizes[0] = nm, sizes[1] = no;
  }
};

ffi::Error SelectSamples(ffi::ThreadPool pool, ffi::Buffer<ffi::F32> ecc_buf,
                         ffi::Buffer<ffi::F32> probability_left, ffi::Buffer<ffi::F32> probability_right,
                         ffi::Buffer<ffi::F32> thresholds, ffi::Buffer<ffi::U32> keys,
                         ffi::Buffer<ffi::S32> locality, ffi::Buffer<ffi::S32> region_spp,
                         ffi::Buffer<ffi::S32> subsample_rank, ffi::ResultBuffer<ffi::S8> region_out,
                         ffi::ResultBuffer<ffi::S8> classes_out,
                         ffi::ResultBuffer<ffi::S32> order_out, ffi::ResultBuffer<ffi::S32> counts_out,
                         ffi::ResultBuffer<ffi::PRED> traced_out, ffi::ResultBuffer<ffi::S32> per_pixel_out,
                         ffi::ResultBuffer<ffi::S32> by_region_out, int32_t spp, int32_t rule, int32_t block_periphery, int32_t block_outside,
                         int64_t budget) {
  const auto dims = ecc_buf.dimensions();
  if (dims.size() != 3 || dims[0] != 2) return ffi::Error::InvalidArgument("select: eccentricities must be (2, H, W)");
  const int64_t h = dims[1], w = dims[2], hw = h * w, per_eye = hw * spp;
  if (probability_left.element_count() != static_cast<size_t>(hw) ||
      probability_right.element_count() != static_cast<size_t>(hw) || thresholds.element_count() != 2 ||
      region_out->element_count() != static_cast<size_t>(2 * hw) || keys.element_count() != 4 ||
      locality.element_count() != static_cast<size_t>(hw) || region_spp.element_count() != 3 ||
      subsample_rank.element_count() != static_cast<size_t>(spp) || block_periphery < 1 || block_outside < 1) {
    return ffi::Error::InvalidArgument("select: operand shapes do not match the eccentricities");
  }
  if (rule < kRuleEither || rule > kRulePixelMask) return ffi::Error::InvalidArgument("select: an unknown rule");
  int8_t* region = region_out->typed_data();  // (2, H, W), made in pass 1
  const uint32_t* key = keys.typed_data();
  const int32_t* perm = locality.typed_data();
  const int32_t* rspp = region_spp.typed_data();
  const int32_t* srank = subsample_rank.typed_data();
  int8_t* cls = classes_out->typed_data();           // (2, S, H, W)
  int32_t* order = order_out->typed_data();          // (2 · H·W · S), locality order
  int32_t* counts = counts_out->typed_data();        // (3)
  bool* traced = traced_out->typed_data();           // (2, S, H, W)
  int32_t* per_pixel = per_pixel_out->typed_data();  // (2, H, W)
  int32_t* by_region = by_region_out->typed_data();  // (3): traced samples per region

  // Pass 1, rows in bands: each sub-sample's class, whether it is wanted, and the wanted
  // samples per pixel (the budget's drops are taken off in pass 2).
  const int64_t rows = 16;
  const int64_t bands = (h + rows - 1) / rows;
  std::vector<int64_t> band_sums(3 * 2 * bands, 0);  // wanted samples per region, per band
  const SelectBand band{ecc_buf.typed_data(), {probability_left.typed_data(), probability_right.typed_data()},
                        thresholds.typed_data()[0], thresholds.typed_data()[1], region, key, rspp, srank, cls,
                        traced, per_pixel, band_sums.data(), h, w, hw, spp, rows, bands, rule, block_periphery,
                        block_outside};
  ParallelFor(pool, 2 * bands, [&](int64_t job) { SelectBandRows(band, job); });

  // Pass 2, the locality-ordered samples in chunks: each chunk lists its mandatory and its
  // optional samples (the stable partition of `compaction_order`), then the lists go to their
  // places. Slots past the traced samples (`order` beyond the wanted ones) are never read as
  // live rays: zeros.
  const int64_t pixels_per_chunk = 8192;
  const int64_t chunks_per_eye = (hw + pixels_per_chunk - 1) / pixels_per_chunk;
  const int64_t chunks = 2 * chunks_per_eye;
  // Each chunk's two lists, allocated uninitialised (zeroing them cost more than filling them).
  std::vector<std::unique_ptr<int32_t[]>> listed(2 * chunks);
  std::vector<int64_t> listed_size(2 * chunks, 0);
  ParallelFor(pool, chunks, [&](int64_t c) {
    const int64_t eye = c / chunks_per_eye, j0 = (c % chunks_per_eye) * pixels_per_chunk;
    const int64_t j1 = std::min(hw, j0 + pixels_per_chunk);
    listed[2 * c].reset(new int32_t[static_cast<size_t>((j1 - j0) * spp)]);
    listed[2 * c + 1].reset(new int32_t[static_cast<size_t>((j1 - j0) * spp)]);
    const ListedSamples list{cls + eye * spp * hw, perm, static_cast<int32_t>(eye * per_eye), spp, hw, w, h};
    int64_t sizes[2];
    list.Run(j0, j1, listed[2 * c].get(), listed[2 * c + 1].get(), sizes);
    listed_size[2 * c] = sizes[0], listed_size[2 * c + 1] = sizes[1];
  });
  int64_t total[2] = {0, 0};
  std::vector<int64_t> offset(2 * chunks);
  for (int k = 0; k < 2; ++k)
    for (int64_t c = 0; c < chunks; ++c) {
      offset[2 * c + k] = total[k];
      total[k] += listed_size[2 * c + k];
    }
  const int64_t wanted = total[0] + total[1];
  for (int64_t c = 0; c < chunks; ++c) offset[2 * c + 1] += total[0];
  ParallelFor(pool, chunks + 1, [&](int64_t c) {
    if (c == chunks) {  // the rest of the list
      std::fill(order + wanted, order + 2 * per_eye, 0);
      return;
    }
    for (int k = 0; k < 2; ++k) {
      const int64_t size = listed_size[2 * c + k];
      if (size > 0) std::memcpy(order + offset[2 * c + k], listed[2 * c + k].get(), size * sizeof(int32_t));
    }
  });
  // Beyond the budget (`traced_mask`'s drops): the listed samples past it are not traced.
  for (int64_t rank = std::min(budget, wanted); rank < wanted; ++rank) {
    const int64_t slot = order[rank], eye = slot / per_eye, j = (slot % per_eye) / spp, s = slot % spp;
    const int64_t pix = perm[j];
    traced[(eye * spp + s) * hw + pix] = false;
    --per_pixel[eye * hw + pix];
    const int32_t r = region[eye * hw + pix];
    if (r >= 0 && r < 3) --band_sums[r];  // any band's sum: only the total is read
  }
  for (int r = 0; r < 3; ++r) {
    int64_t sum = 0;
    for (int64_t b = 0; b < 2 * bands; ++b) sum += band_sums[3 * b + r];
    by_region[r] = static_cast<int32_t>(sum);
  }
  counts[0] = static_cast<int32_t>(total[0]);
  counts[1] = static_cast<int32_t>(total[1]);
  counts[2] = static_cast<int32_t>(2 * per_eye - wanted);
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxSelectSamples, SelectSamples,
                              ffi::Ffi::Bind()
                                  .Ctx<ffi::ThreadPool>()
                                  .Arg<ffi::Buffer<ffi::F32>>()   // eccentricity (2, H, W)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the left eye's P(ω) per pixel (H, W)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the right eye's P(ω) per pixel (H, W)
                                  .Arg<ffi::Buffer<ffi::F32>>()   // the fovea's and the periphery's radii, degrees (2)
                                  .Arg<ffi::Buffer<ffi::U32>>()   // each eye's key data (2, 2)
                                  .Arg<ffi::Buffer<ffi::S32>>()   // locality order of the pixels (H·W)
                                  .Arg<ffi::Buffer<ffi::S32>>()   // samples per pixel per region (3)
                                  .Arg<ffi::Buffer<ffi::S32>>()   // each sub-sample's rank (S)
                                  .Ret<ffi::Buffer<ffi::S8>>()    // regions (2, H, W)
                                  .Ret<ffi::Buffer<ffi::S8>>()    // classes (2, S, H, W)
                                  .Ret<ffi::Buffer<ffi::S32>>()   // compaction order (2·H·W·S)
                                  .Ret<ffi::Buffer<ffi::S32>>()   // count per class (3)
                                  .Ret<ffi::Buffer<ffi::PRED>>()  // traced (2, S, H, W)
                                  .Ret<ffi::Buffer<ffi::S32>>()   // traced per pixel (2, H, W)
                                  .Ret<ffi::Buffer<ffi::S32>>()   // traced per region (3)
                                  .Attr<int32_t>("spp")
                                  .Attr<int32_t>("rule")  // 0 either, 1 strict, 2 thesis-measured
                                  .Attr<int32_t>("block_periphery")
                                  .Attr<int32_t>("block_outside")
                                  .Attr<int64_t>("budget"));
