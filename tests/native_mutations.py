"""Mutation check of the native Whitted integrator: each of a table of one-line mistakes, made in
a copy of the package, must make tests/test_render_native.py fail.

    python tests/native_mutations.py                       # the unmutated copy, then every mutation
    python tests/native_mutations.py --list                # the table
    python tests/native_mutations.py shadow-ignored one-bounce-more
    python tests/native_mutations.py --tests tests/test_render_native.py tests/test_render.py
    python tests/native_mutations.py -k slots              # only the tests pytest -k selects

For each mutation: the package (fovjax/) is copied to a temporary directory; the mutation's
snippet must occur exactly once in all of the copy's C++ sources (every *.cc and *.h under
fovjax/, wherever they lie: `fovjax.native.sources()`, what the build compiles) and is replaced
there; the native library is built from the copy into a directory of its own (FOVJAX_NATIVE_DIR
and FOVJAX_CACHE_DIR point into the temporary directory, so the real cache and sources are never
touched) and a probe checks that the copy is the package imported, that its library loads and
that the mutated file is among the sources it was built from;
then the test files run (pytest -x, one process) with the copy imported in place of the
checkout's package. The mutation is caught when they fail. The unmutated copy runs first, the
same way, and must pass without a skip: otherwise a failure would mean nothing.

Exit status 0 when every mutation chosen is caught; 1 when one survives, a snippet is missing or
found more than once, a mutated copy does not build, or the unmutated copy does not pass; 2 for a
bad command line.

To mutation-test a change of the native code: add the mistakes it could hide to MUTATIONS (a
name, what it means, an exact snippet of the source and its replacement; one line each is best)
and run the script. Each mutation takes a build of the library (about a minute on two cores) and
the test files up to their first failure.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import NamedTuple

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "fovjax"
DEFAULT_TESTS = ("tests/test_render_native.py",)
SOURCE_SUFFIXES = (".cc", ".h")


class Mutation(NamedTuple):
    name: str
    description: str
    snippet: str  # exact text of the source, found exactly once among the package's C++ sources
    replacement: str


MUTATIONS = (
    Mutation(
        "specular-exponent",
        "the specular exponent one more than the material's Ns",
        "spec_out[k] = KeepWhere(cosine > 0.0f, PowOf(cosine, shininess));",
        "spec_out[k] = KeepWhere(cosine > 0.0f, PowOf(cosine, shininess + 1.0f));",
    ),
    Mutation(
        "shadow-ignored",
        "a blocked shadow ray does not darken its light",
        "if (b.sprim[j] >= 0) continue;",
        "if (false && b.sprim[j] >= 0) continue;",
    ),
    Mutation(
        "one-bounce-fewer",
        "reflections stop one level before max_depth",
        "const bool spawn = depth < s.max_depth;",
        "const bool spawn = depth + 1 < s.max_depth;",
    ),
    Mutation(
        "one-bounce-more",
        "reflections go one level past max_depth",
        "const bool spawn = depth < s.max_depth;",
        "const bool spawn = depth <= s.max_depth;",
    ),
    Mutation(
        "unbounded-shadow",
        "a positional light's shadow ray not bounded at the light (tfar = infinity)",
        "far_out[k] = kPositional ? (n2 > 0.0f ? root : 0.0f) : INFINITY;",
        "far_out[k] = INFINITY;",
    ),
    Mutation(
        "light-planes-back-face-light",
        "a light behind the geometric face (n_g·l <= 0) still wanted where the shading normal faces it",
        "wanted_out[k] = (ndl > 0.0f) & (Dot(ng, dir) > 0.0f) & (spot > 0.0f);",
        "wanted_out[k] = (ndl > 0.0f) & (spot > 0.0f);",
    ),
    Mutation(
        "light-planes-spot-hard-edge",
        "a spot light's cone has no ramp between its inner and outer half-angles (1 out to the outer)",
        "spot = Choose(c >= cos_inner, 1.0f, KeepWhere(c > cos_outer, ramp));",
        "spot = Choose(c >= cos_inner, 1.0f, KeepWhere(c > cos_outer, 1.0f));",
    ),
    Mutation(
        "light-planes-phong-unmirrored",
        "Phong's mirrored light direction without the factor 2 (r = (n·l) n - l)",
        "const Vec3 mirrored = (2.0f * ndl) * nsh - dir;",
        "const Vec3 mirrored = ndl * nsh - dir;",
    ),
    Mutation(
        "light-planes-half-vector-unnormalised",
        "Blinn–Phong's half vector not normalised",
        "cosine = Dot(nsh, NormalizeEither(dir - dk));",
        "cosine = Dot(nsh, dir - dk);",
    ),
    Mutation(
        "uncompounded-reflection",
        "a reflection's weight is the last mirror's Kr, not the product along the path",
        "w = w * kr;",
        "w = kr;",
    ),
    Mutation(
        "class-depth-ignored",
        "a shading class's reflection depth is not applied (every class reflects to max_depth)",
        "if (!(depth < s.class_depth[b.cls[k]])) continue;",
        "if (false) continue;",
    ),
    Mutation(
        "class-untested-light-dark",
        "a light whose shadow ray a class does not trace is dropped instead of shining unshadowed",
        "if (!kClasses || Tested(s, b.cls[k], l)) {  // else no ray: unshadowed",
        "if (kClasses && !Tested(s, b.cls[k], l)) continue;\n          if (true) {",
    ),
    Mutation(
        "class-brightest-first",
        "SHADOWS_BRIGHTEST tests the first light instead of the one of the largest R + G + B",
        "s->brightest = l;",
        "s->brightest = 0;",
    ),
    Mutation(
        "class-level-ignored",
        "every class's rays traced against the merged BVH's first tree",
        "const bool levels = kClasses && s.class_level != nullptr;",
        "const bool levels = false;",
    ),
    Mutation(
        "adjoint-shininess-linear",
        "the adjoint's d spec / d Ns without the log of the cosine",
        "dm[15] += static_cast<double>(spec) * std::log(static_cast<double>(cosine)) *",
        "dm[15] += static_cast<double>(spec) *",
    ),
    Mutation(
        "adjoint-reflectance-local",
        "the adjoint's d / d Kr from the level's own radiance instead of what follows it",
        "Add3(dm + 12, g * weight_at[k] * after);",
        "Add3(dm + 12, g * weight_at[k] * radiance_at[k]);",
    ),
    Mutation(
        "adjoint-texture-ignored",
        "the adjoint's d / d Kd without the texture's factor",
        "Add3(dm + 3, gw * texture * (ndl * color));  // kd",
        "Add3(dm + 3, gw * (ndl * color));  // kd",
    ),
    Mutation(
        "adjoint-kd-alone-untextured",
        "the adjoint's d / d Kd without the texture's factor where Kd alone moves (no specular term)",
        "if (!specular) {  // Kd's term alone (and Ka's, Ke's, the ambient's above)\n"
        "        Add3(dm + 3, gw * texture * (ndl * color));",
        "if (!specular) {\n        Add3(dm + 3, gw * (ndl * color));",
    ),
    Mutation(
        "adjoint-blocked-light",
        "the adjoint counts a light whose shadow ray was blocked",
        "if (((bits >> l) & 1u) == 0) continue;",
        "if (false) continue;",
    ),
    Mutation(
        "select-draws-by-first-pixel",
        "the selection draws a row's P(ω) draws only where its first pixel's P is strictly between 0 and 1",
        "const int32_t keep = -((p[x] > 0.0f) & (p[x] < 1.0f));",
        "const int32_t keep = -((p[0] > 0.0f) & (p[0] < 1.0f));",
    ),
    Mutation(
        "select-block-edge-unmarked",
        "the selection leaves the block cut by the image's right edge without its top-left",
        "    tl[whole] |= found;",
        "    tl[whole] |= 0;",
    ),
    Mutation(
        "select-block-last-column-skipped",
        "the selection's block top-left ignores the block's last column",
        "for (int64_t k = 0; k < b; ++k) found |= any[xb + k];",
        "for (int64_t k = 0; k + 1 < b; ++k) found |= any[xb + k];",
    ),
    Mutation(
        "fill-blend-kept-partly-sharp",
        "the fill keeps the blurred row where its weights reach only 0.5, not 1",
        "partly_sharp |= (ecc[x] - fovea_deg) / blend_deg >= 1.0f ? 0 : 1;",
        "partly_sharp |= (ecc[x] - fovea_deg) / blend_deg >= 0.5f ? 0 : 1;",
    ),
    Mutation(
        "fill-blend-kept-not-finite",
        "the fill keeps the blurred row without checking that its sharp values are finite",
        "not_finite |= sharp[j] - sharp[j] == 0.0f ? 0 : 1;",
        "not_finite |= 0;",
    ),
    Mutation(
        "slots-sums-not-zeroed",
        "the slots handler leaves the per-pixel sums as the output buffer held them",
        "    std::fill(sums + 3 * p0, sums + 3 * p1, 0.0f);",
        "    std::fill(sums + 3 * p0, sums + 3 * p0, 0.0f);",
    ),
    Mutation(
        "select-order-tail-not-zeroed",
        "the selection leaves the compaction order past the listed samples as the buffer held it",
        "std::fill(order + wanted, order + 2 * per_eye, 0);",
        "std::fill(order + wanted, order + wanted, 0);",
    ),
    Mutation(
        "fill-blank-not-filled",
        "a blank pixel keeps its own (empty) mean, not its block top-left's",
        "source[x] = blank ? at + 3 * tx : own + 3 * x;",
        "source[x] = own + 3 * x;",
    ),
    Mutation(
        "fill-blank-top-left-unchecked",
        "the fill says every blank pixel's block top-left was traced without looking",
        "missing |= blank & (n_eye[top_row_start + tx] == 0);",
        "missing |= 0;",
    ),
    Mutation(
        "fill-blank-periphery-as-outside",
        "a blank periphery pixel is filled from the outside region's block top-left",
        "const int32_t fovea = r <= 0, outside = r >= 2;",
        "const int32_t fovea = r <= 0, outside = r >= 1;",
    ),
    Mutation(
        "slots-rays-one-camera",
        "the slots integrator makes every slot's ray through eye 0's camera",
        "CameraRays(L.cameras + kCameraStride * t.eye[i0],",
        "CameraRays(L.cameras,",
    ),
    Mutation(
        "slots-eye-run-too-long",
        "a block's rays go through the camera of its first slot's eye, past the other eye's first slot",
        "while (i1 < n && t.eye[i1] == t.eye[i0]) ++i1;",
        "while (i1 < n) ++i1;",
    ),
    Mutation(
        "slots-divisor-rounded-down",
        "the slots' pixel and sub-sample from a divisor's multiplier rounded down (one short at multiples)",
        "m = static_cast<uint32_t>(((uint64_t{1} << shift) + divisor - 1) / divisor);",
        "m = static_cast<uint32_t>((uint64_t{1} << shift) / divisor);",
    ),
    Mutation(
        "select-draw-span-short",
        "the selection leaves the last column of a row's span of draws undrawn",
        "last_drawn + 1 - first_drawn, us + first_drawn);",
        "last_drawn - first_drawn, us + first_drawn);",
    ),
    Mutation(
        "select-draw-span-from-zero-counter",
        "the selection draws a row's span from the row's first counter, not the span's",
        "static_cast<uint32_t>((s * H + y) * W + first_drawn),",
        "static_cast<uint32_t>((s * H + y) * W),",
    ),
    Mutation(
        "packet-one-tree-miss-as-face-0",
        "a packet's missed rays (one tree) report face 0 of the scene",
        "prim[k] = hit ? static_cast<int32_t>(rh.hit.prim_id[k]) + first_face : -1;",
        "prim[k] = hit ? static_cast<int32_t>(rh.hit.prim_id[k]) + first_face : 0;",
    ),
    Mutation(
        "packet-one-tree-occlusion-inverted",
        "a packet's shadow rays (one tree) report blocked where Embree found them clear, and the reverse",
        "prim[k] = valid[k] != 0 && rh.ray.tfar[k] == -INFINITY ? 0 : -1;",
        "prim[k] = valid[k] != 0 && rh.ray.tfar[k] == -INFINITY ? -1 : 0;",
    ),
    Mutation(
        "slots-sums-eye-range-short",
        "the slots' sums leave out the samples in the last quarter of each eye's sample indices",
        "own_hi = static_cast<int32_t>(own_lo + per_eye);",
        "own_hi = static_cast<int32_t>(own_lo + per_eye - per_eye / 4);",
    ),
    Mutation(
        "taa-edge-zero",
        "the history blend's neighbourhood is zero beyond a row's last pixel, not that pixel repeated",
        "for (int ch = 0; ch < 3; ++ch) out[ch] = row[ch], row[3 * w + ch] = row[3 * (w - 1) + ch];",
        "for (int ch = 0; ch < 3; ++ch) out[ch] = row[ch], row[3 * w + ch] = 0.0f;",
    ),
    Mutation(
        "taa-middle-row-coarse-stride",
        "the history blend's middle rate reads its block's row at the coarse rate's stride",
        "const int64_t m = at / middle_stride * middle_stride, q = at / coarse_stride * coarse_stride;",
        "const int64_t m = at / coarse_stride * coarse_stride, q = at / coarse_stride * coarse_stride;",
    ),
    Mutation(
        "taa-held-row-stale",
        "the history blend keeps a rate's held row from the band's first row for all its rows",
        "if (m != middle_at) HeldRow(",
        "if (middle_at < 0) HeldRow(",
    ),
    Mutation(
        "taa-band-halo-missing",
        "a band of the history blend's rows blends the rates' row above it as its own first row",
        "const int64_t at = std::clamp<int64_t>(y, 0, h - 1);",
        "const int64_t at = std::clamp<int64_t>(y, y0, h - 1);",
    ),
    Mutation(
        "taa-rates-weights-swapped",
        "the history blend weighs the coarse rate by the middle rate's weight",
        "const float rest = coarse[3 * x + ch] * (1.0f - b[x]) + middle[3 * x + ch] * b[x];",
        "const float rest = coarse[3 * x + ch] * b[x] + middle[3 * x + ch] * (1.0f - b[x]);",
    ),
    Mutation(
        "taa-history-unclipped",
        "the history blend keeps the history unclipped",
        "const float clipped = above < hi ? above : hi;",
        "const float clipped = before[j];",
    ),
    Mutation(
        "taa-variance-unsquared",
        "the history blend's clip box from a variance whose centre tap is not squared",
        "sum = sum + t4[j], squares = squares + t4[j] * t4[j];",
        "sum = sum + t4[j], squares = squares + t4[j];",
    ),
    Mutation(
        "taa-flags-any",
        "the history blend keeps the blend for a group of eight pixels where any one holds a history",
        "if (x1 - x0 == 8 && all == 0x0101010101010101ull) continue;",
        "if (all != 0) continue;",
    ),
    Mutation(
        "layers-unclamped-grid",
        "Guenter's magnified layers read a grid pixel past the last one instead of holding it",
        "const int64_t i1 = std::min<int64_t>(i0 + 1, cells - 1);",
        "const int64_t i1 = std::min<int64_t>(i0 + 1, cells);",
    ),
    Mutation(
        "first-point-any-sample",
        "a pixel's first point is its last traced sub-sample's, not sub-sample 0's",
        "if (first_points && (order_of[i] - own_lo) % spp == 0) {",
        "if (first_points) {",
    ),
    Mutation(
        "first-point-miss-at-origin",
        "a sub-sample 0 that misses keeps its ray's origin, not a point far along it",
        "const float t = b.prim[k] >= 0 ? b.t[k] : block.miss_t;",
        "const float t = b.prim[k] >= 0 ? b.t[k] : 0.0f;",
    ),
    Mutation(
        "prefilter-gain-unclipped",
        "Patney's contrast gain not clipped at max_gain",
        "std::min(std::max(s_image / std::max(s_blurred, flat_std), 1.0f), max_gain);",
        "std::max(s_image / std::max(s_blurred, flat_std), 1.0f);",
    ),
    Mutation(
        "prefilter-edge-not-repeated",
        "Patney's blurs and windows repeat the second pixel beyond the left edge, not the edge pixel",
        "for (int64_t p = 0; p < left; ++p) std::copy(column, column + c, column - (left - p) * c);",
        "for (int64_t p = 0; p < left; ++p) std::copy(column + c, column + 2 * c, column - (left - p) * c);",
    ),
    Mutation(
        "prefilter-coarse-weight-swapped",
        "Patney's blend weighs the coarse rate's filter by the middle rate's weight",
        "rest[3 * j + ch] = v[3 * j + ch] * (1.0f - b[j]);",
        "rest[3 * j + ch] = v[3 * j + ch] * b[j];",
    ),
    Mutation(
        "prefilter-rect-short",
        "the coarse rate's rectangle one column short of where it shows",
        "span[2] = coarse_first, span[3] = coarse_last + 1;",
        "span[2] = coarse_first, span[3] = coarse_last;",
    ),
    Mutation(
        "prefilter-blurred-luminance-of-image",
        "the blurred image's local contrast measured on the image's luminance",
        "const float lb = b[3 * j] * l0 + b[3 * j + 1] * l1 + b[3 * j + 2] * l2;",
        "const float lb = im[3 * j] * l0 + im[3 * j + 1] * l1 + im[3 * j + 2] * l2;",
    ),
    Mutation(
        "prefilter-window-mean-of-image",
        "the blurred image's local mean luminance taken as the image's",
        "const float mean_lb = m0 * l0 + m1 * l1 + m2 * l2;",
        "const float mean_lb = mean_l[j];",
    ),
    Mutation(
        "prefilter-strips-first",
        "every strip of the blurs' column pass reads the first strip's columns (four rows at a time)",
        "for (int u = 0; u < k + 3; ++u) reads[u] = row(y + u - r) + x0;",
        "for (int u = 0; u < k + 3; ++u) reads[u] = row(y + u - r);",
    ),
    Mutation(
        "prefilter-strips-first-one-row",
        "every strip of the blurs' column pass reads the first strip's columns (the rows left over)",
        "for (int u = 0; u < k; ++u) reads[u] = row(y + u - r) + x0;",
        "for (int u = 0; u < k; ++u) reads[u] = row(y + u - r);",
    ),
    Mutation(
        "prefilter-four-rows-head",
        "the column pass's four sums add their first row's term twice",
        "if (q < u) acc[q] = acc[q] + taps[u - q] * s;",
        "if (q <= u) acc[q] = acc[q] + taps[u - q] * s;",
    ),
    Mutation(
        "prefilter-four-rows-tail",
        "the column pass's four sums leave out a last row's term",
        "if (q > u - k) acc[q] = acc[q] + taps[u - q] * s;",
        "if (q > u - k + 1) acc[q] = acc[q] + taps[u - q] * s;",
    ),
    Mutation(
        "prefilter-four-rows-step",
        "the column pass's four sums read their rows one apart too few (each row the next's)",
        "for (int u = 1; u < k; ++u) acc = acc + taps[u] * rows[q + u][j];",
        "for (int u = 1; u < k; ++u) acc = acc + taps[u] * rows[u][j];",
    ),
    Mutation(
        "prefilter-band-halo-short",
        "a band of Patney's pre-filter makes one row fewer of B above it than its windows read",
        "const int64_t r0 = std::max(around.y0, y0 - rw),",
        "const int64_t r0 = std::max(around.y0, y0 - rw + 1),",
    ),
    Mutation(
        "prefilter-band-row-offset",
        "a band of Patney's pre-filter blends the middle rate's rows from its first row, not the rectangle's",
        "MiddleTerm(filtered[0].data() + (y - f0[0]) * m.Cols() * 3,",
        "MiddleTerm(filtered[0].data() + (y - y0) * m.Cols() * 3,",
    ),
    Mutation(
        "layers-nearest",
        "Guenter's magnified layers take the nearest grid pixel before, not bilinear",
        "  return {i0 * stride, i1 * stride, g - floor_g};",
        "  return {i0 * stride, i1 * stride, 0.0f};",
    ),
    Mutation(
        "layers-weights-swapped",
        "Guenter's blend weighs the outer layer by the middle's weight",
        "const float coarse = outer * (1.0f - w_middle[x]) + middle * w_middle[x];",
        "const float coarse = middle * (1.0f - w_middle[x]) + outer * w_middle[x];",
    ),
    Mutation(
        "surface-normal-unflipped",
        "a hit's normals are not turned to face the ray (the adjoint's surface)",
        "const float sign = Dot(ng, d) > 0.0f ? -1.0f : 1.0f;",
        "const float sign = 1.0f;",
    ),
    Mutation(
        "surface-planes-normal-unflipped",
        "a hit's normals are not turned to face the ray (the forward's surfaces, 16 rays at a time)",
        "const float sign = Dot(ng, dk) > 0.0f ? -1.0f : 1.0f;",
        "const float sign = 1.0f;",
    ),
    Mutation(
        "surface-planes-normals-one-vertex",
        "the shading normal interpolates the first vertex's normal thrice",
        "Gather3(normals, j0), Gather3(normals, j1), Gather3(normals, j2)",
        "Gather3(normals, j0), Gather3(normals, j0), Gather3(normals, j0)",
    ),
    Mutation(
        "surface-planes-barycentric",
        "the hit point's first barycentric weight leaves out v",
        "const float b0 = 1.0f - u - v;",
        "const float b0 = 1.0f - u;",
    ),
    Mutation(
        "plain-with-spot-lights",
        "the option-free loop runs for a scene with spot lights (their cone ignored)",
        "} else if (paths == nullptr && !s.spots && s.shading.specular",
        "} else if (paths == nullptr && s.shading.specular",
    ),
    Mutation(
        "plain-with-phong",
        "the option-free loop runs for Phong's specular term (Blinn–Phong's computed instead)",
        "&& s.shading.specular == kSpecularBlinnPhong && !s.shading.payload",
        "&& !s.shading.payload",
    ),
    Mutation(
        "class-unreplayed-light",
        "a light whose shadow ray a class does not trace is left out of the stored path's visible lights",
        "if (!kPlain && paths != nullptr) paths->visible[depth * paths->n + b.column[k]] |= 1u << l;",
        "if (!kPlain && paths != nullptr && (!kClasses || Tested(s, b.cls[k], l)))\n"
        "            paths->visible[depth * paths->n + b.column[k]] |= 1u << l;",
    ),
    Mutation(
        "fill-bad-flags-half-word",
        "the fill's pixel means look at four of each eight bad-pixel flags",
        "std::memcpy(&any, bad + x0, sizeof any);",
        "std::memcpy(&any, bad + x0, 4);",
    ),
    Mutation(
        "fill-top-left-own-row",
        "a blank pixel is filled from its own row's block top-left, not its block's top-left row",
        "const int64_t ty = y - y % f.block[c];",
        "const int64_t ty = y;",
    ),
    Mutation(
        "camera-frame-eyes-swapped",
        "the camera frame traces each eye's rays through the other eye's camera",
        "CameraRays(L.cameras + kCameraStride * B.eye,",
        "CameraRays(L.cameras + kCameraStride * (L.eyes - 1 - B.eye),",
    ),
    Mutation(
        "camera-frame-one-draw-per-pixel",
        "the camera frame draws every sub-sample of a pixel from sub-sample 0's counter",
        "((static_cast<uint32_t>(sample) * H + y) * W + x) * 2",
        "(y * W + x) * 2",
    ),
    Mutation(
        "camera-frame-jitter-axes-swapped",
        "the camera frame jitters x by the y draw",
        "SamplePosition(t.x[k], cell[0], true, t.jitter[2 * k], n_cells);",
        "SamplePosition(t.x[k], cell[0], true, t.jitter[2 * k + 1], n_cells);",
    ),
    Mutation(
        "camera-frame-ragged-edge-traced",
        "the camera frame traces the sub-samples of a ragged tile past the image's right edge",
        "const bool inside = c < inside_cols && y < H;",
        "const bool inside = y < H;",
    ),
    Mutation(
        "camera-frame-sum-not-averaged",
        "the camera frame's pixel is the sum of its samples, not their mean",
        "out[3 * px + k] = pixel_bad ? bad[k] : sum[k] / mean;",
        "out[3 * px + k] = pixel_bad ? bad[k] : sum[k];",
    ),
    Mutation(
        "camera-frame-bad-unpainted",
        "the camera frame's pixel with a bad sample keeps the mean, not the bad colour",
        "out[3 * px + k] = pixel_bad ? bad[k] : sum[k] / mean;",
        "out[3 * px + k] = sum[k] / mean;",
    ),
    Mutation(
        "camera-frame-tile-transposed",
        "the camera frame reads a one-sample pixel from its 4x4 tile transposed",
        "&scratch.total[3 * ((px / 4) * 16 + py * 4 + px % 4)]",
        "&scratch.total[3 * ((px / 4) * 16 + (px % 4) * 4 + py)]",
    ),
)


class CheckError(Exception):
    """A mutation that cannot be checked (its snippet, its build); the message says why."""


def sources(package: Path) -> list[Path]:
    """The C++ sources under `package` (every *.cc and *.h, the rule of `fovjax.native.sources`,
    which the build compiles), sorted."""
    return sorted(p for p in package.rglob("*") if p.suffix in SOURCE_SUFFIXES and p.is_file())


def locate(package: Path, snippet: str) -> Path:
    """The one source under `package` that holds `snippet`, which must occur exactly once in all
    of them; `CheckError` naming the places otherwise."""
    if not snippet:
        raise CheckError("an empty snippet")
    places = []
    for path in sources(package):
        text = path.read_text()
        start = 0
        while (at := text.find(snippet, start)) >= 0:
            places.append((path, text.count("\n", 0, at) + 1))
            start = at + 1
    if len(places) != 1:
        names = [f"{p.relative_to(package.parent)}:{line}" for p, line in places]
        found = "not found" if not places else f"found {len(places)} times ({', '.join(names)})"
        where = f"{len(sources(package))} C++ sources under {package.name}/"
        raise CheckError(f"snippet {snippet!r} {found} in the {where}")
    return places[0][0]


def apply(package: Path, mutation: Mutation) -> tuple[Path, str]:
    """Make `mutation` in the sources under `package`; returns the file and where (file:line)."""
    path = locate(package, mutation.snippet)
    text = path.read_text()
    line = text.count("\n", 0, text.index(mutation.snippet)) + 1
    path.write_text(text.replace(mutation.snippet, mutation.replacement))
    return path, f"{path.relative_to(package.parent)}:{line}"


def _environment(work: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["FOVJAX_NATIVE_DIR"] = str(work / "native")
    env["FOVJAX_CACHE_DIR"] = str(work / "cache")
    env.pop("FOVJAX_TEST_COMPILE_DIR", None)  # each run compiles its own programs (conftest)
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


def _run(command: list[str], work: Path, env: dict[str, str], timeout: float):
    """`command` run in the copy's directory (its package first on sys.path)."""
    try:
        return subprocess.run(
            command, cwd=work / "src", env=env, capture_output=True, text=True, timeout=timeout
        )
    except subprocess.TimeoutExpired as exc:
        raise CheckError(f"{' '.join(command[:4])} ran past {timeout:.0f} s") from exc


