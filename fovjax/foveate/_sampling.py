"""Which sub-samples of an eye's image are traced: regions, blocks, P(ω) draws, priorities."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ._config import Foveation, region_spp

FOVEA = 0
"""Region code of the fovea (eccentricity ≤ `fovea_deg`) in `FoveatedFrame.regions`."""
PERIPHERY = 1
"""Region code of the periphery (`fovea_deg` < eccentricity ≤ `periphery_deg`)."""
OUTSIDE = 2
"""Region code of everything beyond the periphery."""
# Compaction order: samples that must be traced, then the probabilistic extras, then the rest.
MANDATORY = 0
"""Sample class: always traced (the fovea's samples, the blocks' top-left pixels)."""
OPTIONAL = 1
"""Sample class: traced with the acuity model's probability."""
SKIPPED = 2
"""Sample class: never traced (filled from its block)."""


def regions(ecc: Float[Array, "H W"], foveation: Foveation) -> Int[Array, "H W"]:
    """0 fovea (ω ≤ ω0), 1 periphery (ω0 < ω ≤ ω1), 2 outside (ω > ω1)."""
    return jnp.where(
        ecc <= foveation.fovea_deg, FOVEA, jnp.where(ecc <= foveation.periphery_deg, PERIPHERY, OUTSIDE)
    )


def block_size(region: Int[ArrayLike, "H W"], foveation) -> Int[Array, "H W"]:
    b_peri, b_out = foveation.blocks
    return jnp.where(region == FOVEA, 1, jnp.where(region == PERIPHERY, b_peri, b_out)).astype(jnp.int32)


def top_left(region, foveation) -> tuple[Int[Array, "H W"], Int[Array, "H W"], Bool[Array, "H W"]]:
    """(row, col) of each pixel's block's top-left pixel, and whether the pixel is one."""
    h, w = region.shape
    b = block_size(region, foveation)
    y = jnp.arange(h, dtype=jnp.int32)[:, None]
    x = jnp.arange(w, dtype=jnp.int32)[None, :]
    ty, tx = y - y % b, x - x % b
    return ty, tx, (ty == y) & (tx == x)


