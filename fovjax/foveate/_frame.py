"""The foveated stereo frame: select samples, compact them, trace only those, fill and blur.

Data flow inside one jitted program (static shapes throughout):

1. each eye's eccentricity map from its gaze point, regions, and the sample classes
   (mandatory / probabilistic / skipped) drawn from a stream of the frame key;
2. compaction in locality order: the samples are listed pixel by pixel along a Z-order
   (Morton) curve over each eye's image, a pixel's sub-samples together, and a stable O(N)
   partition puts the traced samples first (mandatory, then probabilistic). The first
   `budget` slots (a static number: every sample unless the configuration caps it) are the
   frame's rays. Along the Z curve consecutive fovea samples fill 8×8 tiles and consecutive
   block top-lefts of the periphery fill 16×16 tiles at stride 2, so a chunk of slots is a
   spatially coherent batch that packet traversal pays off on;
3. `radiance_in_chunks` makes the rays of a chunk of slots from their indices (the full
   render's sub-pixel positions: the same key gives the same rays) and traces and shades them
   with all their shadow and reflection rays; chunks past the traced samples are skipped by a
   `lax.cond`, so the cost follows the samples traced, never the budget or the screen;
4. the samples are accumulated into their pixels chunk by chunk (again only chunks that hold
   samples), and each eye is filled and blurred (`fill_and_blur_pixels`; the pull-push fill
   runs only when a block has no traced sample).

Optionally (`Foveation.fovea_tile_deg`, `grid_tile`; off by default, see there) the fovea
around the gaze and every `blocks[1]`-th pixel are traced first as image tiles in packets
(`tile_rays`, `grid_rays`), left out of the slots, and summed into their pixels before the
slots' samples (`tile_sums`, `grid_sums`).

The fovea and periphery thresholds are traced values: a new pair (within the configuration's
`max_periphery_deg`) reuses the compiled program. Ray counts are rays actually traced; the
padding (budget slots left empty) and any samples dropped beyond the budget are reported
separately.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Collection
from typing import NamedTuple, TypeAlias, cast

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..native.internal import jvp_of, on_platforms
from ..render import RenderConfig
from ._config import max_region_spp, region_spp, shading_classes
from ._eccentricity import eccentricity_map
from ._fill import FOVEA_BLEND_DEG, blur_and_blend, fill_blanks, gaussian_taps
from ._lod import lod_needed, with_levels
from ._native import native_fill_and_blur, native_select_samples, native_whitted_slots
from ._positions import key_words, per_sample_threefry, positions_at
from ._sampling import (
    MANDATORY,
    OPTIONAL,
    SKIPPED,
    compaction_order,
    sample_classes,
    subsample_rank,
)

# fold_in constant that separates the sampling draws from the sub-pixel jitter of the same key.
SAMPLING_STREAM = 0x5A3


# The per-pixel outputs a frame program can return besides its image (`foveated_stereo`'s
# static `diagnostics`): the traced-sample mask, the regions (int8), the eccentricity and the
# per-pixel mean of the traced samples before fill and blur. Each is a screen-sized array that
# a CPU allocates fresh (and the kernel faults in and zeroes) on every frame, so the frame path
# asks only for those it reads.
DIAGNOSTICS = ("traced", "region", "eccentricity", "prefill")
# What `region_view` (the debug view) reads.
DEBUG_VIEW_DIAGNOSTICS = ("traced", "region", "prefill")
# Which of them to return: names of `DIAGNOSTICS` (any order), or one name.
DiagnosticsLike: TypeAlias = str | Collection[str]


def diagnostics_tuple(diagnostics: DiagnosticsLike, where: str = "render_foveated") -> tuple[str, ...]:
    """`diagnostics` (names of `DIAGNOSTICS`, any order, or one name) as the canonical static
    tuple (`DIAGNOSTICS`' order: the same set is the same compiled program)."""
    if isinstance(diagnostics, str):
        names = (diagnostics,)
    elif isinstance(diagnostics, tuple | list | set | frozenset):
        names = tuple(diagnostics)
    else:
        raise ValueError(
            f"{where}: diagnostics must be names from {DIAGNOSTICS} (a tuple), got {diagnostics!r}"
        )
    unknown = [n for n in names if n not in DIAGNOSTICS]
    if unknown:
        raise ValueError(f"{where}: unknown diagnostics {unknown}; expected names from {DIAGNOSTICS}")
    return tuple(n for n in DIAGNOSTICS if n in names)


@dataclasses.dataclass(frozen=True)
class FrameOptions:
    """The frame program's static options (hashable: one compiled program per distinct value;
    everything else a frame takes is traced). `FoveatedRenderer` makes them.

    - `spp`: samples per pixel (`Foveation.spp`);
    - `jitter`: whether the sub-pixel positions are jittered from the frame key (a key was
      given) or are the pixel cells' centres;
    - `config`: the `fovjax.render.RenderConfig`;
    - `budget`: the static number of ray slots of both eyes (the thesis's method; None for the
      other methods' programs, whose slots are every sub-sample of the pixels they trace);
    - `tile` (rows, cols): the fovea tile, `grid` (a stride): the pixel grid, traced as images
      in packets (None: not; only where the budget is every sample, so that their samples are
      never dropped; see `Foveation.fovea_tile_deg`);
    - `diagnostics`: which per-pixel outputs besides the image to return (`DIAGNOSTICS`, in
      that order; the others are None: a CPU allocates each output fresh every frame).
    """

    spp: int
    jitter: bool
    config: RenderConfig
    budget: int | None = None
    tile: tuple[int, int] | None = None
    grid: int | None = None
    diagnostics: tuple[str, ...] = DIAGNOSTICS


class FoveatedOutputs(NamedTuple):
    """A frame program's outputs; the per-pixel `traced` (2, S, H, W), `region` (2, H, W int8:
    0 fovea, 1 periphery, 2 outside), `eccentricity` (2, H, W degrees) and `prefill` (2, H, W,
    3: each pixel's mean of its traced samples, before fill and blur) are None unless asked
    for (`diagnostics`)."""

    image: Float[Array, "H W2 3"]
    counts: object  # fovjax.render RayCounts
    primary_by_region: Int[Array, " 3"]
    mandatory: Int[Array, ""]
    optional: Int[Array, ""]
    dropped: Int[Array, ""]
    padding: Int[Array, ""]
    traced: Bool[Array, "2 S H W"] | None
    region: Int[Array, "2 H W"] | None
    eccentricity: Float[Array, "2 H W"] | None
    prefill: Float[Array, "2 H W 3"] | None
    bad_pixels: Int[Array, ""]


@functools.lru_cache(maxsize=16)
def locality_order(h: int, w: int) -> np.ndarray:
    """The pixels of an h × w image (flat indices) along a Z-order (Morton) curve."""
    y, x = np.divmod(np.arange(h * w, dtype=np.int64), w)
    code = np.zeros(h * w, np.int64)
    for bit in range(int(max(h, w) - 1).bit_length()):
        code |= ((x >> bit) & 1) << (2 * bit) | ((y >> bit) & 1) << (2 * bit + 1)
    return np.argsort(code, kind="stable").astype(np.int32)


class Selection(NamedTuple):
    """Which samples of a stereo frame are traced: per-eye eccentricity and regions, the class
    of every sample (2, S, H, W), the count per class, the compacted slot list (flat indices
    into the locality-ordered samples (2, H·W, S), padded) and the number of slots traced."""

    eccentricity: Float[Array, "2 H W"]
    region: Int[Array, "2 H W"]
    classes: Int[Array, "2 S H W"]
    counts: Int[Array, " 3"]
    order: Int[Array, " N"]
    rank: Int[Array, " N"] | None  # None: not kept (the traced mask is made with the selection)
    n_traced: Int[Array, ""]
    covered: Bool[Array, "2 H W"] | None = None  # pixels the fovea tile traces (not in the slots)


def eccentricities(cameras, gaze, foveation) -> Float[Array, "2 H W"]:
    """Stage 1: each eye's eccentricity map from its gaze point."""
    ecc = jnp.stack([eccentricity_map(cam, gaze[i], foveation) for i, cam in enumerate(cameras)])
    # Computed once: without the barrier XLA copies the (cheap-looking) arithmetic into each of
    # its many consumers (the images are the same either way).
    return jax.lax.optimization_barrier(ecc)


def tile_origins(gaze, tile: tuple[int, int], h: int, w: int) -> Int[Array, "2 2"]:
    """Per eye, the (row, col) of the top-left pixel of the fovea tile (`tile` = (rows, cols),
    static): centred on the gaze point, moved inside the image."""
    th, tw = tile
    centre = jnp.round(jnp.asarray(gaze, jnp.float32) * jnp.array([w, h], jnp.float32)).astype(jnp.int32)
    row = jnp.clip(centre[:, 1] - th // 2, 0, h - th)
    col = jnp.clip(centre[:, 0] - tw // 2, 0, w - tw)
    return jnp.stack([row, col], axis=1)


def tile_mask(origins, tile: tuple[int, int], h: int, w: int) -> Bool[Array, "2 H W"]:
    """The pixels of each eye's fovea tile."""
    th, tw = tile
    y = jnp.arange(h, dtype=jnp.int32)[None, :, None]
    x = jnp.arange(w, dtype=jnp.int32)[None, None, :]
    row, col = origins[:, 0, None, None], origins[:, 1, None, None]
    return (y >= row) & (y < row + th) & (x >= col) & (x < col + tw)


def sampling_keys(key):
    """Each eye's key of the sampling draws: a stream of the frame key apart from the sub-pixel
    jitter's (the JAX selection's and the native one's, which must draw the same bits)."""
    return jax.random.split(jax.random.fold_in(key, SAMPLING_STREAM), 2)


def select_samples(ecc, key, *, foveation, budget, covered=None) -> Selection:
    """Stage 2: regions, sample classes from the sampling stream of `key`, and their compaction
    in locality order (see the module docstring). `covered` (2, H, W): pixels traced as an
    image tile, left out of the slots (counted in `counts` all the same)."""
    keys = sampling_keys(key)
    per_eye = [sample_classes(ecc[i], foveation, keys[i]) for i in range(2)]
    classes = jnp.stack([c for c, _ in per_eye])  # (2, S, H, W)
    region = jnp.stack([r for _, r in per_eye])  # (2, H, W)
    _, spp, h, w = classes.shape
    perm = jnp.asarray(locality_order(h, w))
    listed = classes if covered is None else jnp.where(covered[:, None], SKIPPED, classes)
    local = listed.reshape(2, spp, h * w)[:, :, perm].transpose(0, 2, 1).reshape(-1)
    order, counts, rank = cast(tuple[Array, Array, Array], compaction_order(local, with_rank=True))
    n_slots = jnp.minimum(counts[MANDATORY] + counts[OPTIONAL], budget)
    if covered is not None:  # the tile's samples: counted, not listed
        in_tile = covered[:, None]
        counts = counts + jnp.stack(
            [jnp.sum(in_tile & (classes == c), dtype=counts.dtype) for c in (MANDATORY, OPTIONAL)]
            + [jnp.zeros((), counts.dtype)]
        )
    return Selection(ecc, region, classes, counts, order, rank, n_slots, covered)


def selection_with_mask(ecc, key, *, foveation, budget, native: bool):
    """Stages 2 and 4's masks together, for a frame without image tiles: (`Selection` with its
    regions and classes as int8 and no ranks, which samples are traced (2, S, H, W), traced samples per pixel
    (2, H, W), traced samples per region (3): fovea, periphery, outside). `native`: on a CPU
    through the native handler (`foveate/_select.cc`, `SelectSamples`: the same
    integers as `select_samples`, `traced_mask`, `traced_count` and `samples_by_region`, on both
    cores), chosen inside the program, so it still lowers for other platforms, where the JAX
    functions run."""

    def in_jax():
        sel = select_samples(ecc, key, foveation=foveation, budget=budget)
        mask = traced_mask(sel, budget)
        n = traced_count(mask, foveation.spp)
        by_region = samples_by_region(sel.region, n)
        return (
            sel.region.astype(jnp.int8),
            sel.classes.astype(jnp.int8),
            sel.order,
            sel.counts,
            mask,
            n,
            by_region,
        )

    _, h, w = ecc.shape
    # The handler recomputes the JAX path's per-sample draws (`uniform_draws`), which need the
    # default PRNG and int32 indices; elsewhere the JAX selection runs.
    per_sample = per_sample_threefry(sampling_keys(key)[0])
    if not native or not per_sample or 2 * foveation.spp * h * w >= 2**31:
        region, classes, order, counts, mask, n, by_region = in_jax()
    else:

        def on_cpu():
            return _native_selection(ecc, key, foveation=foveation, budget=budget)

        outs = on_platforms(in_jax, cpu=on_cpu, derivatives=False)()
        region, classes, order, counts, mask, n, by_region = outs
    n_slots = jnp.minimum(counts[MANDATORY] + counts[OPTIONAL], budget)
    return Selection(ecc, region, classes, counts, order, None, n_slots), mask, n, by_region


def samples_by_region(region, n) -> Int[Array, " 3"]:
    """Traced samples per region (fovea, periphery, outside) from each pixel's region and count:
    one scatter-add instead of three masked reductions (slow on XLA:CPU)."""
    return jnp.zeros(3, jnp.int32).at[region.reshape(-1)].add(n.reshape(-1))


def _native_selection(ecc, key, *, foveation, budget):
    """`selection_with_mask`'s outputs through the native handler (CPU only)."""
    _, h, w = ecc.shape
    spp = foveation.spp
    keys = sampling_keys(key)
    key_data = key_words(keys)
    return native_select_samples(
        ecc,
        (foveation.probability(ecc[0]), foveation.probability(ecc[1])),
        (foveation.fovea_deg, foveation.periphery_deg),
        key_data,
        locality_order(h, w),
        region_spp(foveation) or (spp, spp, spp),
        subsample_rank(spp),
        spp=spp,
        rule=foveation.rule,
        blocks=(int(foveation.blocks[0]), int(foveation.blocks[1])),
        budget=budget,
    )


def _slot_samples(slots, *, spp, h, w):
    """(eye, sample, pixel) of locality-ordered slot indices."""
    per_eye = spp * h * w
    eye = slots // per_eye
    within = slots % per_eye
    pixel = jnp.asarray(locality_order(h, w))[within // spp]
    return eye, within % spp, pixel


def slot_rays(cameras, positions, slots, *, spp, h, w):
    """Primary rays of the slots: the full render's sub-pixel `positions` (spp, H, W, 2), or a
    function of (sample, pixel) that gives them (`positions_at`), directions computed from the
    indices (no screen-sized ray arrays)."""
    eye, sample, pixel = _slot_samples(slots, spp=spp, h=h, w=w)
    if callable(positions):
        xy = positions(sample, pixel)
    else:
        xy = positions.reshape(spp, h * w, 2)[sample, pixel]
    left, right = cameras
    is_left = (eye == 0)[:, None]
    directions = jnp.where(is_left, left.ray_directions(xy), right.ray_directions(xy))
    origins = jnp.where(is_left, left.position, right.position)
    return origins, directions


def tile_rays(cameras, positions, sel: Selection, origins, tile: tuple[int, int]):
    """The fovea tile of each eye as image-shaped rays (2·S, rows, cols): the full render's
    sub-pixel positions, active where the sample is traced."""
    from ..render.internal import ImageTile

    spp = positions.shape[0]
    th, tw = tile
    o, d, active, shading = [], [], [], []
    for i, cam in enumerate(cameras):
        row, col = origins[i, 0], origins[i, 1]
        xy = jax.lax.dynamic_slice(positions, (0, row, col, 0), (spp, th, tw, 2))
        cls = jax.lax.dynamic_slice(sel.classes[i], (0, row, col), (spp, th, tw))
        di = cam.ray_directions(xy)
        d.append(di)
        o.append(jnp.broadcast_to(cam.position, di.shape))
        active.append(cls != SKIPPED)
        region = jax.lax.dynamic_slice(sel.region[i], (row, col), (th, tw))
        shading.append(jnp.broadcast_to(region, (spp, th, tw)))
    return ImageTile(
        jnp.concatenate(o), jnp.concatenate(d), jnp.concatenate(active), jnp.concatenate(shading)
    )


def grid_layout(spp: int):
    """(n, to_image, from_image) for a stride grid's samples: each grid pixel's n × n
    sub-samples laid out as an n × n block of an image (so an 8×8 packet holds 4×4 grid pixels
    at SPP 4: neighbouring rays)."""
    n = int(round(spp**0.5))

    def to_image(x):  # (2, S, Hg, Wg, ...) -> (2, Hg·n, Wg·n, ...)
        e, _, hg, wg = x.shape[:4]
        rest = x.shape[4:]
        x = x.reshape((e, n, n, hg, wg) + rest)  # sample s: cell (s % n, s // n) = (x, y)
        x = jnp.moveaxis(x, (1, 2), (2, 4))  # (e, hg, n_y, wg, n_x, ...)
        return x.reshape((e, hg * n, wg * n) + rest)

    def from_image(x, hg, wg):  # inverse
        e = x.shape[0]
        rest = x.shape[3:]
        x = x.reshape((e, hg, n, wg, n) + rest)
        x = jnp.moveaxis(x, (2, 4), (1, 2))
        return x.reshape((e, n * n, hg, wg) + rest)

    return n, to_image, from_image


def grid_rays(cameras, positions, sel: Selection, stride: int):
    """Every `stride`-th pixel of each eye (rows and columns) as image-shaped rays (its
    sub-samples side by side, `grid_layout`), active where the sample is traced."""
    from ..render.internal import ImageTile

    spp = positions.shape[0]
    _, to_image, _ = grid_layout(spp)
    xy = positions[:, ::stride, ::stride]
    d = jnp.stack([cam.ray_directions(xy) for cam in cameras])  # (2, S, Hg, Wg, 3)
    o = jnp.stack([jnp.broadcast_to(cam.position, d.shape[1:]) for cam in cameras])
    active = sel.classes[:, :, ::stride, ::stride] != SKIPPED
    region = jnp.broadcast_to(sel.region[:, None, ::stride, ::stride], active.shape)
    return ImageTile(to_image(o), to_image(d), to_image(active), to_image(region))


def grid_sums(radiance, tile, *, spp, h, w, stride):
    """The grid's samples summed into their pixels: (sums (2, H, W, 3), bad pixel (2, H, W),
    bad samples)."""
    _, _, from_image = grid_layout(spp)
    hg, wg = -(-h // stride), -(-w // stride)
    rgb = from_image(radiance, hg, wg)
    active = from_image(tile.active, hg, wg)
    bad = active & ~jnp.all(jnp.isfinite(rgb), axis=-1)
    rgb = jnp.where((active & ~bad)[..., None], rgb, 0.0)
    pix, bad_pix = rgb[:, 0], bad[:, 0]
    for s in range(1, spp):
        pix, bad_pix = pix + rgb[:, s], bad_pix | bad[:, s]
    sums = jnp.zeros((2, h, w, 3), jnp.float32).at[:, ::stride, ::stride].set(pix)
    bad_pixel = jnp.zeros((2, h, w), bool).at[:, ::stride, ::stride].set(bad_pix)
    return sums, bad_pixel, jnp.sum(bad, dtype=jnp.int32)


def trace_selection(
    scene,
    bvh,
    cameras,
    positions,
    sel: Selection,
    *,
    config,
    budget: int,
    tiles=(),
    classes=None,
    scale=None,
    consume=None,
):
    """Stage 3: trace and shade the selected samples (`radiance_in_chunks`), `tiles` (image
    tiles of rays) first; `classes`: the renderer's `ShadingClasses` per region (a sample's
    class is its region), None for full fidelity. Returns the per-slot radiance (padded to
    whole chunks), the tiles' and the ray counts. `scale`: as `radiance_in_chunks`'s (levels of
    detail: the finest level's). `consume`: as `radiance_in_chunks`'s (each chunk's radiance
    handed to a function, e.g. `sample_adder`'s, instead of returned). The samples per pixel and
    the image size are the selection's (`sel.classes` (2, S, H, W))."""
    from ..render.internal import radiance_in_chunks

    _, spp, h, w = sel.classes.shape

    def rays_at(first, size):
        slots = jax.lax.dynamic_slice_in_dim(sel.order, first, size)
        return slot_rays(cameras, positions, slots, spp=spp, h=h, w=w)

    def class_at(first, size):
        slots = jax.lax.dynamic_slice_in_dim(sel.order, first, size)
        eye, _, pixel = _slot_samples(slots, spp=spp, h=h, w=w)
        return sel.region.reshape(2, h * w)[eye, pixel]

    if classes is None:
        tiles = tuple(t._replace(shading_class=None) for t in tiles)
    return radiance_in_chunks(
        scene,
        bvh,
        rays_at,
        sel.n_traced,
        n_slots=budget,
        config=config,
        tiles=tiles,
        classes=classes,
        class_at=None if classes is None else class_at,
        scale=scale,
        consume=consume,
    )


def slots_why_not(config, jitter_key, classes, h: int, w: int, spp: int) -> str:
    """Why `traced_sums` cannot run its slots through the native integrator in one call, or ""
    where it can: the native integrator on (`integrator_plan`), sub-pixel draws the handler
    reproduces (threefry2x32, `positions_at`'s per sample uniform; or no jitter), and shading
    classes it implements: per-region reflection depth, shadow rays and geometry level of detail
    (a tree of the merged BVH per region) run in the handler; a texture level of detail
    (`ShadingClasses.texture_level`: trilinear lookups in the mip pyramids, with the ray cones of
    "auto") is not written there and keeps the chunked JAX path."""
    from ..render.internal import integrator_plan

    plan = integrator_plan(config)
    if not plan.cpu:
        return f"the native integrator is off ({plan.reason})"
    if classes is not None and (classes.texture_level is not None or classes.texture_cone is not None):
        return "a texture level of detail per region (Fidelity.texture_lod) runs in the chunked JAX path only"
    if 2 * spp * h * w >= 2**31:
        return f"2 x {spp} x {h} x {w} samples do not fit the handler's 32-bit slot indices"
    if jitter_key is not None and not per_sample_threefry(jitter_key):
        return "the frame key's sub-pixel draws are not the default threefry2x32 the handler reproduces"
    return ""


def slots_in_one_call(config, jitter_key, classes, h: int, w: int, spp: int) -> bool:
    """Whether `traced_sums` runs its slots through the native integrator in one call
    (`slots_why_not` says why not)."""
    return not slots_why_not(config, jitter_key, classes, h, w, spp)


def slots_in_one_warp_call(config, classes, scale) -> bool:
    """Whether `traced_sums` can run its slots through the Warp integrator on CUDA in one launch
    (`warp_slot_sums`): the Warp integrator on there (`warp_integrator_plan`) at full fidelity (no
    shading classes, no levels of detail)."""
    from ..render.internal import warp_integrator_plan

    return warp_integrator_plan(config).cuda and classes is None and scale is None


def warp_slot_sums(scene, bvh, cameras, jitter_key, sel: Selection, *, config, budget: int):
    """Stages 3 and 4a of `traced_sums` on a GPU: every slot's ray made at once, the live ones
    (the first `sel.n_traced`, a device value: no host round trip) traced and shaded in one
    launch of the Warp integrator, each sample added to its pixel in one scatter. Returns
    ((sums, bad pixel, bad samples), (primary, shadow, reflection rays)), as `traced_sums`'s
    branches."""
    from ..render.internal import chunk_rays, scene_scale, warp_integrate

    _, spp, h, w = sel.classes.shape
    positions = functools.partial(positions_at, jitter_key, spp=spp, h=h, w=w)

    def rays_at(first, size):
        slots = jax.lax.dynamic_slice_in_dim(sel.order, first, size)
        return slot_rays(cameras, positions, slots, spp=spp, h=h, w=w)

    o, d, valid = chunk_rays(rays_at, 0, budget)
    active = jnp.arange(budget, dtype=jnp.int32) < sel.n_traced
    offset = config.ray_offset * scene_scale(scene)
    rgb, n_shadow, n_reflection = warp_integrate(scene, bvh, o, d, active, offset, config)
    add = sample_adder(sel, spp=spp, h=h, w=w, size=budget)
    sums = add(empty_sums(h, w, jnp.minimum(sel.n_traced, 0)), 0, rgb)
    return sums, (jnp.sum(active & valid, dtype=jnp.int32), n_shadow, n_reflection)


def _first_points(points, scene, bvh, o, d, prim, target, far):
    """`points` with each ray's hit o + t·d set at `target` (a miss: t = `far`), t recomputed
    from its face `prim` (`hit_geometry`: differentiable in the vertices and the rays)."""
    from ..trace import hit_geometry

    t, _, _ = hit_geometry(scene.vertices, bvh.faces, prim, o, d)
    t = jnp.where(jnp.isfinite(t), t, far)
    return points.at[target].set(o + t[:, None] * d, mode="drop")


def first_hit_points(
    scene, bvh, cameras, jitter_key, sel: Selection, *, config, budget: int, far
) -> Float[Array, "P 3"]:
    """Per pixel (2·H·W, 3) the point its sub-sample 0's primary ray hits (a miss: the point
    `far` along the ray, a scalar without derivatives; 0 where that sub-sample is not
    among the live slots), chunk by chunk over the live slots (`closest_hit` on
    `config.backend`). What the slots handler gives with `traced_sums`' `first_points` from the
    rays it traces anyway. Forward-mode derivatives (a loop over the live chunks)."""
    from ..render.internal import chunk_loop
    from ..trace import closest_hit

    _, spp, h, w = sel.classes.shape
    size = min(config.chunk_size, budget)
    order = sel.order
    if order.shape[0] % size:  # whole chunks (the padding is never live)
        order = jnp.pad(order, (0, size - order.shape[0] % size))
    positions = functools.partial(positions_at, jitter_key, spp=spp, h=h, w=w)
    lanes = jnp.arange(size, dtype=jnp.int32)
    n_pixels = 2 * h * w

    def body(points, first):
        slots = jax.lax.dynamic_slice_in_dim(order, first, size)
        eye, sample, pixel = _slot_samples(slots, spp=spp, h=h, w=w)
        wanted = (first + lanes < sel.n_traced) & (sample == 0)
        o, d = slot_rays(cameras, positions, slots, spp=spp, h=h, w=w)
        hit = closest_hit(bvh, o, d, 0.0, jnp.where(wanted, jnp.inf, 0.0), backend=config.backend)
        target = jnp.where(wanted, eye * (h * w) + pixel, n_pixels)
        return _first_points(points, scene, bvh, o, d, hit.prim, target, far)

    init = jnp.zeros((n_pixels, 3), jnp.float32)
    return chunk_loop(order.shape[0] // size, size, sel.n_traced, body, init)


def traced_sums(
    scene,
    bvh,
    cameras,
    jitter_key,
    sel: Selection,
    *,
    config,
    budget: int,
    classes=None,
    scale=None,
    first_points: float | None = None,
):
    """Stages 3 and 4a without image tiles: the selected samples traced and summed into their
    pixels; a `ChunkedRadiance` whose `consumed` is (sums (2·H·W, 3), bad pixel (2·H·W), bad
    samples). `classes`, `scale`: as `trace_selection`'s. Chunk by chunk, each chunk's samples go
    to their pixels as it is traced (`sample_adder`: no array of every slot's radiance). Where
    `slots_in_one_call` holds and the program runs on a CPU, one call of the native handler
    (`native_whitted_slots`, with the shading classes' tables where given) makes every live
    slot's ray, traces it and adds it to its pixel: the chunk loop's per-chunk operations are
    not run; on an NVIDIA GPU, where
    `slots_in_one_warp_call` holds, one launch of the Warp integrator does (`warp_slot_sums`).
    Its derivatives on a CPU are those of a replay of the paths it stored
    (`fovjax.render.internal.replay_radiance` over the slots: no ray traced again; the paths hold
    what the classes left out: levels not reflected to, lights whose shadow rays were not traced
    count as unblocked, faces of the class's level), and elsewhere those of the JAX integrator
    over every slot (`dense`), so that forward and reverse mode both go through the frame; with
    classes elsewhere, those of the chunked path (forward mode). `first_points` (None, or the
    distance of a miss's point in scene sizes): `consumed` has a fourth member,
    `first_hit_points`' (on a CPU from the rays the handler traces anyway; derivatives from
    the faces it stored; at full fidelity only)."""
    from ..render.internal import ChunkedRadiance, scene_scale

    if first_points is not None and classes is not None:
        raise ValueError("traced_sums: first_points at full fidelity only (classes is None)")

    _, spp, h, w = sel.classes.shape
    size = min(config.chunk_size, budget)
    n_pixels = 2 * h * w

    def chunked(scene, cameras, order, n_traced):
        s = sel._replace(order=order, n_traced=n_traced)
        # The sums start from zeros made from the slot count (a non-negative int, so its minimum
        # with 0 is 0): a constant zero array would be hoisted to the program's start and held
        # through sampling (30 MiB at 2×1280×1024).
        consume = (empty_sums(h, w, jnp.minimum(n_traced, 0)), sample_adder(s, spp=spp, h=h, w=w, size=size))
        positions = functools.partial(positions_at, jitter_key, spp=spp, h=h, w=w)
        out = trace_selection(
            scene,
            bvh,
            cameras,
            positions,
            s,
            config=config,
            budget=budget,
            classes=classes,
            scale=scale,
            consume=consume,
        )
        return out.consumed, (out.primary, out.shadow, out.reflection)

    def with_first_points(run):
        """`run` with `first_hit_points` after its sums, where `first_points` asks for them."""
        if first_points is None:
            return run

        def run_and_points(scene, cameras, order, n_traced):
            consumed, counts = run(scene, cameras, order, n_traced)
            s = sel._replace(order=order, n_traced=n_traced)
            kw = {"config": config, "budget": budget, "far": far_of(scene)}
            return (*consumed, first_hit_points(scene, bvh, cameras, jitter_key, s, **kw)), counts

        return run_and_points

    def far_of(scene):
        """A miss's point's distance along its ray (`first_points` scene sizes)."""
        return jax.lax.stop_gradient(cast(float, first_points) * scene_scale(scene))

    def slot_points(scene, cameras, order, n_traced, prim):
        """Every live slot of sub-sample 0's hit point at its pixel, from its face `prim`."""
        o, d = slot_rays_of(cameras, order)
        live = jnp.arange(order.shape[0], dtype=jnp.int32) < n_traced
        eye, sample, pixel = _slot_samples(order, spp=spp, h=h, w=w)
        target = jnp.where(live & (sample == 0), eye * (h * w) + pixel, n_pixels)
        points = jnp.zeros((n_pixels, 3), jnp.float32)
        return _first_points(points, scene, bvh, o, d, prim, target, far_of(scene))

    def in_one_call(scene, cameras, order, n_traced):
        return native_slots(scene, cameras, order, n_traced, store_paths=False)

    def slot_offset(scene):
        """The secondary rays' offset (`radiance_in_chunks`'s: from `scale` where given)."""
        return config.ray_offset * (scene_scale(scene) if scale is None else jnp.asarray(scale, jnp.float32))

    def native_slots(scene, cameras, order, n_traced, *, store_paths):
        from ..render.internal import camera_rows, integrator_options, whitted_operands
        from ..scene import stratified_offsets

        with jax.ensure_compile_time_eval():
            grid = np.asarray(stratified_offsets(spp), np.float32)
        key_data = jnp.zeros(2, jnp.uint32) if jitter_key is None else key_words(jitter_key)
        offset = jax.lax.stop_gradient(jnp.asarray(slot_offset(scene), jnp.float32).reshape(1))
        sums, bad_pixel, counts, prim, visible, points = native_whitted_slots(
            (*whitted_operands(scene, bvh), offset),
            order,
            n_traced,
            key_data,
            jnp.asarray(locality_order(h, w)),
            grid,
            camera_rows(cameras),
            spp=spp,
            height=h,
            width=w,
            jitter=jitter_key is not None,
            **integrator_options(config, bvh),
            store_paths=store_paths,
            region=None if classes is None else sel.region,
            classes=classes,
            far=None if first_points is None else far_of(scene),
        )
        consumed = (sums, bad_pixel, counts[3]) + (() if first_points is None else (points,))
        out = consumed, (counts[0], counts[1], counts[2])
        return (out, (prim, visible)) if store_paths else out

    def slot_rays_of(cameras, order):
        """Every slot's camera ray (unit direction), as the handler makes it."""
        positions = functools.partial(positions_at, jitter_key, spp=spp, h=h, w=w)
        o, d = slot_rays(cameras, positions, order, spp=spp, h=h, w=w)
        n2 = jnp.sum(d * d, axis=-1, keepdims=True)
        return o, d * jnp.where(n2 > 0, jax.lax.rsqrt(jnp.where(n2 > 0, n2, 1.0)), 0.0)

    def slot_sums(rgb, bad, order, n_traced):
        """Every live slot's radiance added to its pixel (`sample_adder` over every slot)."""
        live = jnp.arange(order.shape[0], dtype=jnp.int32) < n_traced
        eye, _, pixel = _slot_samples(order, spp=spp, h=h, w=w)
        target = jnp.where(live, eye * (h * w) + pixel, n_pixels)
        bad = live & bad
        rgb = jnp.where((live & ~bad)[:, None], rgb, 0.0)
        sums = jnp.zeros((n_pixels, 3), jnp.float32).at[target].add(rgb, mode="drop")
        bad_pixel = jnp.zeros(n_pixels, bool).at[target].max(bad, mode="drop")
        return sums, bad_pixel, jnp.sum(bad, dtype=jnp.int32)

    def dense(scene, cameras, order, n_traced):
        """The slots through the renderer's `radiance`, every slot at once: what `chunked`
        computes, with fixed shapes (its derivatives go both ways)."""
        from ..render import radiance
        from ..trace import closest_hit

        o, d = slot_rays_of(cameras, order)
        live = jnp.arange(order.shape[0], dtype=jnp.int32) < n_traced
        r = radiance(scene, bvh, o, d, active=live, config=config)
        counts = (r.counts.primary, r.counts.shadow, r.counts.reflection)
        if first_points is None:
            return slot_sums(r.rgb, r.bad, order, n_traced), counts
        first = live & (_slot_samples(order, spp=spp, h=h, w=w)[1] == 0)  # only sub-sample 0's point is kept
        prim = closest_hit(bvh, o, d, 0.0, jnp.where(first, jnp.inf, 0.0), backend=config.backend).prim
        points = slot_points(scene, cameras, order, n_traced, prim)
        return (*slot_sums(r.rgb, r.bad, order, n_traced), points), counts

    def replay_jvp(primals, tangents):
        """The handler's sums, with the derivatives of a replay of the paths it stored."""
        from ..render.internal import (
            SHADING_FIELDS,
            StoredPaths,
            native_shading_adjoint,
            replay_radiance,
            shading_attributes,
            shading_of,
            shading_tangent,
            split_tangents,
            whitted_operands,
        )

        scene, cameras, order, n_traced = primals
        out, paths = native_slots(scene, cameras, order, n_traced, store_paths=True)
        paths = StoredPaths(*paths)
        offset = slot_offset(scene)

        def replayed(scene, cameras, order, n_traced):
            o, d = slot_rays_of(cameras, order)
            rgb = replay_radiance(scene, bvh, o, d, offset, paths, shading_of(config))
            bad = ~jnp.all(jnp.isfinite(rgb), axis=-1)
            return slot_sums(rgb, bad, order, n_traced), out[1]

        def replayed_rgb(scene, cameras, order, n_traced):
            o, d = slot_rays_of(cameras, order)
            return (replay_radiance(scene, bvh, o, d, offset, paths, shading_of(config)),)

        def adjoint(primals, stored, cotangent, moving):  # what it reads comes in `stored` (traced later)
            ops, o, d, offset, prim, visible = stored
            attributes = shading_attributes(config)
            return native_shading_adjoint(
                ops, o, d, offset, prim, visible, cotangent, shading=attributes, moving=moving
            )

        # As the full frame's (`fovjax/render/_integrator.py`): the shading parameters through the
        # native adjoint, the rest through the replay, each only where something moves.
        rest, moving = split_tangents(primals, tangents, SHADING_FIELDS)
        sums = None
        if rest is not None:
            _, ((sums, *_), _) = jvp_of(replayed, primals, rest)
        if moving is not None:
            o, d = slot_rays_of(cameras, order)
            stored = (whitted_operands(scene, bvh), o, d, offset, *paths)
            rgb = shading_tangent(replayed_rgb, adjoint, primals, stored, moving, SHADING_FIELDS)
            # A bad slot's pixel is painted `bad_color` (`pixel_means`): its tangent is not read.
            by_adjoint = slot_sums(rgb, jnp.zeros(rgb.shape[0], bool), order, n_traced)[0]
            sums = by_adjoint if sums is None else sums + by_adjoint
        if sums is None:
            sums = jnp.zeros_like(out[0][0])
        no_counts = tuple(np.zeros(np.shape(c), jax.dtypes.float0) for c in out[1])
        integers = tuple(np.zeros(np.shape(c), jax.dtypes.float0) for c in out[0][1:3])
        if first_points is None:
            return out, ((sums, *integers), no_counts)
        # The points' derivatives: recomputed on the primary faces the handler stored.
        points = functools.partial(slot_points, prim=paths.prim[0])
        _, d_points = jvp_of(points, primals, tangents)
        return out, ((sums, *integers, d_points), no_counts)

    def in_one_warp_call(scene, cameras, order, n_traced):
        s = sel._replace(order=order, n_traced=n_traced)
        return warp_slot_sums(scene, bvh, cameras, jitter_key, s, config=config, budget=budget)

    on_cpu = slots_in_one_call(config, jitter_key, classes, h, w, spp)
    on_gpu = slots_in_one_warp_call(config, classes, scale)
    if not (on_cpu or on_gpu):
        run = with_first_points(chunked)
        (consumed, (primary, shadow, reflection)) = run(scene, cameras, sel.order, sel.n_traced)
    else:
        from ..render.internal import integrator_plan

        cpu_only = on_cpu and integrator_plan(config).cpu_only
        replays = scene.num_lights <= 32  # the paths' visibility bits
        run = on_platforms(
            with_first_points(chunked),
            cpu=in_one_call if on_cpu else None,
            cuda=with_first_points(in_one_warp_call) if on_gpu else None,
            cpu_only=cpu_only,
            cpu_jvp=replay_jvp if on_cpu and replays else None,
            # `dense` is the frame at full fidelity: with classes the chunked path's derivatives.
            differentiate=dense if classes is None else None,
        )
        consumed, (primary, shadow, reflection) = run(scene, cameras, sel.order, sel.n_traced)
    return ChunkedRadiance(None, primary, shadow, reflection, (), consumed)


def _tile_slice(mask, origins, tile, spp):
    """(2·S, rows, cols): a (1, H, W) pixel mask over each eye's fovea tile, per sub-sample."""
    th, tw = tile
    parts = [jax.lax.dynamic_slice(mask[0], (origins[i, 0], origins[i, 1]), (th, tw)) for i in range(2)]
    return jnp.concatenate([jnp.broadcast_to(p, (spp, th, tw)) for p in parts])


def tile_sums(radiance, active, origins, *, spp, h, w, init=None):
    """The fovea tile's samples summed into their pixels, onto `init` (sums (2, H, W, 3), bad
    pixel (2, H, W), bad samples) or zeros: the accumulate's starting point, flat. A sample
    whose radiance is not finite is bad (its pixel painted `bad_color` by `accumulate`)."""
    _, th, tw = active.shape
    rgb = radiance.reshape(2, spp, th, tw, 3)
    active = active.reshape(2, spp, th, tw)
    bad = active & ~jnp.all(jnp.isfinite(rgb), axis=-1)
    rgb = jnp.where((active & ~bad)[..., None], rgb, 0.0)
    pix, bad_pix = rgb[:, 0], bad[:, 0]
    for s in range(1, spp):
        pix, bad_pix = pix + rgb[:, s], bad_pix | bad[:, s]
    if init is None:
        init = (jnp.zeros((2, h, w, 3), jnp.float32), jnp.zeros((2, h, w), bool), jnp.int32(0))
    sums, bad_pixel, n_bad = init
    for i in range(2):
        at = (origins[i, 0], origins[i, 1])
        old = jax.lax.dynamic_slice(sums[i], at + (0,), pix[i].shape)
        sums = sums.at[i].set(jax.lax.dynamic_update_slice(sums[i], old + pix[i], at + (0,)))
        old = jax.lax.dynamic_slice(bad_pixel[i], at, bad_pix[i].shape)
        bad_pixel = bad_pixel.at[i].set(jax.lax.dynamic_update_slice(bad_pixel[i], old | bad_pix[i], at))
    n_bad = n_bad + jnp.sum(bad, dtype=jnp.int32)
    return sums.reshape(-1, 3), bad_pixel.reshape(-1), n_bad


def accumulate(total, sel: Selection, n, *, spp, h, w, size, bad_color, init=None):
    """Stage 4a: add each traced sample's radiance to its pixel, chunk by chunk (only chunks
    that hold samples), onto `init` (sums, bad pixel, bad samples: the tile's) or zeros. A
    sample whose radiance is not finite is bad: its pixel is painted `bad_color` outright, as
    in the full render. Returns (per-pixel mean of the traced samples (2, H, W, 3), bad
    samples, bad pixels (2, H, W))."""
    from ..render.internal import chunk_loop

    add = sample_adder(sel, spp=spp, h=h, w=w, size=size)

    def body(carry, first):
        return add(carry, first, jax.lax.dynamic_slice_in_dim(total, first, size))

    n_chunks = total.shape[0] // size
    if init is None:
        init = empty_sums(h, w)
    sums = chunk_loop(n_chunks, size, sel.n_traced, body, init)
    return pixel_means(sums, n, h=h, w=w, bad_color=bad_color)


def empty_sums(h: int, w: int, zero=None):
    """Stage 4a's starting point: no sample in any pixel (sums (2·H·W, 3), bad pixel (2·H·W),
    bad samples). `zero`: an int32 zero to build them from (a traced one keeps XLA from
    hoisting the constant to the program's start)."""
    zero = jnp.int32(0) if zero is None else zero
    n_pixels = 2 * h * w
    return (jnp.full((n_pixels, 3), zero, jnp.float32), jnp.full(n_pixels, zero, jnp.int32) > 0, zero)


def sample_adder(sel: Selection, *, spp, h, w, size):
    """Stage 4a per chunk: `add(carry, first, rgb)` adds the radiance `rgb` (size, 3) of slots
    first..first+size to their pixels (carry: sums, bad pixel, bad samples; flat)."""
    lanes = jnp.arange(size, dtype=jnp.int32)
    n_pixels = 2 * h * w

    def add(carry, first, rgb):
        sums, bad_pixel, n_bad = carry
        slots = jax.lax.dynamic_slice_in_dim(sel.order, first, size)
        active = first + lanes < sel.n_traced
        eye, _, pixel = _slot_samples(slots, spp=spp, h=h, w=w)
        target = jnp.where(active, eye * (h * w) + pixel, n_pixels)  # inactive: dropped
        bad = active & ~jnp.all(jnp.isfinite(rgb), axis=-1)
        rgb = jnp.where(active[:, None] & ~bad[:, None], rgb, 0.0)
        sums = sums.at[target].add(rgb, mode="drop")
        bad_pixel = bad_pixel.at[target].max(bad, mode="drop")
        return sums, bad_pixel, n_bad + jnp.sum(bad, dtype=jnp.int32)

    return add


def count_true(mask: Bool[Array, "..."]) -> Int[Array, ""]:
    """How many entries of `mask` are true, exactly: sums of 128 entries as uint8 (at most
    128), then their sum as int32, where the size is a multiple of 128. XLA:CPU reduces a
    screen-sized bool array summed as int32 in one pass to a slower windowed reduction."""
    flat = mask.reshape(-1)
    if flat.shape[0] % 128:
        return jnp.sum(flat, dtype=jnp.int32)
    return jnp.sum(jnp.sum(flat.reshape(-1, 128), axis=1, dtype=jnp.uint8), dtype=jnp.int32)


def pixel_means(sums, n, *, h, w, bad_color):
    """Stage 4a's end: (per-pixel mean of the traced samples (2, H, W, 3), bad samples, bad
    pixels (2, H, W)) from the sums."""
    sums, bad_pixel, n_bad = sums[:3]  # (first faces after them, where asked)
    mean = sums.reshape(2, h, w, 3) / jnp.maximum(n, 1)[..., None]
    bad_pixel = bad_pixel.reshape(2, h, w)
    mean = jnp.where(bad_pixel[..., None], jnp.asarray(bad_color, jnp.float32), mean)
    return mean, n_bad, bad_pixel


def traced_mask(sel: Selection, budget: int) -> Bool[Array, "2 S H W"]:
    """Which samples were traced: every sample the plan asked for, unless the budget dropped
    some (then from the compaction's ranks, mapped back from locality order)."""
    if sel.rank is None:
        raise ValueError("traced_mask needs the selection's ranks (select_samples keeps them)")
    rank = sel.rank
    wanted = sel.classes != SKIPPED
    _, spp, h, w = sel.classes.shape

    def with_drops(_):
        kept = (rank < budget).reshape(2, h * w, spp).transpose(0, 2, 1)
        perm = jnp.asarray(locality_order(h, w))
        grid = jnp.zeros((2, spp, h * w), bool).at[:, :, perm].set(kept).reshape(wanted.shape)
        if sel.covered is not None:  # a tile's samples are never dropped
            grid = grid | sel.covered[:, None]
        return wanted & grid

    dropped = sel.counts[MANDATORY] + sel.counts[OPTIONAL] > budget
    return jax.lax.cond(dropped, with_drops, lambda _: wanted, None)


def traced_count(mask, spp) -> Int[Array, "2 H W"]:
    """Traced samples per pixel."""
    n = mask[:, 0].astype(jnp.int32)
    for s in range(1, spp):
        n = n + mask[:, s]
    return n


def fill_and_blur_eyes(prefill, n, sel: Selection, foveation, *, top_lefts_traced: bool = False):
    """Stage 4b: each eye filled and blurred (`fill_and_blur_pixels`; both eyes in the same
    passes, the blur band by band straight into the side-by-side image)."""
    filled, _ = fill_blanks(prefill, n, sel.region, foveation, top_lefts_traced=top_lefts_traced)
    return blur_and_blend(filled, sel.eccentricity, foveation, side_by_side=True)


def fill_and_blur_sums(
    sums, n, sel: Selection, foveation, *, bad_color, top_lefts_traced: bool, native: bool
):
    """Stages 4a's end and 4b from the pixel sums (`empty_sums`' carry, flat): the pixel means,
    filled and blurred side by side, as `pixel_means` then `fill_and_blur_eyes` make them.
    `native`: on a CPU in one call of the native handler (`FillAndBlur`: equal to float
    rounding, one pass per band of rows on both cores instead of XLA's screen-sized passes),
    chosen inside the program; where a blank pixel's block top-left was not traced either (the
    strict rule, or samples dropped beyond the budget) the JAX path runs instead, for its
    pull-push fill. Derivatives are always the JAX path's (a custom JVP)."""
    _, h, w = n.shape
    taps = gaussian_taps(foveation.blur_sigma)
    rest = sums[1:]  # bad pixels, bad samples: not differentiable

    def in_jax(rgb, ecc, fovea_deg):
        fov = eqx.tree_at(lambda f: f.fovea_deg, foveation, fovea_deg)
        prefill, _, _ = pixel_means((rgb, *rest), n, h=h, w=w, bad_color=bad_color)
        return fill_and_blur_eyes(
            prefill, n, sel._replace(eccentricity=ecc), fov, top_lefts_traced=top_lefts_traced
        )

    args = (sums[0], sel.eccentricity, jnp.asarray(foveation.fovea_deg, jnp.float32))
    # (the handler's offsets into an eye's rows are int32: 3·H·W below 2^31)
    if not native or min(h, w) <= len(taps) // 2 or 3 * h * w >= 2**31:
        return in_jax(*args)

    def on_cpu(rgb, ecc, fovea_deg):
        image, complete = native_fill_and_blur(
            rgb,
            n,
            rest[0],
            sel.region,
            ecc,
            bad_color,
            taps,
            fovea_deg,
            blocks=(int(foveation.blocks[0]), int(foveation.blocks[1])),
            blend_deg=FOVEA_BLEND_DEG,
            blur_fovea=bool(foveation.blur_fovea),
        )
        if top_lefts_traced:
            return image
        return jax.lax.cond(complete, lambda: image, lambda: in_jax(rgb, ecc, fovea_deg))

    return on_platforms(in_jax, cpu=on_cpu)(*args)


def foveated_stereo(
    scene,
    bvh,
    rig,
    head_pose,
    gaze,
    key,
    foveation,
    lod=None,
    shading=None,
    *,
    options: FrameOptions,
):
    """One foveated stereo frame (see the module docstring). Pure; jit with `options` (the
    `FrameOptions`) static. `gaze` (2, 2): per-eye normalised display coordinates. `lod`: with
    levels of detail per region
    (`Fidelity.lod`), the `LODTables` of `scene` and `bvh` merged over the levels
    (`render_foveated` prepares them); None otherwise. `shading`: the per-region
    `ShadingClasses` tables of `program_fidelity` (traced values: the reflection depth and
    shadow mode per region are not part of the program); None: computed from `foveation`.

    Only the selected samples ever become rays: their sub-pixel positions are the full
    render's (`pixel_sample_positions` from the same key, computed for those samples only:
    `positions_at`) and their directions are computed from their indices, chunk by chunk, so
    no screen-sized ray arrays exist."""
    from ..render import RayCounts
    from ..render.internal import pixel_spread_angle
    from ..scene import pixel_sample_positions

    if not isinstance(options, FrameOptions):
        raise TypeError(f"foveated_stereo: options must be a FrameOptions, got {type(options).__name__}")
    spp, jitter, config, budget = options.spp, options.jitter, options.config, options.budget
    if budget is None:
        raise ValueError("foveated_stereo: FrameOptions.budget is the frame's static ray slots, got None")
    tile, grid = options.tile, options.grid
    diagnostics = diagnostics_tuple(options.diagnostics, "foveated_stereo")
    if lod is None and lod_needed(foveation) is not None:
        raise ValueError(
            "foveated_stereo: Foveation.fidelity asks for levels of detail (Fidelity.lod); pass the "
            "merged scene, BVH and LODTables (render_foveated prepares them)"
        )
    cameras = rig.eye_cameras(head_pose)
    h, w = rig.eye_height, rig.eye_width
    ecc = eccentricities(cameras, gaze, foveation)
    every = 2 * max_region_spp(foveation) * h * w  # every sample a region may trace
    if (tile is not None or grid is not None) and budget < every:
        raise ValueError(f"image tiles need a budget of every sample ({every}), got {budget}")
    origins = None if tile is None else tile_origins(gaze, tile, h, w)
    covered = None if tile is None else tile_mask(origins, tile, h, w)
    on_grid = None
    if grid is not None:
        yy, xx = np.mgrid[:h, :w]
        on_grid = jnp.asarray((yy % grid == 0) & (xx % grid == 0))[None]
        covered = jnp.broadcast_to(on_grid, (2, h, w)) if covered is None else covered | on_grid
    native = False
    if tile is None and grid is None:
        from ..render.internal import integrator_plan

        native = integrator_plan(config).cpu
        sel, mask, n, by_region = selection_with_mask(
            ecc, key, foveation=foveation, budget=budget, native=native
        )
    else:
        sel = select_samples(ecc, key, foveation=foveation, budget=budget, covered=covered)
        mask = traced_mask(sel, budget)
        n = traced_count(mask, spp)
        by_region = samples_by_region(sel.region, n)
    # The slots' sub-pixel positions, computed for the traced samples only (`positions_at`);
    # the image tiles slice the full render's screen of them.
    frame_key = key if jitter else None
    positions = functools.partial(positions_at, frame_key, spp=spp, h=h, w=w)
    tiles: tuple = ()  # ImageTiles
    if tile is not None or grid is not None:
        screen = pixel_sample_positions(w, h, spp, frame_key)
        if grid is not None:
            tiles += (grid_rays(cameras, screen, sel, grid),)
        if tile is not None:
            ft = tile_rays(cameras, screen, sel, origins, tile)
            if grid is not None:  # the grid's pixels are the grid tile's
                ft = ft._replace(active=ft.active & ~_tile_slice(on_grid, origins, tile, spp))
            tiles += (ft,)
    size = min(config.chunk_size, budget)
    padded = -(-budget // size) * size
    if padded > sel.order.shape[0]:  # whole chunks of slots (the padding is never live)
        sel = sel._replace(order=jnp.pad(sel.order, (0, padded - sel.order.shape[0])))
    classes = shading_classes(foveation, config) if shading is None else shading
    if classes is not None and classes.texture_cone is not None:  # cones in radians
        spread = pixel_spread_angle(rig.vfov_deg(), h)
        classes = classes._replace(texture_cone=jnp.asarray(classes.texture_cone) * spread)
    # --- geometry level of detail ---
    scale = None
    if lod is not None:
        from ..render.internal import scene_scale

        classes = with_levels(classes, foveation, config, lod, bvh, cameras)
        scale = scene_scale(eqx.tree_at(lambda a: a.vertices, scene, scene.vertices[: lod.num_vertices]))
    # --- end geometry level of detail ---
    summed = not tiles  # the samples go to their pixels as they are traced (`traced_sums`)
    if summed:
        traced = traced_sums(
            scene, bvh, cameras, frame_key, sel, config=config, budget=budget, classes=classes, scale=scale
        )
    else:
        traced = trace_selection(
            scene,
            bvh,
            cameras,
            positions,
            sel,
            config=config,
            budget=budget,
            tiles=tiles,
            classes=classes,
            scale=scale,
        )
    # The pixel sums start from zeros made from a count of the trace (a non-negative int, so its
    # minimum with 0 is 0): a constant zero array would be hoisted to the program's start and
    # held through sampling and tracing (30 MiB of the temp block's peak at 2×1280×1024).
    if summed:
        prefill, n_bad, bad_pixel = pixel_means(traced.consumed, n, h=h, w=w, bad_color=config.bad_color)
    else:
        zero = jnp.minimum(traced.primary, 0)
        init = (jnp.full((2, h, w, 3), zero, jnp.float32), jnp.zeros((2, h, w), bool), zero)
        if grid is not None:
            init = grid_sums(traced.tiles[0], tiles[0], spp=spp, h=h, w=w, stride=grid)
        if tile is not None:  # onto the grid's sums or the zeros; flat
            init = tile_sums(traced.tiles[-1], tiles[-1].active, origins, spp=spp, h=h, w=w, init=init)
        else:
            init = (init[0].reshape(-1, 3), init[1].reshape(-1), init[2])
        prefill, n_bad, bad_pixel = accumulate(
            traced.total,
            sel,
            n,
            spp=spp,
            h=h,
            w=w,
            size=min(config.chunk_size, budget),
            bad_color=config.bad_color,
            init=init,
        )
    # Under the rule "either" every block's top-left is mandatory, so with no sample dropped
    # (a budget of every sample) no block is left empty: the pull-push fill is not compiled.
    complete = foveation.rule == "either" and budget >= every
    if summed:
        image = fill_and_blur_sums(
            traced.consumed,
            n,
            sel,
            foveation,
            bad_color=config.bad_color,
            top_lefts_traced=complete,
            native=native,
        )
    else:
        image = fill_and_blur_eyes(prefill, n, sel, foveation, top_lefts_traced=complete)
    counts = sel.counts
    wanted = counts[MANDATORY] + counts[OPTIONAL]
    return FoveatedOutputs(
        image=image,
        counts=RayCounts(traced.primary, traced.shadow, traced.reflection, n_bad),
        primary_by_region=by_region,
        mandatory=counts[MANDATORY],
        optional=counts[OPTIONAL],
        dropped=jnp.maximum(wanted - budget, 0),
        padding=jnp.maximum(budget - wanted, 0),
        traced=mask if "traced" in diagnostics else None,
        region=sel.region.astype(jnp.int8) if "region" in diagnostics else None,  # 0, 1, 2: exact
        eccentricity=ecc if "eccentricity" in diagnostics else None,
        prefill=prefill if "prefill" in diagnostics else None,
        bad_pixels=count_true(bad_pixel),
    )


@dataclasses.dataclass(frozen=True)
class FoveationStats:
    """Per-frame foveation figures: primary rays traced per region (fovea, periphery,
    outside), the samples the plan asked for (mandatory + probabilistic), the static budget,
    the budget slots left empty (padding), samples dropped because the budget was full, and
    pixels shown from earlier frames' samples (`reused`: a temporal method's)."""

    primary_by_region: tuple[int, int, int]
    mandatory: int
    optional: int
    budget: int
    padding: int
    dropped: int
    fovea_deg: float
    periphery_deg: float
    # Pixels shown from earlier frames' samples (a temporal method, `Foveation.method`; else 0).
    reused: int = 0


def region_view(outputs: FoveatedOutputs, *, dim: float = 0.12) -> Float[Array, "H W2 3"]:
    """The debug view of thesis figures 58–59: each eye right after ray generation — pixels with
    a traced sample in their rendered colour, the others in a dim colour of their region
    (periphery yellow, outside red) — and the fovea's edge drawn green. Needs the outputs of
    `DEBUG_VIEW_DIAGNOSTICS`."""
    traced, region, prefill = outputs.traced, outputs.region, outputs.prefill  # DEBUG_VIEW_DIAGNOSTICS
    if traced is None or region is None or prefill is None:
        missing = [n for n in DEBUG_VIEW_DIAGNOSTICS if getattr(outputs, n) is None]
        raise ValueError(
            f"region_view: the frame was rendered without the diagnostics {missing}; render it with "
            f"diagnostics including {DEBUG_VIEW_DIAGNOSTICS}"
        )
    colours = jnp.array([[0.0, 0.0, 0.0], [1.0, 0.8, 0.1], [1.0, 0.15, 0.1]], jnp.float32)
    any_traced = jnp.any(traced, axis=1)[..., None]
    shown = jnp.where(any_traced, prefill, dim * colours[region])
    # One-pixel ring where the region changes from fovea to periphery.
    fovea = region == 0
    edge = fovea & ~(
        jnp.roll(fovea, 1, 1) & jnp.roll(fovea, -1, 1) & jnp.roll(fovea, 1, 2) & jnp.roll(fovea, -1, 2)
    )
    shown = jnp.where(edge[..., None], jnp.array([0.1, 1.0, 0.1]), shown)
    return jnp.concatenate([shown[0], shown[1]], axis=1)