def _tail(done: subprocess.CompletedProcess, lines: int) -> str:
    return " | ".join((done.stdout + done.stderr).strip().splitlines()[-lines:])


PROBE = (
    "import json, fovjax, fovjax.native as native\n"
    "s = native.status()\n"
    "print(json.dumps({'package': fovjax.__file__, 'available': bool(s), 'reason': s.reason,"
    " 'library': s.library, 'sources': [str(p) for p in native.sources()]}))\n"
)


def _probe(work: Path, env: dict[str, str], mutated: Path | None) -> None:
    """Build and load the copy's handlers (the test run then finds them built) and check that
    the copy is the package imported from the work directory, that its library was built in
    the work directory, and that the mutated file is one of the sources the build compiles."""
    import json

    done = _run([sys.executable, "-c", PROBE], work, env, 900.0)
    if done.returncode != 0:
        raise CheckError(f"the probe failed: {_tail(done, 1)}")
    status = json.loads(done.stdout.strip().splitlines()[-1])
    if not Path(status["package"]).resolve().is_relative_to((work / "src").resolve()):
        raise CheckError(f"the copy was not the package imported ({status['package']})")
    if not status["available"]:
        raise CheckError(f"the handlers did not build or load: {status['reason']}")
    if not Path(status["library"]).resolve().is_relative_to((work / "native").resolve()):
        raise CheckError(f"the library was not built in the work directory ({status['library']})")
    compiled = {Path(p).resolve() for p in status["sources"]}
    if mutated is not None and mutated.resolve() not in compiled:
        raise CheckError(f"{mutated.name} is not among the sources the build compiles")


