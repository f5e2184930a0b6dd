"""Reconstruction of a foveated eye image: resolve sub-samples, fill blanks, blur (thesis 4.5)."""

from __future__ import annotations

from typing import cast

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ._config import Foveation
from ._sampling import FOVEA, PERIPHERY

# Width of the band outside the fovea over which the image blends from sharp to blurred.
FOVEA_BLEND_DEG = 1.0


def gaussian_taps(sigma: float, radius: int = 2) -> np.ndarray:
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    return (k / k.sum()).astype(np.float32)


def pull_push(image: Float[Array, "H W C"], valid: Bool[Array, "H W"]) -> Float[Array, "H W C"]:
    """Fill invalid pixels from valid ones (pull-push, Gortler et al. 1996): average valid
    pixels over 2x2 cells level by level up to one cell, then fill each level's empty cells
    from the coarser level on the way back down. A static number of levels, no pixel loop.
    Cells are aligned to the image's top-left corner; a level with an odd side gets a row or
    column of empty (zero-weight) cells, so the pyramid is no larger than the image (the
    same cells and sums as a pyramid over the image padded to a power-of-two square)."""
    h, w = valid.shape
    levels = int(np.ceil(np.log2(max(h, w)))) if max(h, w) > 1 else 0
    weight = valid.astype(jnp.float32)
    value = image.astype(jnp.float32) * weight[..., None]
    pyramid = []
    for _ in range(levels):
        pyramid.append((value, weight))
        rows, cols = value.shape[0], value.shape[1]
        pad = ((0, rows % 2), (0, cols % 2))
        value = jnp.pad(value, pad + ((0, 0),))
        weight = jnp.pad(weight, pad)
        rows, cols = value.shape[0] // 2, value.shape[1] // 2
        value = value.reshape(rows, 2, cols, 2, -1).sum((1, 3))
        weight = weight.reshape(rows, 2, cols, 2).sum((1, 3))
    colour = value / jnp.maximum(weight, 1e-30)[..., None]
    for value, weight in reversed(pyramid):
        rows, cols = weight.shape
        up = jnp.repeat(jnp.repeat(colour, 2, axis=0), 2, axis=1)[:rows, :cols]
        colour = jnp.where(weight[..., None] > 0, value / jnp.maximum(weight, 1e-30)[..., None], up)
    return colour


def resolve(colors: Float[Array, "S H W 3"], traced: Bool[Array, "S H W"]):
    """Box-filter the traced sub-samples of each pixel. Returns (colour, number traced)."""
    n = jnp.sum(traced, axis=0)
    total = jnp.sum(jnp.where(traced[..., None], colors, 0.0), axis=0)
    return total / jnp.maximum(n, 1)[..., None], n


def fill_and_blur(
    colors: Float[Array, "S H W 3"],
    traced: Bool[Array, "S H W"],
    region: Int[Array, "H W"],
    ecc: Float[Array, "H W"],
    foveation: Foveation,
) -> tuple[Float[Array, "H W 3"], Bool[Array, "H W"]]:
    """One pass: every pixel with no traced sample takes its block's top-left value, then a 5×5
    Gaussian (σ = foveation.blur_sigma) smooths everything outside the fovea, blending in over
    FOVEA_BLEND_DEG beyond ω0 so the fovea (and every traced foveal pixel) stays untouched;
    `blur_fovea=True` blurs every pixel instead. Returns (image, pixels that were blank)."""
    pix, n = resolve(colors, traced)
    return fill_and_blur_pixels(pix, n, region, ecc, foveation)


def _block_broadcast(x, b: int):
    """Each pixel takes the value of the top-left pixel of its aligned b × b block (`x`
    (..., H, W, C): rows and columns are the axes before the last)."""
    if b == 1:
        return x
    h, w = x.shape[-3:-1]
    top = x[..., ::b, ::b, :]
    up = jnp.repeat(jnp.repeat(top, b, axis=-3), b, axis=-2)
    return up[..., :h, :w, :]


def top_left_values(pix, n, region, foveation):
    """`pix` and `n` at each pixel's block's top-left pixel (`top_left`), from strided slices
    and repeats per block size (the block sizes are static): no per-pixel gather, which
    XLA:CPU runs several times slower over a screen. Each fuses into its consumer (no
    screen-sized copy: the colours and counts are not stacked into one array)."""
    sizes = (1, *foveation.blocks)

    def pick(x):
        by_region = [_block_broadcast(x, b) for b in sizes]
        return jnp.where(
            (region == FOVEA)[..., None],
            by_region[0],
            jnp.where((region == PERIPHERY)[..., None], by_region[1], by_region[2]),
        )

    return pick(pix), pick(n[..., None])[..., 0]


# Rows per band of `blur_and_blend`: its temporaries are a band's, not a screen's.
BAND_ROWS = 64


def _reflect(i, n: int):
    """Indices reflected into [0, n) as `jnp.pad(mode="reflect")` does (the edge not repeated)."""
    i = jnp.abs(i)
    return jnp.where(i > n - 1, 2 * (n - 1) - i, i)