def block_top_lefts(region: Int[ArrayLike, "H W"], foveation) -> Bool[Array, "H W"]:
    """Every pixel that is some pixel's block top-left (`top_left`): the fill source of that
    block. (A pixel that tests only itself, as the thesis's ray generation does, can miss this
    at region boundaries, where a 2x2 block's top-left lies in the outside zone and is not
    4-aligned.)

    Pixel (y, x) is the top-left of a block of edge b exactly when b divides y and x and some
    pixel of the aligned b x b block from it has block edge b: an OR over each block's pixels
    (strided slices), the same mask as scattering every pixel's top-left, without the
    screen-sized scatter (whose index arrays cost more than the rest of the sampling on
    XLA:CPU)."""
    region = jnp.asarray(region)
    h, w = region.shape
    mask = region == FOVEA  # blocks of one pixel
    for code, b in ((PERIPHERY, int(foveation.blocks[0])), (OUTSIDE, int(foveation.blocks[1]))):
        inside = region == code
        if b == 1:
            mask = mask | inside
            continue
        hp, wp = -(-h // b) * b, -(-w // b) * b
        inside = jnp.pad(inside, ((0, hp - h), (0, wp - w)))
        hit = inside[0::b, 0::b]
        for i in range(b):
            for j in range(b):
                if i or j:
                    hit = hit | inside[i::b, j::b]
        corner = jnp.zeros((1, b, 1, b), bool).at[0, 0, 0, 0].set(True)
        tl = (hit[:, None, :, None] & corner).reshape(hp, wp)[:h, :w]
        mask = mask | tl
    return mask


def thesis_measured_mandatory(region: Int[ArrayLike, "H W"], spp: int) -> Bool[Array, "S H W"]:
    """The samples the thesis's measured ray counts imply (rule "thesis-measured"): every
    sub-sample of a pixel within the periphery threshold (fovea and periphery regions), and
    one sample (sub-sample 0) of every pixel beyond it, whatever the SPP; nothing is drawn.

    Why: the thesis's Table 2 is exactly linear in SPP, rays = a + b·SPP, with b / b_full the
    share of pixels within ω1 and a the pixels beyond ω1 at about one sample each; see the
    docs/thesis.md, "Table 2: what its ray counts imply"."""
    inside = (jnp.asarray(region) != OUTSIDE)[None]
    first = (jnp.arange(spp) == 0)[:, None, None]
    return inside | first


@functools.lru_cache(maxsize=16)
def subsample_rank(spp: int) -> np.ndarray:
    """The rank of each of a pixel's `spp` sub-samples in the order a region with fewer
    samples per pixel keeps them (`Fidelity.spp`: a pixel keeps the sub-samples of rank < its
    region's spp). Sub-sample s lies in cell (s % n, s // n) of the pixel's n x n grid
    (`fovjax.scene.pixel_sample_positions`); the order starts with sub-sample 0 (the one the
    rule "thesis-measured" keeps beyond the periphery) and then always takes the cell farthest
    from those already taken (ties: the lowest index), so every prefix is spread over the
    pixel: at SPP 4 the order is 0, 3, 1, 2 (a diagonal pair first)."""
    n = int(round(spp**0.5))
    cells = np.stack([np.arange(spp) % n, np.arange(spp) // n], axis=1).astype(np.float64)
    order = [0]
    gap = np.linalg.norm(cells - cells[0], axis=1)
    for _ in range(spp - 1):
        gap[order] = -1.0
        nxt = int(np.argmax(gap))  # argmax: the lowest index among ties
        order.append(nxt)
        gap = np.minimum(gap, np.linalg.norm(cells - cells[nxt], axis=1))
    rank = np.empty(spp, np.int32)
    rank[np.asarray(order)] = np.arange(spp, dtype=np.int32)
    return rank


def allowed_samples(region: Int[ArrayLike, "H W"], foveation) -> Bool[Array, "S H W"] | None:
    """Which sub-samples a pixel may trace under its region's `Fidelity.spp` (rank
    below the region's samples per pixel), or None where every region takes every sub-sample."""
    spp = region_spp(foveation)
    if spp is None:
        return None
    rank = jnp.asarray(subsample_rank(foveation.spp))[:, None, None]
    return rank < jnp.asarray(spp, jnp.int32)[region][None]


# Rows per band of `uniform_draws`.
DRAW_ROWS = 64


def uniform_draws(key: jax.Array, shape: tuple[int, ...]) -> Float[Array, "S H W"]:
    """`jax.random.uniform(key, shape)` (float32), the same values, drawn a band of rows at a
    time (`_positions.uniform_at`, a `lax.fori_loop`): the generator's intermediate arrays are
    a band's, not a screen's (on a CPU every screen-sized temporary is fresh memory on every
    frame). Falls back to the one call where the key's PRNG does not allow it."""
    from ._positions import per_sample_threefry, uniform_at

    spp, h, w = shape
    if not per_sample_threefry(key) or spp * h * w >= 2**31:
        return jax.random.uniform(key, shape, jnp.float32)
    rows = min(DRAW_ROWS, h)

    def band(b, out):
        first = jnp.minimum(b * rows, h - rows)  # the last band overlaps the one before
        y = first + jnp.arange(rows, dtype=jnp.int32)[None, :, None]
        s = jnp.arange(spp, dtype=jnp.int32)[:, None, None]
        index = (s * h + y) * w + jnp.arange(w, dtype=jnp.int32)[None, None, :]
        return jax.lax.dynamic_update_slice(out, uniform_at(key, index), (0, first, 0))

    return jax.lax.fori_loop(0, -(-h // rows), band, jnp.zeros(shape, jnp.float32))


def sample_classes(
    ecc: Float[Array, "H W"], foveation, key: jax.Array
) -> tuple[Int[Array, "S H W"], Int[Array, "H W"]]:
    """Class of every sub-sample (spp, H, W): MANDATORY (traced: fovea, and block top-lefts under
    the "either" rule; under "thesis-measured" see `thesis_measured_mandatory`), OPTIONAL
    (traced: kept by its P(ω) draw), SKIPPED; and the pixel regions.
    Blocks are aligned to the eye's pixel grid; a pixel's block size is its own region's.

    One uniform draw per sub-sample from `key`: a fixed key gives the same pattern frame after
    frame (temporally stable), a fresh key per frame a fresh pattern.
    """
    region = regions(ecc, foveation)
    is_tl = block_top_lefts(region, foveation)
    p = foveation.probability(ecc)
    u = uniform_draws(key, (foveation.spp,) + ecc.shape)
    kept = u < p[None]
    fovea = (region == FOVEA)[None]
    if foveation.rule == "either":
        mandatory = fovea | is_tl[None]
        optional = ~mandatory & kept
    elif foveation.rule == "strict":  # only top-left pixels, each sub-sample kept with P(ω)
        mandatory = jnp.broadcast_to(fovea, kept.shape)
        optional = ~mandatory & is_tl[None] & kept
    else:  # thesis-measured: see `thesis_measured_mandatory`
        mandatory = jnp.broadcast_to(thesis_measured_mandatory(region, foveation.spp), kept.shape)
        optional = jnp.zeros_like(mandatory)
    cls = jnp.where(mandatory, MANDATORY, jnp.where(optional, OPTIONAL, SKIPPED)).astype(jnp.int32)
    allowed = allowed_samples(region, foveation)
    if allowed is not None:  # beyond the region's samples per pixel, nothing is traced
        cls = jnp.where(allowed, cls, SKIPPED)
    # Where the classes do not depend on the frame's values (the rule "thesis-measured" at SPP
    # 1: every sample mandatory), XLA would fold the screen-sized prefix sums and reductions
    # downstream at compile time, taking minutes for that frame program at full size; the
    # barrier keeps them run-time work.
    return jax.lax.optimization_barrier(cls), region


def _two_prefix_sums(
    a: Int[Array, " N"], b: Int[Array, " N"], block: int = 1024
) -> tuple[Int[Array, " N"], Int[Array, " N"]]:
    """The inclusive running sums of two arrays of 0/1 entries: the same integers as
    `jnp.cumsum(a)`, `jnp.cumsum(b)`, several times faster over millions of entries on XLA:CPU,
    where a flat cumsum of one long axis is slow. In blocks: each block's own running sum plus
    the sum of the blocks before it. Within a block each count stays below 2**16, so both
    travel in one int32 (b in the high half) through the long running sum, the costly one;
    only the short sums of the blocks before are per array."""
    if block >= 2**16:
        raise ValueError(f"_two_prefix_sums: block {block} must be below 2**16 (the packed halves)")
    n = a.shape[0]
    if n <= block:
        return jnp.cumsum(a), jnp.cumsum(b)
    padded = -(-n // block) * block
    packed = jnp.pad(a + (b << 16), (0, padded - n)).reshape(-1, block)
    within = jnp.cumsum(packed, axis=1)
    within_a, within_b = within & 0xFFFF, within >> 16
    outs = []
    for w in (within_a, within_b):
        before = jnp.cumsum(w[:, -1]) - w[:, -1]
        outs.append((w + before[:, None]).reshape(-1)[:n])
    return outs[0], outs[1]


def compaction_order(classes: Int[Array, " N"], *, with_rank: bool = False):
    """A stable permutation listing MANDATORY samples first, then OPTIONAL, then SKIPPED (each
    in its original, spatially coherent order), and the count of each class. O(N), no sort;
    the counts are the running sums' last entries (no separate reductions). `with_rank`: also
    each sample's position in that order (the inverse permutation)."""
    is_mandatory, is_optional = ((classes == c).astype(jnp.int32) for c in (MANDATORY, OPTIONAL))
    ones = _two_prefix_sums(is_mandatory, is_optional)
    index = jnp.arange(1, classes.shape[0] + 1, dtype=jnp.int32)
    running = [*ones, index - ones[0] - ones[1]]  # the skipped ones: the rest
    counts = jnp.stack([r[-1] for r in running])
    offsets = (jnp.int32(0), counts[0], counts[0] + counts[1])
    rank = jnp.zeros_like(classes)
    for c in (MANDATORY, OPTIONAL, SKIPPED):
        rank = jnp.where(classes == c, offsets[c] + running[c] - 1, rank)
    order = (
        jnp.zeros_like(classes)
        .at[rank]
        .set(jnp.arange(classes.shape[0], dtype=classes.dtype), unique_indices=True)
    )
    return (order, counts, rank) if with_rank else (order, counts)