class Outcome(NamedTuple):
    failed: bool
    tests: int
    skipped: int
    first_failure: str
    seconds: float


def run_tests(
    work: Path, env: dict[str, str], tests: list[Path], timeout: float, select: str | None
) -> Outcome:
    """The test files (absolute paths in the checkout, so its conftest and pyproject apply) run
    from the copy's directory, the copy first on sys.path; stops at the first failure."""
    report = work / "report.xml"
    command = [
        sys.executable,
        "-m",
        "pytest",
        "-q",
        "-x",
        "-n",
        "0",
        "-p",
        "no:cacheprovider",
        f"--junitxml={report}",
        *(["-k", select] if select else []),
        *map(str, tests),
    ]
    t0 = time.perf_counter()
    done = _run(command, work, env, timeout)
    seconds = time.perf_counter() - t0
    if not report.exists():
        raise CheckError(f"pytest wrote no report (exit {done.returncode}): {_tail(done, 5)}")
    cases = ET.parse(report).getroot().iter("testcase")
    tests_run, skipped, first = 0, 0, ""
    for case in cases:
        tests_run += 1
        if case.find("skipped") is not None:
            skipped += 1
        if not first and (case.find("failure") is not None or case.find("error") is not None):
            first = f"{case.get('classname', '').rsplit('.', 1)[-1]}::{case.get('name')}"
    failed = done.returncode != 0
    if failed and not first:  # e.g. a collection error
        first = f"(exit {done.returncode}) {_tail(done, 1)}"
    return Outcome(failed, tests_run, skipped, first, seconds)


