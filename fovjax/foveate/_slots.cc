// The foveated frame's slots (its oracle: fovjax/foveate/_frame.py, `traced_sums`' chunked path).
#pragma once

#include "native/csrc/layout.h"
#include "native/csrc/thread_pool.h"
#include "render/_frame.cc"
#include "render/_whitted.cc"
#include "foveate/_select.cc"

namespace {

//
// `fovjax.foveate._frame.trace_selection` through the native integrator with `sample_adder`
// consuming its chunks, in one call: each live slot's primary ray from its index
// (`_slot_samples`, `positions_at`, `Camera.ray_directions`, `normalize`: the same operations
// in the same order), its Whitted radiance (`WhittedBlock`), then every slot's radiance added to
// its pixel in slot order, as the chunks add them. Its work is the live slots' (the chunk loop's
// per-chunk operations around the integrator are gone). With shading classes (per-region
// fidelity: `ShadingClasses` tables, traced operands) a slot's class is its pixel's region, as
// `trace_selection`'s `class_at` has it, and `WhittedBlock` applies its class's reflection depth,
// shadow mode and tree of a merged BVH to it and to its reflections. Where `first_point_out` is
// not empty, each pixel's sub-sample 0's primary hit point too (a miss: `far` along the ray; 0
// where that sub-sample is not live), `first_hit_points`' values.

struct SlotLayout {
  const int32_t* order;
  const int32_t* locality;  // (H·W): pixel of each locality rank
  const float* grid;        // (S, 2): the sub-samples' cell centres
  const float* cameras;     // (2, kCameraStride)
  uint32_t key[2];
  bool jitter;
  int64_t spp, h, w, per_eye, cells;  // cells: the strata per row, sqrt(spp)
};

// Per-block scratch of `SlotRays`.
struct SlotScratch {
  std::vector<float> x, y, jitter;
  std::vector<uint32_t> counter;
  std::vector<int32_t> eye, sample, px, py;
  void Reserve(int64_t n) {
    for (auto* v : {&x, &y}) v->resize(n);
    jitter.resize(2 * n), counter.resize(2 * n);
    for (auto* v : {&eye, &sample, &px, &py}) v->resize(n);
  }
};

// A tracing block's buffers, one set per thread (`ThreadLocal`), kept from call to call.
struct SlotBlockBuffers {
  std::vector<float> o, d;
  SlotScratch scratch;
  std::unique_ptr<bool[]> active;
  std::vector<int32_t> ray_class;
};

// Division by a divisor fixed for a loop, as a multiply and a shift (Granlund and Montgomery,
// 1994): for 0 <= a < 2^31 and d >= 1, a / d = (a·m) >> shift with l = ceil(log2 d), m =
// ceil(2^(31 + l) / d) < 2^32 and shift = 31 + l, exactly. GCC vectorises the multiply, where it
// leaves an integer division scalar.
struct Divisor {
  uint32_t m, shift;
  explicit Divisor(uint32_t divisor) {
    uint32_t l = 0;
    while ((uint64_t{1} << l) < divisor) ++l;
    shift = 31 + l;
    m = static_cast<uint32_t>(((uint64_t{1} << shift) + divisor - 1) / divisor);
  }
};
inline uint32_t Quotient(uint32_t a, uint32_t m, uint32_t shift) {
  return static_cast<uint32_t>((static_cast<uint64_t>(a) * m) >> shift);
}

// The slots at `position` [0, n): each one's eye, sub-sample, pixel column and row, and its
// jitter draws' threefry counters. The index arithmetic in 32 bits (the caller checks the sizes).
FOVJAX_VECTOR_CLONES
void SlotPositions(const int32_t* __restrict__ order, const int32_t* __restrict__ locality,
                   const int32_t* __restrict__ position, int64_t n, uint32_t S, uint32_t H, uint32_t W,
                   uint32_t per_eye, uint32_t* __restrict__ counter, int32_t* __restrict__ eyes,
                   int32_t* __restrict__ samples, int32_t* __restrict__ xs, int32_t* __restrict__ ys) {
  // (each array its own restrict parameter: GCC gathers only where it knows them apart)
  const Divisor by_s(S), by_w(W);
  const uint32_t ms = by_s.m, ss = by_s.shift, mw = by_w.m, sw = by_w.shift;
  for (int64_t i = 0; i < n; ++i) {
    const uint32_t slot = static_cast<uint32_t>(order[position[i]]);
    const uint32_t eye = slot >= per_eye, within = slot - eye * per_eye;  // two eyes
    const uint32_t rank = Quotient(within, ms, ss), sample = within - rank * S;
    const uint32_t pixel = static_cast<uint32_t>(locality[static_cast<int32_t>(rank)]);  // (int32: a 32-bit gather)
    const uint32_t y = Quotient(pixel, mw, sw), x = pixel - y * W;
    counter[2 * i] = ((sample * H + y) * W + x) * 2;
    counter[2 * i + 1] = ((sample * H + y) * W + x) * 2 + 1;
    eyes[i] = static_cast<int32_t>(eye), samples[i] = static_cast<int32_t>(sample);
    xs[i] = static_cast<int32_t>(x), ys[i] = static_cast<int32_t>(y);
  }
}

// Each slot's continuous pixel coordinates (`pixel_sample_positions`).
FOVJAX_VECTOR_CLONES
void SlotSamplePositions(const int32_t* __restrict__ px, const int32_t* __restrict__ py,
                         const int32_t* __restrict__ sample, const float* __restrict__ grid,
                         const float* __restrict__ jitter, bool jittered, float cells, int64_t n,
                         float* __restrict__ x, float* __restrict__ y) {
  for (int64_t i = 0; i < n; ++i) {
    const float u = jittered ? jitter[2 * i] : 0.0f, v = jittered ? jitter[2 * i + 1] : 0.0f;
    x[i] = SamplePosition(static_cast<float>(px[i]), grid[2 * sample[i]], jittered, u, cells);
    y[i] = SamplePosition(static_cast<float>(py[i]), grid[2 * sample[i] + 1], jittered, v, cells);
  }
}

// Slots [begin, begin + n) as rays (o, d, active) and whether each is valid (a primary ray
// `radiance` counts); the pixel each goes to in `target`: the slots' pixels, their positions,
// then the directions through `CameraRays` for each run of one eye's slots (the compaction lists
// each eye's samples in long runs), loops over lanes that vectorise.
void SlotRays(const SlotLayout& L, const int32_t* position, int64_t begin, int64_t n, float* o, float* d,
              bool* active, bool* valid, int32_t* target, SlotScratch& t) {
  const uint32_t W = static_cast<uint32_t>(L.w), H = static_cast<uint32_t>(L.h);
  SlotPositions(L.order, L.locality, position + begin, n, static_cast<uint32_t>(L.spp), H, W,
                static_cast<uint32_t>(L.per_eye), t.counter.data(), t.eye.data(), t.sample.data(), t.px.data(),
                t.py.data());
  const int32_t h = static_cast<int32_t>(H), w = static_cast<int32_t>(W);
  for (int64_t i = 0; i < n; ++i) target[i] = (t.eye[i] * h + t.py[i]) * w + t.px[i];
  if (L.jitter) UniformAt(L.key[0], L.key[1], t.counter.data(), 2 * n, t.jitter.data());
  SlotSamplePositions(t.px.data(), t.py.data(), t.sample.data(), L.grid, t.jitter.data(), L.jitter,
                      static_cast<float>(L.cells), n, t.x.data(), t.y.data());
  std::fill(active, active + n, true);
  for (int64_t i0 = 0, i1 = 0; i0 < n; i0 = i1) {
    while (i1 < n && t.eye[i1] == t.eye[i0]) ++i1;
    CameraRays(L.cameras + kCameraStride * t.eye[i0], t.x.data() + i0, t.y.data() + i0, i1 - i0,
               static_cast<float>(W), static_cast<float>(H), o + 3 * i0, d + 3 * i0, valid + i0);
  }
}

ffi::Error WhittedSlots(ffi::ThreadPool pool, ffi::Buffer<ffi::S32> order, ffi::Buffer<ffi::S32> n_live,
                        ffi::Buffer<ffi::U32> key, ffi::Buffer<ffi::S32> locality,
                        ffi::Buffer<ffi::F32> grid, ffi::Buffer<ffi::F32> cameras,
                        ffi::Buffer<ffi::S32> region, ffi::Buffer<ffi::S32> class_depth,
                        ffi::Buffer<ffi::S32> class_shadows, ffi::Buffer<ffi::S32> class_level,
                        ffi::Buffer<ffi::F32> far,
                        FOVJAX_SCENE_PARAMS,
                        ffi::ResultBuffer<ffi::F32> sums_out, ffi::ResultBuffer<ffi::PRED> bad_out,
                        ffi::ResultBuffer<ffi::S32> counts_out, ffi::ResultBuffer<ffi::S32> path_prim,
                        ffi::ResultBuffer<ffi::U32> path_visible,
                        ffi::ResultBuffer<ffi::F32> first_point_out, int32_t spp, int32_t height,
                        int32_t width, int32_t jitter, int32_t max_depth, int32_t recompute,
                        int32_t packets, int32_t robust, int32_t specular, int32_t specular_payload,
                        float min_contribution) {
  if (g_device == nullptr) return ffi::Error::Internal("fovjax Embree backend used before init");
  const int64_t hw = static_cast<int64_t>(height) * width, per_eye = hw * spp;
  int64_t cells = 1;
  while (cells * cells < spp) ++cells;
  if (spp < 1 || cells * cells != spp || height < 1 || width < 1 || 2 * per_eye >= (int64_t{1} << 31) ||
      n_live.element_count() != 1 || key.element_count() != 2 ||
      locality.element_count() != static_cast<size_t>(hw) ||
      grid.element_count() != 2 * static_cast<size_t>(spp) ||
      cameras.element_count() != 2 * static_cast<size_t>(kCameraStride) ||
      sums_out->element_count() != 6 * static_cast<size_t>(hw) ||
      bad_out->element_count() != 2 * static_cast<size_t>(hw) || counts_out->element_count() != 4 ||
      first_point_out->element_count() != (far.element_count() == 1 ? 6 * static_cast<size_t>(hw) : 0) ||
      far.element_count() > 1) {
    return ffi::Error::InvalidArgument("fovjax slots: operand shapes do not match the image");
  }
  HandlerScene scene;
  const Shading shading{specular, specular_payload != 0, min_contribution};
  ffi::Error status = scene.Load(FOVJAX_SCENE_ARGS, max_depth, recompute, robust, shading);
  if (status.failure()) return status;
  ShadeScene& s = scene.s;
  // Per-region fidelity: a slot's class is its pixel's region (`trace_selection`'s `class_at`).
  status = ClassesFrom(class_depth, class_shadows, class_level, &s);
  if (status.failure()) return status;
  const bool classes = s.class_depth != nullptr;
  if (region.element_count() != (classes ? 2 * static_cast<size_t>(hw) : 0)) {
    return ffi::Error::InvalidArgument(
        "fovjax slots: the regions are (2, H, W) with class tables and empty without");
  }
  const int32_t* pixel_class = classes ? region.typed_data() : nullptr;
  const int64_t n = std::max<int64_t>(
      0, std::min<int64_t>(n_live.typed_data()[0], static_cast<int64_t>(order.element_count())));
  // Each slot's path (`PathsOut`, a column per slot of `order`), where the buffers are not empty.
  const int64_t levels = static_cast<int64_t>(max_depth) + 1;
  const int64_t slots = static_cast<int64_t>(order.element_count());
  const bool store = path_prim->element_count() != 0;
  if ((store && (path_prim->element_count() != static_cast<size_t>(levels * slots) ||
                 path_visible->element_count() != static_cast<size_t>(levels * slots) ||
                 light_kind.element_count() > 32)) ||
      (!store && path_visible->element_count() != 0)) {
    return ffi::Error::InvalidArgument("fovjax slots: paths are (max_depth + 1) x slots, for at most 32 lights");
  }
  const PathsOut paths{path_prim->typed_data(), path_visible->typed_data(), slots, levels, nullptr};
  if (store) paths.Clear();
  SlotLayout L{order.typed_data(), locality.typed_data(), grid.typed_data(), cameras.typed_data(),
               {key.typed_data()[0], key.typed_data()[1]}, jitter != 0, spp, height, width, per_eye, cells};
  for (int64_t i = 0; i < n; ++i) {
    if (L.order[i] < 0 || L.order[i] >= 2 * per_eye) {
      return ffi::Error::InvalidArgument("fovjax slots: a live slot is outside the image's samples");
    }
  }
  // Each live slot's radiance, rays traced, valid flag and pixel (scratch for the sums below).
  std::unique_ptr<float[]> radiance(new float[3 * std::max<int64_t>(n, 1)]);
  std::unique_ptr<int32_t[]> traced(new int32_t[std::max<int64_t>(n, 1)]);
  std::unique_ptr<int32_t[]> target(new int32_t[std::max<int64_t>(n, 1)]);
  std::unique_ptr<bool[]> valid(new bool[std::max<int64_t>(n, 1)]);
  const bool first_points = far.element_count() == 1;
  std::unique_ptr<float[]> point(first_points ? new float[3 * std::max<int64_t>(n, 1)] : nullptr);
  // The order the slots are traced in: the live slots are two ascending runs (the mandatory
  // samples, then the optional ones, each in locality order), merged so that neighbouring
  // samples of both classes share packets; `traced_at[i]`: where slot i was traced. The sums
  // below still go in slot order.
  std::unique_ptr<int32_t[]> position(new int32_t[std::max<int64_t>(n, 1)]);
  std::unique_ptr<int32_t[]> traced_at(new int32_t[std::max<int64_t>(n, 1)]);
  int64_t runs = 0;  // where the second ascending run begins (0: the slots are not two runs)
  {
    const int32_t* o = L.order;
    int64_t split = 1;
    while (split < n && o[split] > o[split - 1]) ++split;
    int64_t end = split + 1;
    while (end < n && o[end] > o[end - 1]) ++end;
    int64_t k = 0;
    if (split < n && end >= n) {
      runs = split;
      int64_t a = 0, b = split;
      while (a < split && b < n) position[k++] = static_cast<int32_t>(o[a] < o[b] ? a++ : b++);
      while (a < split) position[k++] = static_cast<int32_t>(a++);
      while (b < n) position[k++] = static_cast<int32_t>(b++);
    } else {
      for (; k < n; ++k) position[k] = static_cast<int32_t>(k);
    }
    for (int64_t i = 0; i < n; ++i) traced_at[position[i]] = static_cast<int32_t>(i);
  }
  const NativeScene& t = *scene.tree;
  const int64_t per_block = 1024, blocks = (n + per_block - 1) / per_block;
  // The per-pixel outputs zeroed a slice per block, beside the block's tracing: the stores are
  // bound by memory, the tracing by arithmetic, so the zeroing costs little there (a separate
  // pass after the tracing cost its whole memory time).
  float* sums = sums_out->typed_data();
  bool* bad = bad_out->typed_data();
  float* pixel_point = first_point_out->typed_data();
  const int64_t pixels = 2 * hw, jobs = std::max<int64_t>(blocks, 1);
  ParallelFor(pool, jobs, [&](int64_t blk) {
    const int64_t p0 = pixels * blk / jobs, p1 = pixels * (blk + 1) / jobs;
    std::fill(sums + 3 * p0, sums + 3 * p1, 0.0f);
    std::fill(bad + p0, bad + p1, false);
    if (first_points) std::fill(pixel_point + 3 * p0, pixel_point + 3 * p1, 0.0f);
    if (blk >= blocks) return;
    SlotBlockBuffers& buffers = ThreadLocal<SlotBlockBuffers>();
    std::vector<float>&o = buffers.o, &d = buffers.d;
    SlotScratch& scratch = buffers.scratch;
    std::unique_ptr<bool[]>& active = buffers.active;
    std::vector<int32_t>& ray_class = buffers.ray_class;
    o.resize(3 * per_block), d.resize(3 * per_block);
    scratch.Reserve(per_block);
    if (!active) active.reset(new bool[per_block]);
    const int64_t begin = blk * per_block, m = std::min(n, begin + per_block) - begin;
    SlotRays(L, position.get(), begin, m, o.data(), d.data(), active.get(), valid.get() + begin,
             target.get() + begin, scratch);
    BlockRays block;
    block.n = m;
    block.primary_point = first_points ? point.get() + 3 * begin : nullptr;
    block.miss_t = first_points ? far.typed_data()[0] : 0.0f;
    PathsOut block_paths = paths;
    block_paths.column = position.get() + begin;  // the slots these rays are
    if (classes) {
      ray_class.resize(per_block);
      for (int64_t i = 0; i < m; ++i) ray_class[i] = pixel_class[target[begin + i]];
    }
    WhittedBlock(t, s, o.data(), d.data(), active.get(), block, radiance.get() + 3 * begin,
                 traced.get() + begin, packets != 0, true, store ? &block_paths : nullptr,
                 classes ? ray_class.data() : nullptr);
  });
  status = scene.Checked(kFaceOutOfRange);
  if (status.failure()) return status;
  // The sums, per eye on its own task: every slot's radiance added to its pixel in slot order
  // (`sample_adder`: a sample whose radiance is not finite adds nothing and marks its pixel).
  int64_t eye_counts[2][4] = {{0, 0, 0, 0}, {0, 0, 0, 0}};
  ParallelFor(pool, 2, [&](int64_t eye) {
    bool* eye_bad = bad + eye * hw;
    const int32_t first = static_cast<int32_t>(eye * hw);
    // This eye's slots by their indices (an eye's samples are one range of them), read in
    // order: the other eye's slots cost no reads of where they were traced.
    const int32_t* order_of = L.order;
    const int32_t own_lo = static_cast<int32_t>(eye * per_eye), own_hi = static_cast<int32_t>(own_lo + per_eye);
    int64_t primary = 0, shadow = 0, reflection = 0, n_bad = 0;
    // Where the slots are two ascending runs, this eye's are one range of each (found by
    // bisection); else every slot is looked at. The pixels' sums a few slots ahead are fetched
    // early: each slot's is a miss of its own.
    int64_t ranges[2][2] = {{0, n}, {n, n}};
    if (runs > 0) {
      for (int r = 0; r < 2; ++r) {
        const int32_t* lo = order_of + (r == 0 ? 0 : runs);
        const int32_t* hi = order_of + (r == 0 ? runs : n);
        ranges[r][0] = std::lower_bound(lo, hi, own_lo) - order_of;
        ranges[r][1] = std::lower_bound(lo, hi, own_hi) - order_of;
      }
    }
    constexpr int64_t kAhead = 16;
    for (const auto& range : ranges) {
      for (int64_t i = range[0]; i < range[1]; ++i) {
        if (i + kAhead < range[1]) __builtin_prefetch(sums + 3 * static_cast<int64_t>(target[traced_at[i + kAhead]]), 1);
        if (order_of[i] < own_lo || order_of[i] >= own_hi) continue;
        const int64_t k = traced_at[i];
        const int32_t px = target[k];
        if (first_points && (order_of[i] - own_lo) % spp == 0) {
          std::copy(point.get() + 3 * k, point.get() + 3 * k + 3, pixel_point + 3 * static_cast<int64_t>(px));
        }
        const float* rgb = radiance.get() + 3 * k;
        primary += valid[k];
        shadow += traced[k] >> 8;
        reflection += traced[k] & 255;
        if (!(std::isfinite(rgb[0]) && std::isfinite(rgb[1]) && std::isfinite(rgb[2]))) {
          eye_bad[px - first] = true;
          ++n_bad;
          continue;
        }
        float* out = sums + 3 * static_cast<int64_t>(px);
        out[0] += rgb[0], out[1] += rgb[1], out[2] += rgb[2];
      }
    }
    eye_counts[eye][0] = primary, eye_counts[eye][1] = shadow;
    eye_counts[eye][2] = reflection, eye_counts[eye][3] = n_bad;
  });
  for (int k = 0; k < 4; ++k) counts_out->typed_data()[k] = static_cast<int32_t>(eye_counts[0][k] + eye_counts[1][k]);
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxWhittedSlots, WhittedSlots,
                              WithCameraRayAttrs(WithSceneArgs(ffi::Ffi::Bind()
                                                .Ctx<ffi::ThreadPool>()
                                                .Arg<ffi::Buffer<ffi::S32>>()   // slots in compaction order (P)
                                                .Arg<ffi::Buffer<ffi::S32>>()   // live slots (1)
                                                .Arg<ffi::Buffer<ffi::U32>>()   // the frame key's data (2)
                                                .Arg<ffi::Buffer<ffi::S32>>()   // locality order (H·W)
                                                .Arg<ffi::Buffer<ffi::F32>>()   // sub-sample cell centres (S, 2)
                                                .Arg<ffi::Buffer<ffi::F32>>()   // the eyes' cameras (2, 16)
                                                .Arg<ffi::Buffer<ffi::S32>>()   // region per pixel (2·H·W) or empty
                                                .Arg<ffi::Buffer<ffi::S32>>()   // class max_depth (K) or empty
                                                .Arg<ffi::Buffer<ffi::S32>>()   // class shadow mode (K) or empty
                                                .Arg<ffi::Buffer<ffi::S32>>()   // class tree (K) or empty
                                                .Arg<ffi::Buffer<ffi::F32>>())  // a miss's distance (1) or empty
                                  .Ret<ffi::Buffer<ffi::F32>>()   // per-pixel sums (2·H·W, 3)
                                  .Ret<ffi::Buffer<ffi::PRED>>()  // bad pixel (2·H·W)
                                  .Ret<ffi::Buffer<ffi::S32>>()   // primary, shadow, reflection rays, bad samples
                                  .Ret<ffi::Buffer<ffi::S32>>()   // paths' faces ((max_depth + 1) x P) or empty
                                  .Ret<ffi::Buffer<ffi::U32>>()   // paths' unblocked lights, bits, or empty
                                  .Ret<ffi::Buffer<ffi::F32>>()));  // sub-sample 0's hit point (2·H·W, 3) or empty
