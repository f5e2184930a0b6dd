"""What the methods' frames share with the thesis's: trace every sub-sample of a chosen set of
pixels (listed in locality order and compacted as `fovjax.foveate._frame` lists its samples,
then traced as its slots are: `traced_sums`) and resolve them to per-pixel means."""

from __future__ import annotations

import dataclasses
import functools
from typing import cast

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ...native.internal import on_platforms
from .._frame import (
    FoveatedOutputs,
    Selection,
    count_true,
    locality_order,
    pixel_means,
    samples_by_region,
    traced_count,
    traced_sums,
)
from .._native import native_select_samples
from .._positions import positions_at
from .._sampling import MANDATORY, SKIPPED, compaction_order, regions, subsample_rank


def select_pixels(ecc, trace_pixel, *, spp: int, foveation) -> Selection:
    """Every sub-sample of the pixels to trace (`trace_pixel` (2, H, W)), compacted in
    locality order; the regions are the foveation's (for the frame statistics)."""
    classes = jnp.where(trace_pixel[:, None], MANDATORY, SKIPPED).astype(jnp.int32)
    classes = jnp.broadcast_to(classes, (2, spp) + ecc.shape[1:])
    _, _, h, w = classes.shape
    perm = jnp.asarray(locality_order(h, w))
    local = classes.reshape(2, spp, h * w)[:, :, perm].transpose(0, 2, 1).reshape(-1)
    order, counts, rank = cast(tuple[Array, Array, Array], compaction_order(local, with_rank=True))
    region = jnp.stack([regions(ecc[i], foveation) for i in range(2)])
    return Selection(ecc, region, classes, counts, order, rank, counts[MANDATORY])


def pixel_selection(ecc, trace_pixel, *, spp: int, foveation, native: bool):
    """`select_pixels` with its traced mask (2, S, H, W), traced samples per pixel (2, H, W) and
    per region (3): (selection with int8 classes and no ranks, mask, counts, counts by region).
    `native`: on a CPU through the thesis's native selection handler (`native_select_samples`),
    chosen inside the program (the JAX functions elsewhere), under its rule "pixel-mask": every
    sub-sample of a pixel whose P is 1 (the traced pixels) mandatory, nothing else: the same
    integers as `select_pixels`, without XLA's screen-sized gathers, prefix sums and per-region
    scatter."""
    _, h, w = ecc.shape

    def in_jax():
        region = jnp.stack([regions(ecc[i], foveation) for i in range(2)]).astype(jnp.int8)
        sel = select_pixels(ecc, trace_pixel, spp=spp, foveation=foveation)
        mask = sel.classes != SKIPPED
        n = traced_count(mask, spp)
        by_region = samples_by_region(region, n)
        return region, sel.classes.astype(jnp.int8), sel.order, sel.counts, mask, n, by_region

    if not native or 2 * spp * h * w >= 2**31:
        region, classes, order, counts, mask, n, by_region = in_jax()
    else:

        def on_cpu():
            return native_select_samples(
                ecc,
                (trace_pixel[0].astype(jnp.float32), trace_pixel[1].astype(jnp.float32)),
                (foveation.fovea_deg, foveation.periphery_deg),
                jnp.zeros((2, 2), jnp.uint32),  # the draws' key: no draw is made
                locality_order(h, w),
                (spp, spp, spp),
                subsample_rank(spp),
                spp=spp,
                rule="pixel-mask",
                blocks=(1, 1),
                budget=2 * spp * h * w,
            )

        outs = on_platforms(in_jax, cpu=on_cpu, derivatives=False)()
        region, classes, order, counts, mask, n, by_region = outs
    sel = Selection(ecc, region, classes, counts, order, None, counts[MANDATORY])
    return sel, mask, n, by_region


def side_by_side(eyes: Float[Array, "2 H W 3"]) -> Float[Array, "H W2 3"]:
    """Both eyes' images side by side, left first: `concatenate([eyes[0], eyes[1]], axis=1)` as
    a transpose (XLA:CPU fuses a concatenate with the gathers and blends before it into one
    loop several times slower than the same work written out)."""
    _, h, w, c = eyes.shape
    return jnp.transpose(eyes, (1, 0, 2, 3)).reshape(h, 2 * w, c)


