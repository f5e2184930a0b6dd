"""What the methods' frames share with the thesis's: trace every sub-sample of a chosen set of
pixels (listed in locality order and compacted as `fovjax.foveate._frame` lists its samples,
then traced chunk by chunk over the traced slots only) and resolve them to per-pixel means."""

from __future__ import annotations

import dataclasses
import functools
from typing import cast

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from .._frame import FoveatedOutputs, Selection, accumulate, locality_order, trace_selection, traced_count
from .._positions import positions_at
from .._sampling import MANDATORY, SKIPPED, compaction_order, regions


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

    def outputs(self, image, diagnostics) -> FoveatedOutputs:
        """The frame's `FoveatedOutputs` with `image` (H, 2W, 3) (every traced sample counts as
        mandatory: a method's pixels are traced whole, nothing is drawn or dropped)."""
        sel = self.selection
        wanted = sel.counts[MANDATORY]
        by_region = jnp.zeros(3, jnp.int32).at[sel.region.reshape(-1)].add(self.n.reshape(-1))
        return FoveatedOutputs(
            image=image,
            counts=self.counts,
            primary_by_region=by_region,
            mandatory=wanted,
            optional=jnp.zeros((), jnp.int32),
            dropped=jnp.zeros((), jnp.int32),
            padding=self.budget - wanted,
            traced=self.mask if "traced" in diagnostics else None,
            region=sel.region.astype(jnp.int8) if "region" in diagnostics else None,
            eccentricity=sel.eccentricity if "eccentricity" in diagnostics else None,
            prefill=self.prefill if "prefill" in diagnostics else None,
            bad_pixels=jnp.sum(self.bad_pixel, dtype=jnp.int32),
        )


def trace_pixels(
    scene, bvh, cameras, key, ecc, trace_pixel, *, foveation, spp, jitter, config
) -> TracedPixels:
    """Trace and shade every sub-sample of the pixels `trace_pixel` (2, H, W) at the full
    render's sub-pixel positions of `key` (pixel-cell centres without `jitter`), with all their
    shadow and reflection rays; a static budget of every sample (nothing is ever dropped)."""
    from ...render import RayCounts

    _, h, w = ecc.shape
    sel = select_pixels(ecc, trace_pixel, spp=spp, foveation=foveation)
    budget = 2 * spp * h * w
    size = min(config.chunk_size, budget)
    padded = -(-budget // size) * size
    if padded > sel.order.shape[0]:  # whole chunks of slots (the padding is never live)
        sel = sel._replace(order=jnp.pad(sel.order, (0, padded - sel.order.shape[0])))
    positions = functools.partial(positions_at, key if jitter else None, spp=spp, h=h, w=w)
    traced = trace_selection(scene, bvh, cameras, positions, sel, config=config, budget=budget)
    mask = sel.classes != SKIPPED
    n = traced_count(mask, spp)
    zero = jnp.minimum(traced.primary, 0)  # see `foveated_stereo`: not hoisted to the start
    init = (jnp.full((2 * h * w, 3), zero, jnp.float32), jnp.zeros(2 * h * w, bool), zero)
    prefill, n_bad, bad_pixel = accumulate(
        traced.total, sel, n, spp=spp, h=h, w=w, size=size, bad_color=config.bad_color, init=init
    )
    counts = RayCounts(traced.primary, traced.shadow, traced.reflection, n_bad)
    return TracedPixels(sel, positions, size, budget, prefill, n, mask, counts, bad_pixel)
