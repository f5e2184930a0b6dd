// The full frame in one call: its camera rays, their Whitted radiance and the box filter (the
// oracle: fovjax/render/_frame.py, `camera_frame`'s reference).
#pragma once

#include "native/csrc/layout.h"
#include "native/csrc/thread_pool.h"
#include "native/csrc/threefry.h"
#include "render/_whitted.cc"

namespace {

//
// `pixel_sample_positions` → `Camera.ray_directions` → `sample_radiance` → `resolve` (→
// `side_by_side`) for one or two cameras, with the same operations in the same order: each
// sub-sample's position (its cell centre, or the frame key's threefry jitter in its cell), its
// ray, its radiance (`WhittedBlock`) and each pixel's mean of its samples, painted the bad colour
// where one is not finite. XLA neither writes the rays nor reads per-ray results: the program's
// image is the handler's output.

// `pixel_sample_positions` of one axis: the pixel's corner plus its sub-sample's cell centre, or
// with `jitter` the cell's corner plus the uniform u across the cell (the same operations).
inline float SamplePosition(float corner, float cell, bool jitter, float u, float cells) {
  return jitter ? corner + (cell + (u - 0.5f) / cells) : corner + cell;
}

// `Camera.ray_direction_components` (a unit direction) and then `radiance`'s `normalize` of it,
// for continuous pixel coordinates (x, y) of the camera row `c` (`layout.CAMERA_COLUMNS`) of an
// image width × height: the ray's origin and direction into o and d; whether `radiance` counts
// the ray (`valid`: finite, a direction not 0).
// Written without branches (`KeepWhere`), so that a loop of it vectorises (`CameraRays`).
inline __attribute__((always_inline)) bool CameraRay(const float* c, float x, float y, float width, float height,
                                                     float* o, float* d) {
  const float* r = c + 3;
  const float tan_half = c[12], aspect = c[13];
  const float sx = ((2.0f * x / width - 1.0f + c[14]) * tan_half) * aspect;
  const float sy = (1.0f - 2.0f * y / height + c[15]) * tan_half;
  float raw[3];
  for (int k = 0; k < 3; ++k) raw[k] = sx * r[3 * k] + sy * r[3 * k + 1] - r[3 * k + 2];
  const float scale = 1.0f / std::sqrt(raw[0] * raw[0] + raw[1] * raw[1] + raw[2] * raw[2]);
  for (int k = 0; k < 3; ++k) raw[k] = raw[k] * scale;  // `ray_direction_components`
  const float n2 = raw[0] * raw[0] + raw[1] * raw[1] + raw[2] * raw[2];  // `normalize`
  const float inv = KeepWhere(n2 > 0.0f, 1.0f / std::sqrt(n2));
  bool finite = true, nonzero = false;
  for (int k = 0; k < 3; ++k) {
    o[k] = c[k];
    d[k] = raw[k] * inv;
    finite = finite & std::isfinite(c[k]) & std::isfinite(raw[k]);
    nonzero = nonzero | (d[k] != 0.0f);
  }
  return finite & nonzero;
}

// `CameraRay` for the rays k < n of one camera `c` from their pixel coordinates: origins and
// directions into o and d (3 floats a ray), whether each is valid into `valid`.
FOVJAX_VECTOR_CLONES void CameraRays(const float* __restrict__ c, const float* __restrict__ xs,
                                     const float* __restrict__ ys, int64_t n, float width, float height,
                                     float* __restrict__ o, float* __restrict__ d, bool* __restrict__ valid) {
  float camera[kCameraStride];
  std::copy(c, c + kCameraStride, camera);
  for (int64_t k = 0; k < n; ++k) valid[k] = CameraRay(camera, xs[k], ys[k], width, height, o + 3 * k, d + 3 * k);
}

// The frame's shape: `eyes` cameras of height × width pixels, spp = cells² sub-samples each,
// traced as one image of sub-samples per eye, cells times the size (`sample_radiance`'s layout:
// sample (sx, sy) of pixel (x, y) at (cells·y + sy, cells·x + sx)). A block is 4 pixel rows ×
// up to `block_cols` pixel columns of one eye: 4·cells rows of sub-samples, in 4×4 tiles (each
// a packet), the tiles of 4 rows one after another, then the next 4 rows.
struct FrameLayout {
  const float* cameras;  // (eyes, kCameraStride)
  const float* grid;     // (spp, 2): the sub-samples' cell centres
  uint32_t key[2];
  bool jitter;
  int64_t eyes, h, w, spp, cells, block_cols;
  int64_t Bands() const { return (h + 3) / 4; }
  int64_t Segments() const { return (w + block_cols - 1) / block_cols; }
  int64_t Blocks() const { return eyes * Bands() * Segments(); }
  // Sub-sample columns of a block `cols` pixels wide, rounded up to whole tiles.
  int64_t TileCols(int64_t cols) const { return (cols * cells + 3) / 4 * 4; }
};

// A block's place: its eye, first pixel row and column, and its pixel columns.
struct FrameBlock {
  int64_t eye, y0, x0, cols;
  FrameBlock(const FrameLayout& L, int64_t blk) {
    const int64_t per_eye = L.Bands() * L.Segments();
    eye = blk / per_eye;
    const int64_t within = blk - eye * per_eye;
    y0 = 4 * (within / L.Segments());
    x0 = L.block_cols * (within % L.Segments());
    cols = std::min(L.block_cols, L.w - x0);
  }
};

// Per-thread scratch of a frame block.
struct FrameScratch {
  std::vector<float> o, d, total, x, y, jitter;
  std::vector<int32_t> traced, sample;
  std::vector<uint32_t> counter;
  std::vector<int32_t> col_x, col_s;  // `FrameRays`' tables of the block's columns
  std::unique_ptr<bool[]> active, valid;
  int64_t size = 0;
  void Reserve(int64_t n) {
    if (n <= size) return;
    for (auto* v : {&o, &d, &total}) v->resize(3 * n);
    for (auto* v : {&x, &y}) v->resize(n);
    jitter.resize(2 * n), counter.resize(2 * n);
    traced.resize(n), sample.resize(n);
    active.reset(new bool[n]), valid.reset(new bool[n]);
    size = n;
  }
};

// A block's rays in its tile order (`FrameLayout`): sub-samples outside the image (a ragged
// edge's) inactive. Returns the number of rays (4·cells rows × the tile columns). Each ray's
// pixel and sub-sample from tables of the block's rows and columns (no division per ray), then
// the draws and the directions in loops that vectorise.
int64_t FrameRays(const FrameLayout& L, const FrameBlock& B, FrameScratch& t) {
  const int64_t cells = L.cells, rows = 4 * cells, cols = L.TileCols(B.cols), n = rows * cols;
  t.Reserve(n);
  int32_t row_y[64], row_s[64];  // cells ≤ 16 (spp ≤ 256: `camera_frame_why_not`)
  std::vector<int32_t>&col_x = t.col_x, &col_s = t.col_s;
  col_x.resize(cols), col_s.resize(cols);
  for (int64_t r = 0; r < rows; ++r) row_y[r] = static_cast<int32_t>(B.y0 + r / cells), row_s[r] = r % cells * cells;
  for (int64_t c = 0; c < cols; ++c) col_x[c] = static_cast<int32_t>(B.x0 + c / cells), col_s[c] = c % cells;
  const int64_t inside_cols = B.cols * cells;
  const uint32_t H = static_cast<uint32_t>(L.h), W = static_cast<uint32_t>(L.w);
  const float n_cells = static_cast<float>(cells);
  int64_t i = 0;
  for (int64_t r0 = 0; r0 < rows; r0 += 4) {
    for (int64_t c0 = 0; c0 < cols; c0 += 4) {
      for (int64_t r = r0; r < r0 + 4; ++r) {
        for (int64_t c = c0; c < c0 + 4; ++c, ++i) {
          const uint32_t y = static_cast<uint32_t>(row_y[r]), x = static_cast<uint32_t>(col_x[c]);
          const int32_t sample = row_s[r] + col_s[c];
          const bool inside = c < inside_cols && y < H;
          t.active[i] = inside;
          t.sample[i] = sample;
          t.x[i] = static_cast<float>(x), t.y[i] = static_cast<float>(y);
          if (L.jitter) {
            t.counter[2 * i] = inside ? ((static_cast<uint32_t>(sample) * H + y) * W + x) * 2 : 0;
            t.counter[2 * i + 1] = t.counter[2 * i] + 1;
          } else {  // the cell centre
            t.x[i] = SamplePosition(t.x[i], L.grid[2 * sample], false, 0.0f, n_cells);
            t.y[i] = SamplePosition(t.y[i], L.grid[2 * sample + 1], false, 0.0f, n_cells);
          }
        }
      }
    }
  }
  if (L.jitter) {
    UniformAt(L.key[0], L.key[1], t.counter.data(), 2 * n, t.jitter.data());
    for (int64_t k = 0; k < n; ++k) {
      const float* cell = L.grid + 2 * t.sample[k];
      t.x[k] = SamplePosition(t.x[k], cell[0], true, t.jitter[2 * k], n_cells);
      t.y[k] = SamplePosition(t.y[k], cell[1], true, t.jitter[2 * k + 1], n_cells);
    }
  }
  CameraRays(L.cameras + kCameraStride * B.eye, t.x.data(), t.y.data(), n, static_cast<float>(W),
             static_cast<float>(H), t.o.data(), t.d.data(), t.valid.get());
  for (int64_t k = 0; k < n; ++k) t.valid[k] = t.valid[k] & t.active[k];
  return n;
}

ffi::Error CameraFrame(ffi::ThreadPool pool, ffi::Buffer<ffi::U32> key, ffi::Buffer<ffi::F32> grid,
                       ffi::Buffer<ffi::F32> cameras, ffi::Buffer<ffi::F32> bad_color, FOVJAX_SCENE_PARAMS,
                       ffi::ResultBuffer<ffi::F32> image_out, ffi::ResultBuffer<ffi::S32> counts_out,
                       int32_t spp, int32_t height, int32_t width, int32_t jitter, int32_t max_depth,
                       int32_t recompute, int32_t packets, int32_t robust, int32_t specular,
                       int32_t specular_payload, float min_contribution) {
  if (g_device == nullptr) return ffi::Error::Internal("fovjax Embree backend used before init");
  int64_t cells = 1;
  while (cells * cells < spp) ++cells;
  const int64_t eyes = static_cast<int64_t>(cameras.element_count() / kCameraStride);
  const int64_t hw = static_cast<int64_t>(height) * width;
  if (spp < 1 || cells * cells != spp || cells > 16 || height < 1 || width < 1 || (eyes != 1 && eyes != 2) ||
      cameras.element_count() != static_cast<size_t>(eyes * kCameraStride) ||
      2 * spp * hw >= (int64_t{1} << 32) || key.element_count() != 2 ||
      grid.element_count() != 2 * static_cast<size_t>(spp) || bad_color.element_count() != 3 ||
      image_out->element_count() != static_cast<size_t>(3 * eyes * hw) || counts_out->element_count() != 5) {
    return ffi::Error::InvalidArgument("fovjax camera frame: operand shapes do not match the image");
  }
  HandlerScene scene;
  const Shading shading{specular, specular_payload != 0, min_contribution};
  ffi::Error status = scene.Load(FOVJAX_SCENE_ARGS, max_depth, recompute, robust, shading);
  if (status.failure()) return status;
  const ShadeScene& s = scene.s;
  const FrameLayout L{cameras.typed_data(), grid.typed_data(), {key.typed_data()[0], key.typed_data()[1]},
                      jitter != 0, eyes, height, width, spp, cells, std::max<int64_t>(1, 256 / cells)};
  const NativeScene& t = *scene.tree;
  const float* bad = bad_color.typed_data();
  float* image = image_out->typed_data();
  const float mean = static_cast<float>(spp);
  std::atomic<int64_t> counts[5] = {0, 0, 0, 0, 0};
  ParallelFor(pool, L.Blocks(), [&](int64_t blk) {
    FrameScratch& scratch = ThreadLocal<FrameScratch>();
    const FrameBlock B(L, blk);
    const int64_t n = FrameRays(L, B, scratch);
    BlockRays block;
    block.n = n;
    WhittedBlock(t, s, scratch.o.data(), scratch.d.data(), scratch.active.get(), block, scratch.total.data(),
                 scratch.traced.data(), packets != 0, false);
    int64_t primary = 0, shadow = 0, reflection = 0, bad_samples = 0, bad_pixels = 0;
    for (int64_t i = 0; i < n; ++i) {
      primary += scratch.valid[i];
      shadow += scratch.traced[i] >> 8;
      reflection += scratch.traced[i] & 255;
    }
    // Each pixel: its samples summed in sample order, then the mean (`resolve`; with one
    // sample, the sample: x / 1 is x).
    const int64_t tiles = L.TileCols(B.cols) / 4, rows = std::min<int64_t>(4, height - B.y0);
    for (int64_t py = 0; py < rows; ++py) {
      // The eyes side by side: row y holds eye 0's W pixels, then eye 1's.
      float* out = image + 3 * (((B.y0 + py) * eyes + B.eye) * width + B.x0);
      if (spp == 1) {
        for (int64_t px = 0; px < B.cols; ++px) {
          const float* rgb = &scratch.total[3 * ((px / 4) * 16 + py * 4 + px % 4)];
          const bool finite = std::isfinite(rgb[0]) & std::isfinite(rgb[1]) & std::isfinite(rgb[2]);
          bad_samples += !finite;
          for (int k = 0; k < 3; ++k) out[3 * px + k] = finite ? rgb[k] : bad[k];
        }
        continue;
      }
      for (int64_t px = 0; px < B.cols; ++px) {
        float sum[3] = {0.0f, 0.0f, 0.0f};
        bool pixel_bad = false;
        for (int64_t sy = 0; sy < cells; ++sy) {  // sample sy·cells + sx, in sample order
          for (int64_t sx = 0; sx < cells; ++sx) {
            const int64_t r = py * cells + sy, c = px * cells + sx;
            const int64_t i = (r / 4) * 16 * tiles + (c / 4) * 16 + (r % 4) * 4 + c % 4;
            const float* rgb = &scratch.total[3 * i];
            const bool finite = std::isfinite(rgb[0]) && std::isfinite(rgb[1]) && std::isfinite(rgb[2]);
            bad_samples += !finite;
            pixel_bad = pixel_bad || !finite;
            for (int k = 0; k < 3; ++k) sum[k] = sy == 0 && sx == 0 ? rgb[k] : sum[k] + rgb[k];
          }
        }
        bad_pixels += pixel_bad;
        for (int k = 0; k < 3; ++k) out[3 * px + k] = pixel_bad ? bad[k] : sum[k] / mean;
      }
    }
    if (spp == 1) bad_pixels = bad_samples;
    counts[0] += primary, counts[1] += shadow, counts[2] += reflection;
    counts[3] += bad_samples, counts[4] += bad_pixels;
  });
  status = scene.Checked(kFaceOutOfRange);
  if (status.failure()) return status;
  for (int k = 0; k < 5; ++k) counts_out->typed_data()[k] = static_cast<int32_t>(counts[k].load());
  return ffi::Error::Success();
}

}  // namespace

