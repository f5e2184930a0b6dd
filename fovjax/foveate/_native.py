"""The foveated frame's native side: sample selection (`foveate/_select.cc`), the slots
integrator (`foveate/_slots.cc`), the reconstruction (`foveate/_fill.cc`), Patney 2016's history
blend and pre-filters (`foveate/_taa.cc`, `foveate/_prefilter.cc`) and Guenter 2012's layers
(`foveate/_layers.cc`), each the primal of its JAX oracle in `_frame.py` / `_fill.py` /
`_methods/` on a CPU. Not differentiable: the callers' custom
JVPs take derivatives from the JAX side (`fovjax.native.internal.on_platforms`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..native.internal import handler, layout

SELECT_TARGET = "fovjax_select_samples"
SLOTS_TARGET = "fovjax_whitted_slots"
FILL_TARGET = "fovjax_fill_and_blur"
TAA_TARGET = "fovjax_taa_blend"
PREFILTER_TARGET = "fovjax_patney_prefilter"
LAYERS_TARGET = "fovjax_layer_blend"


def native_whitted_slots(
    operands: tuple,
    order,
    n_live,
    key_data,
    locality,
    grid,
    cameras,
    *,
    spp: int,
    height: int,
    width: int,
    jitter: bool,
    max_depth: int,
    recompute: bool,
    packets: bool,
    robust: bool = True,
    shading: dict | None = None,
    store_paths: bool = False,
    region=None,
    classes=None,
    far=None,
):
    """A foveated frame's live slots made into rays, traced through the Whitted integrator and
    summed into their pixels, in one call of the slots handler (CPU only): (sums (2·H·W, 3), bad
    pixel (2·H·W), [primary, shadow, reflection rays, bad samples], and each slot's path with
    `store_paths` (else empty): (max_depth + 1, P) the face hit at each level and the lights
    its shadow rays reached, as `fovjax.render.internal.StoredPaths` holds them, a column per
    slot of `order`). `order` the slots in
    compaction order, the first `n_live` live; `key_data` the frame key's (2,) uint32
    (threefry2x32; unused without `jitter`); `locality` each locality rank's pixel; `grid` the
    sub-samples' cell centres (S, 2); `cameras` (`camera_rows`). `operands`: the scene's
    (`fovjax.render.internal.whitted_operands`) with the ray offset last; `robust`: the BVH's
    `watertight`; `shading`: the shading options' attributes
    (`fovjax.render.internal.shading_attributes`; None: `RenderConfig`'s defaults). `classes`:
    None (every slot at full fidelity), or the `fovjax.render.internal.ShadingClasses` whose
    `max_depth`, `shadows` and `level` (a tree of the merged BVH per class, or None) the slots
    are traced with (traced int32 tables; no texture level of detail), a slot's class being its
    pixel's `region` (2, H, W), as `_frame.trace_selection`'s `class_at`. `far` (a traced
    scalar, or None): a sixth output, per pixel (2·H·W, 3) the point its sub-sample 0's primary
    ray hit (a miss: `far` along the ray; 0 where that sub-sample is not live),
    `_frame.first_hit_points`' values (else empty). What `_frame.trace_selection` with the
    native integrator and `sample_adder` compute, in their order."""
    from ..render import DEFAULT_CONFIG
    from ..render.internal import MAX_NATIVE_DEPTH, shading_attributes

    if not 0 <= max_depth <= MAX_NATIVE_DEPTH:
        raise ValueError(
            f"the native integrator counts at most {MAX_NATIVE_DEPTH} reflections, got max_depth {max_depth}"
        )
    f32, i32 = jnp.float32, jnp.int32
    n_pixels = 2 * height * width
    none = jnp.zeros((0,), i32)
    tables = (none, none, none, none)
    if classes is not None:
        if classes.texture_level is not None or classes.texture_cone is not None:
            raise ValueError(
                "the native slots integrator has no texture level of detail (ShadingClasses.texture_level)"
            )
        if region is None:
            raise ValueError("native_whitted_slots: classes need each pixel's region (2, H, W)")
        level = none if classes.level is None else jnp.asarray(classes.level, i32).reshape(-1)
        tables = (
            jnp.asarray(region, i32).reshape(n_pixels),
            jnp.asarray(classes.max_depth, i32).reshape(-1),
            jnp.asarray(classes.shadows, i32).reshape(-1),
            level,
        )
    slots = int(np.shape(order)[0])
    stored = (max_depth + 1) * slots if store_paths else 0
    out = (
        jax.ShapeDtypeStruct((n_pixels, 3), f32),
        jax.ShapeDtypeStruct((n_pixels,), jnp.bool_),
        jax.ShapeDtypeStruct((4,), i32),
        jax.ShapeDtypeStruct((stored,), i32),
        jax.ShapeDtypeStruct((stored,), jnp.uint32),
        jax.ShapeDtypeStruct((0 if far is None else n_pixels, 3), f32),
    )
    call = handler(SLOTS_TARGET, out, what="the native slots integrator", vmap_method="sequential")
    sums, bad, counts, prim, visible, points = call(
        jnp.asarray(order, i32).reshape(-1),
        jnp.asarray(n_live, i32).reshape(1),
        jnp.asarray(key_data, jnp.uint32).reshape(2),
        jnp.asarray(locality, i32).reshape(-1),
        jnp.asarray(grid, f32).reshape(spp, 2),
        jax.lax.stop_gradient(jnp.asarray(cameras, f32).reshape(2, layout.CAMERA_STRIDE)),
        *tables,
        jnp.zeros(0, f32) if far is None else jax.lax.stop_gradient(jnp.asarray(far, f32)).reshape(1),
        *operands,
        spp=np.int32(spp),
        height=np.int32(height),
        width=np.int32(width),
        jitter=np.int32(jitter),
        max_depth=np.int32(max_depth),
        recompute=np.int32(recompute),
        packets=np.int32(packets),
        robust=np.int32(robust),
        **(shading_attributes(DEFAULT_CONFIG) if shading is None else shading),
    )
    if store_paths:
        prim, visible = prim.reshape(max_depth + 1, slots), visible.reshape(max_depth + 1, slots)
    return sums, bad, counts, prim, visible, points


def native_select_samples(
    ecc,
    probability,
    thresholds,
    key_data,
    locality,
    per_region_spp,
    subsample_rank,
    *,
    spp: int,
    rule: str,
    blocks: tuple[int, int],
    budget: int,
):
    """The foveated frame's sample selection through the selection handler (CPU only): (regions
    int8 (2, H, W), classes int8 (2, S, H, W), compaction order (2·H·W·S), count per class (3),
    traced mask (2, S, H, W), traced samples per pixel (2, H, W), traced samples per region (3));
    see `_frame.selection_with_mask` for what each operand is. `ecc` (2, H, W): the regions are
    made from it and `thresholds` (the fovea's and the periphery's radii, as
    `_sampling.regions` makes them); `probability`: each eye's P(ω) (H, W), apart (no pass
    that stacks the two).
    `rule`: `Foveation.rule`, or "pixel-mask" (`_methods._sparse.pixel_selection`: every
    sub-sample of the pixels whose P is 1)."""
    _, h, w = ecc.shape
    out = (
        jax.ShapeDtypeStruct((2, h, w), jnp.int8),
        jax.ShapeDtypeStruct((2, spp, h, w), jnp.int8),
        jax.ShapeDtypeStruct((2 * spp * h * w,), jnp.int32),
        jax.ShapeDtypeStruct((3,), jnp.int32),
        jax.ShapeDtypeStruct((2, spp, h, w), jnp.bool_),
        jax.ShapeDtypeStruct((2, h, w), jnp.int32),
        jax.ShapeDtypeStruct((3,), jnp.int32),
    )
    call = handler(SELECT_TARGET, out, what="the native sample selection", vmap_method="sequential")
    f32 = jnp.float32
    left, right = probability
    return call(
        jax.lax.stop_gradient(jnp.asarray(ecc, f32)),
        jax.lax.stop_gradient(jnp.asarray(left, f32)),
        jax.lax.stop_gradient(jnp.asarray(right, f32)),
        jax.lax.stop_gradient(jnp.stack([jnp.asarray(t, f32).reshape(()) for t in thresholds])),
        jnp.asarray(key_data, jnp.uint32).reshape(2, 2),
        jnp.asarray(locality, jnp.int32),
        jnp.asarray(per_region_spp, jnp.int32),
        jnp.asarray(subsample_rank, jnp.int32),
        spp=np.int32(spp),
        rule=np.int32(layout.RULES[rule]),
        block_periphery=np.int32(blocks[0]),
        block_outside=np.int32(blocks[1]),
        budget=np.int64(budget),
    )


def native_fill_and_blur(
    sums, n, bad_pixel, region, ecc, bad_color, taps, fovea_deg, *, blocks, blend_deg, blur_fovea
):
    """The foveated frame's reconstruction through the fill handler (CPU only): each pixel's
    mean of its traced samples (`sums` (2·H·W, 3) over `n` (2, H, W); `bad_pixel` (2·H·W) in
    `bad_color`), every blank pixel filled from its block's top-left, the 5×5 Gaussian (`taps`)
    blended in beyond `fovea_deg` over `blend_deg` (or everywhere with `blur_fovea`), both eyes
    side by side: (image (H, 2W, 3), whether every blank pixel's block top-left was traced;
    where not, the image is not the JAX path's and the caller runs that). The arithmetic of
    `_frame.pixel_means`, `_fill.fill_blanks` and `blur_and_blend` in their order: equal to
    float rounding."""
    _, h, w = region.shape
    out = (jax.ShapeDtypeStruct((h, 2 * w, 3), jnp.float32), jax.ShapeDtypeStruct((1,), jnp.bool_))
    call = handler(FILL_TARGET, out, what="the native fill and blur", vmap_method="sequential")
    f32 = jnp.float32
    image, complete = call(
        jax.lax.stop_gradient(jnp.asarray(sums, f32).reshape(2 * h * w, 3)),
        jnp.asarray(n, jnp.int32),
        jnp.asarray(bad_pixel, bool).reshape(2 * h * w),
        jnp.asarray(region, jnp.int8),
        jax.lax.stop_gradient(jnp.asarray(ecc, f32)),
        jnp.broadcast_to(jnp.asarray(bad_color, f32), (3,)),
        jnp.asarray(taps, f32),
        jax.lax.stop_gradient(jnp.asarray(fovea_deg, f32).reshape(1)),
        block_periphery=np.int32(blocks[0]),
        block_outside=np.int32(blocks[1]),
        blend_deg=np.float32(blend_deg),
        blur_fovea=np.int32(blur_fovea),
    )
    return image, complete[0]


def native_taa_blend(pixels, w_inner, w_middle, color, valid, *, strides, alpha: float, gamma: float):
    """Patney 2016's shading rates blended and its history blend through the TAA handler (CPU
    only): the traced `pixels` and the history's `color` (N, H, W, 3), the inner and middle
    rates' weights and `valid` (N, H, W), the middle and coarse rates' `strides`; what
    `_methods._patney.rates_and_history` computes, its neighbourhood's taps added in its order."""
    f32 = jnp.float32
    out = jax.ShapeDtypeStruct(np.shape(pixels), f32)
    call = handler(TAA_TARGET, out, what="the native history blend", vmap_method="sequential")
    return call(
        jax.lax.stop_gradient(jnp.asarray(pixels, f32)),
        jax.lax.stop_gradient(jnp.asarray(w_inner, f32)),
        jax.lax.stop_gradient(jnp.asarray(w_middle, f32)),
        jax.lax.stop_gradient(jnp.asarray(color, f32)),
        jnp.asarray(valid, bool),
        alpha=np.float32(alpha),
        keep=np.float32(1.0 - alpha),
        gamma=np.float32(gamma),
        middle_stride=np.int64(strides[0]),
        coarse_stride=np.int64(strides[1]),
    )