def blur_and_blend(
    filled: Float[Array, "E H W 3"], ecc: Float[Array, "E H W"], foveation, *, side_by_side: bool = False
) -> Float[Array, "..."]:
    """The 5×5 Gaussian of `fill_and_blur` (σ = foveation.blur_sigma, edge-reflecting borders)
    of each of the E images, blended with the sharp image by eccentricity (or the blur alone
    with `blur_fovea`), in bands of `BAND_ROWS` rows (a `lax.fori_loop`): the values of the
    separable convolution over the whole screen (5 shifted adds per axis over reflect-padded
    copies; tests/test_foveate_blur.py holds it as this function's oracle), but the only
    screen-sized array is the result, (E, H, W, 3), or the images side by side (H, E·W, 3)
    with `side_by_side` (written in place: no copy to lay the eyes out). On a CPU each
    screen-sized temporary is fresh memory, faulted in on every frame."""
    taps = gaussian_taps(foveation.blur_sigma)
    r = len(taps) // 2
    e, h, w, c = filled.shape
    rows = min(BAND_ROWS, h)
    n_bands = -(-h // rows)
    shape = (h, e * w, c) if side_by_side else (e, h, w, c)

    def band(i, out):
        eye, first = i // n_bands, jnp.minimum((i % n_bands) * rows, h - rows)  # the last overlaps
        src = filled[eye, _reflect(first - r + jnp.arange(rows + 2 * r), h)]  # (rows + 2r, W, 3)
        # sum() of arrays is an array (the taps are never empty); cast says so to the checker.
        vertical = cast(Array, sum(float(t) * src[k : k + rows] for k, t in enumerate(taps)))
        padded = jnp.pad(vertical, ((0, 0), (r, r), (0, 0)), mode="reflect")
        result = cast(Array, sum(float(t) * padded[:, k : k + w] for k, t in enumerate(taps)))
        if not foveation.blur_fovea:
            ecc_rows = jax.lax.dynamic_slice(ecc, (eye, first, 0), (1, rows, w))[0]
            t = jnp.clip((ecc_rows - foveation.fovea_deg) / FOVEA_BLEND_DEG, 0.0, 1.0)
            weight = (t * t * (3 - 2 * t))[..., None]  # smoothstep
            result = src[r : r + rows] * (1 - weight) + result * weight
        if side_by_side:
            return jax.lax.dynamic_update_slice(out, result, (first, eye * w, 0))
        return jax.lax.dynamic_update_slice(out, result[None], (eye, first, 0, 0))

    # Every element is written by a band, so the loop may start from any values: a broadcast of
    # one input element is not created (and its memory held) before the input exists, as a
    # constant zero array would be (XLA hoists it to the program's start).
    start = jnp.broadcast_to(filled[0, 0, 0, 0], shape)
    return jax.lax.fori_loop(0, e * n_bands, band, start)


def fill_blanks(pix, n, region, foveation, *, top_lefts_traced: bool = False):
    """Every pixel with no traced sample takes its block's top-left value; a block whose
    top-left was not traced either is filled by pull-push. `pix` (..., H, W, 3), leading axes
    independent images. `top_lefts_traced` (static): the caller knows every block's top-left
    has a traced sample (the rule "either" with no sample dropped), so the pull-push is left
    out of the program. Returns (filled, pixels that were blank)."""
    blank = n == 0
    tl_pix, tl_n = top_left_values(pix, n, region, foveation)
    filled = jnp.where(blank[..., None], tl_pix, pix)
    # A block whose top-left was not traced (the "strict" rule, or samples dropped beyond the
    # ray budget) is still empty: fill it from the nearest traced pixels by pull-push.
    have = ~blank | (tl_n > 0)

    # Only when some block is empty (rare: the strict rule, or a budget overflow): the pyramid
    # is a dozen screen-sized passes, one image at a time.
    def fill_empty(f):
        images = f.reshape((-1,) + f.shape[-3:])
        valid = have.reshape((-1,) + have.shape[-2:])

        def one(i, images):
            pushed = pull_push(images[i], valid[i])
            return images.at[i].set(jnp.where(valid[i][..., None], images[i], pushed))

        return jax.lax.fori_loop(0, images.shape[0], one, images).reshape(f.shape)

    if top_lefts_traced:
        return filled, blank
    return jax.lax.cond(jnp.all(have), lambda f: f, fill_empty, filled), blank


def fill_and_blur_pixels(
    pix: Float[Array, "H W 3"],
    n: Int[Array, "H W"],
    region: Int[Array, "H W"],
    ecc: Float[Array, "H W"],
    foveation: Foveation,
) -> tuple[Float[Array, "H W 3"], Bool[Array, "H W"]]:
    """`fill_and_blur` from resolved pixels: the mean of each pixel's traced samples and how
    many there were."""
    filled, blank = fill_blanks(pix, n, region, foveation)
    return blur_and_blend(filled[None], ecc[None], foveation)[0], blank