// The attributes of the handlers that make their camera rays (this one, the foveated frame's
// slots): the sub-samples, the image and the integrator's options.
template <typename Binding>
auto WithCameraRayAttrs(Binding binding) {
  return std::move(binding)
      .template Attr<int32_t>("spp")
      .template Attr<int32_t>("height")
      .template Attr<int32_t>("width")
      .template Attr<int32_t>("jitter")
      .template Attr<int32_t>("max_depth")
      .template Attr<int32_t>("recompute")
      .template Attr<int32_t>("packets")
      .template Attr<int32_t>("robust")
      .template Attr<int32_t>("specular")  // as the Whitted handler's
      .template Attr<int32_t>("specular_payload")
      .template Attr<float>("min_contribution");
}

XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxCameraFrame, CameraFrame,
                              WithCameraRayAttrs(WithSceneArgs(ffi::Ffi::Bind()
                                                .Ctx<ffi::ThreadPool>()
                                                .Arg<ffi::Buffer<ffi::U32>>()   // the frame key's data (2)
                                                .Arg<ffi::Buffer<ffi::F32>>()   // sub-sample cell centres (S, 2)
                                                .Arg<ffi::Buffer<ffi::F32>>()   // the cameras (E, 16), E 1 or 2
                                                .Arg<ffi::Buffer<ffi::F32>>())  // the bad colour (3)
                                  .Ret<ffi::Buffer<ffi::F32>>()   // the image (H, E·W, 3)
                                  .Ret<ffi::Buffer<ffi::S32>>()));  // primary, shadow, reflection rays, bad samples, bad pixels