@dataclasses.dataclass(frozen=True)
class TracedPixels:
    """The traced pixels of a frame: the selection, the sub-sample positions (a function of
    (sample, pixel)), the chunk size, the per-pixel means and counts, the ray counts."""

    selection: Selection
    positions: object
    size: int
    budget: int
    prefill: Float[Array, "2 H W 3"]
    n: Int[Array, "2 H W"]
    mask: Bool[Array, "2 S H W"]
    counts: object  # fovjax.render RayCounts
    bad_pixel: Bool[Array, "2 H W"]
    by_region: Int[Array, " 3"]
    first_points: Float[Array, "2 H W 3"] | None = None  # `_frame.first_hit_points`', where asked

    def outputs(self, image, diagnostics) -> FoveatedOutputs:
        """The frame's `FoveatedOutputs` with `image` (H, 2W, 3) (every traced sample counts as
        mandatory: a method's pixels are traced whole, nothing is drawn or dropped)."""
        sel = self.selection
        wanted = sel.counts[MANDATORY]
        return FoveatedOutputs(
            image=image,
            counts=self.counts,
            primary_by_region=self.by_region,
            mandatory=wanted,
            optional=jnp.zeros((), jnp.int32),
            dropped=jnp.zeros((), jnp.int32),
            padding=self.budget - wanted,
            traced=self.mask if "traced" in diagnostics else None,
            region=sel.region.astype(jnp.int8) if "region" in diagnostics else None,
            eccentricity=sel.eccentricity if "eccentricity" in diagnostics else None,
            prefill=self.prefill if "prefill" in diagnostics else None,
            bad_pixels=count_true(self.bad_pixel),
        )


def trace_pixels(
    scene,
    bvh,
    cameras,
    key,
    ecc,
    trace_pixel,
    *,
    foveation,
    spp,
    jitter,
    config,
    first_points: float | None = None,
) -> TracedPixels:
    """Trace and shade every sub-sample of the pixels `trace_pixel` (2, H, W) at the full
    render's sub-pixel positions of `key` (pixel-cell centres without `jitter`), with all their
    shadow and reflection rays; a static budget of every sample (nothing is ever dropped).
    `first_points` (None, or a miss's distance in scene sizes): also each pixel's sub-sample 0's
    primary hit point (`_frame.first_hit_points`)."""
    from ...render import RayCounts
    from ...render.internal import integrator_plan

    _, h, w = ecc.shape
    native = integrator_plan(config).cpu
    sel, mask, n, by_region = pixel_selection(ecc, trace_pixel, spp=spp, foveation=foveation, native=native)
    budget = 2 * spp * h * w
    size = min(config.chunk_size, budget)
    padded = -(-budget // size) * size
    if padded > sel.order.shape[0]:  # whole chunks of slots (the padding is never live)
        sel = sel._replace(order=jnp.pad(sel.order, (0, padded - sel.order.shape[0])))
    jitter_key = key if jitter else None
    positions = functools.partial(positions_at, jitter_key, spp=spp, h=h, w=w)
    # The thesis's frame's slots: on a CPU with the native integrator one call of the slots
    # handler makes, traces and sums every live slot's ray; elsewhere the chunk loop.
    traced = traced_sums(
        scene, bvh, cameras, jitter_key, sel, config=config, budget=budget, first_points=first_points
    )
    points = None if first_points is None else traced.consumed[3].reshape(2, h, w, 3)
    prefill, n_bad, bad_pixel = pixel_means(traced.consumed, n, h=h, w=w, bad_color=config.bad_color)
    # Made once: the methods read each pixel's mean several times (magnified, held, blended),
    # and XLA would otherwise recompute the division at each read.
    prefill = jax.lax.optimization_barrier(prefill)
    counts = RayCounts(traced.primary, traced.shadow, traced.reflection, n_bad)
    return TracedPixels(sel, positions, size, budget, prefill, n, mask, counts, bad_pixel, by_region, points)