def check(mutation: Mutation | None, tests: list[Path], args: argparse.Namespace) -> tuple[str, Outcome]:
    """Copy the package, make `mutation` (None: none), build, run the tests; (where, outcome)."""
    work = Path(tempfile.mkdtemp(prefix=f"fovjax-mutation-{mutation.name if mutation else 'none'}-"))
    try:
        shutil.copytree(
            ROOT / PACKAGE, work / "src" / PACKAGE, ignore=shutil.ignore_patterns("__pycache__", "*.so")
        )
        mutated, where = apply(work / "src" / PACKAGE, mutation) if mutation else (None, "")
        env = _environment(work)
        _probe(work, env, mutated)
        return where, run_tests(work, env, tests, args.timeout, args.k)
    finally:
        if args.keep:
            print(f"  kept {work}", flush=True)
        else:
            shutil.rmtree(work, ignore_errors=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="mutations to check (default: all; --list names them)")
    parser.add_argument("--list", action="store_true", help="print the table and exit")
    parser.add_argument(
        "--tests",
        nargs="+",
        default=list(DEFAULT_TESTS),
        help=f"test files (default {' '.join(DEFAULT_TESTS)})",
    )
    parser.add_argument("-k", default=None, metavar="EXPR", help="only the tests pytest -k EXPR selects")
    parser.add_argument("--timeout", type=float, default=1800.0, help="seconds per test run (default 1800)")
    parser.add_argument("--keep", action="store_true", help="keep each work directory (its path is printed)")
    args = parser.parse_args(argv)
    by_name = {m.name: m for m in MUTATIONS}
    if args.list:
        for m in MUTATIONS:
            print(f"{m.name}: {m.description}\n    {m.snippet}\n -> {m.replacement}")
        return 0
    unknown = [n for n in args.names if n not in by_name]
    if unknown:
        parser.error(f"unknown mutation {', '.join(unknown)}; expected some of {', '.join(by_name)}")
    tests = [(ROOT / t).resolve() if not Path(t).is_absolute() else Path(t) for t in args.tests]
    missing = [str(t) for t in tests if not t.is_file()]
    if missing:
        parser.error(f"--tests: no such file {', '.join(missing)}")
    if os.environ.get("FOVJAX_NATIVE", "1") == "0":
        parser.error("FOVJAX_NATIVE=0 turns the native integrator off: nothing to check")
    chosen = [by_name[n] for n in args.names] if args.names else list(MUTATIONS)
    # Every snippet is checked against the checkout's sources before any slow work.
    problems = []
    for m in chosen:
        try:
            locate(ROOT / PACKAGE, m.snippet)
        except CheckError as exc:
            problems.append(f"{m.name}: {exc}")
    if problems:
        print("native_mutations: " + "\n".join(problems), file=sys.stderr)
        return 1
    names = ", ".join(str(t.relative_to(ROOT)) if t.is_relative_to(ROOT) else str(t) for t in tests)
    print(f"native_mutations: {len(chosen)} mutation(s) against {names}", flush=True)

    print("unmutated copy ...", flush=True)
    try:
        _, base = check(None, tests, args)
    except CheckError as exc:
        print(f"native_mutations: the unmutated copy cannot be checked: {exc}", file=sys.stderr)
        return 1
    if base.failed or base.skipped or base.tests == 0:
        why = base.first_failure or f"{base.skipped} of {base.tests} tests skipped"
        print(f"native_mutations: the unmutated copy does not pass: {why}", file=sys.stderr)
        return 1
    print(f"  passes: {base.tests} tests in {base.seconds:.0f} s", flush=True)

    rows = []
    for m in chosen:
        print(f"{m.name} ...", flush=True)
        try:
            where, out = check(m, tests, args)
        except CheckError as exc:
            rows.append((m.name, "ERROR", str(exc), ""))
        else:
            result = "caught" if out.failed else "SURVIVED"
            detail = out.first_failure if out.failed else f"{out.tests} tests passed"
            rows.append((m.name, result, f"{where}: {detail}", f"{out.seconds:.0f} s"))
        print(f"  {rows[-1][1]}: {rows[-1][2]}", flush=True)

    width = max(len(r[0]) for r in rows)
    print("\n" + "mutation".ljust(width + 2) + "result    where: first failing test  (seconds)")
    for name, result, detail, seconds in rows:
        print(f"{name.ljust(width + 2)}{result.ljust(10)}{detail}  {seconds}")
    bad = [r for r in rows if r[1] != "caught"]
    if bad:
        print(f"native_mutations: {len(bad)} of {len(rows)} not caught", file=sys.stderr)
        return 1
    print(f"native_mutations: all {len(rows)} caught")
    return 0


if __name__ == "__main__":
    sys.exit(main())