def native_patney_prefilter(image, w_inner, w_middle, taps, *, luminance, max_gain: float, flat_std: float):
    """Patney 2016's pre-filters and the blend of its shading rates through the pre-filter
    handler (CPU only): the image (2, H, W, 3), the inner and middle rates' weights (2, H, W),
    `taps` the (blur, window) taps of the middle rate's filter and of the coarse rate's, both
    eyes side by side (H, 2W, 3): what `_methods._patney.prefilter_and_blend` computes, each
    filter only where its weight is not 0."""
    _, h, w, _ = np.shape(image)
    f32 = jnp.float32
    out = jax.ShapeDtypeStruct((h, 2 * w, 3), f32)
    call = handler(PREFILTER_TARGET, out, what="the native pre-filters", vmap_method="sequential")
    (middle_blur, middle_window), (coarse_blur, coarse_window) = taps
    return call(
        jax.lax.stop_gradient(jnp.asarray(image, f32)),
        jax.lax.stop_gradient(jnp.asarray(w_inner, f32)),
        jax.lax.stop_gradient(jnp.asarray(w_middle, f32)),
        *(np.asarray(t, np.float32) for t in (middle_blur, middle_window, coarse_blur, coarse_window)),
        np.asarray(luminance, np.float32),
        max_gain=np.float32(max_gain),
        flat_std=np.float32(flat_std),
    )


def native_layer_blend(pix, ecc, radii, *, strides: tuple[int, int], blend_deg: float):
    """Guenter 2012's layers through the layers handler (CPU only): each pixel's mean `pix`
    (2, H, W, 3), the eccentricities `ecc` (2, H, W), the inner and middle layers' `radii`
    (2,); the middle and outer layers magnified from their grids of `strides`, blended over
    `blend_deg`, both eyes side by side (H, 2W, 3): what `_methods._guenter.composite`
    computes, in its order."""
    _, h, w, _ = np.shape(pix)
    f32 = jnp.float32
    out = jax.ShapeDtypeStruct((h, 2 * w, 3), f32)
    call = handler(LAYERS_TARGET, out, what="the native layer blend", vmap_method="sequential")
    return call(
        jax.lax.stop_gradient(jnp.asarray(pix, f32)),
        jax.lax.stop_gradient(jnp.asarray(ecc, f32)),
        jax.lax.stop_gradient(jnp.asarray(radii, f32).reshape(2)),
        middle_stride=np.int32(strides[0]),
        outer_stride=np.int32(strides[1]),
        blend_deg=np.float32(blend_deg),
    )
