"""Reconstruction of a foveated eye image: resolve sub-samples, fill blanks, blur (thesis 4.5)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ._sampling import FOVEA, PERIPHERY

# Width of the band outside the fovea over which the image blends from sharp to blurred.
FOVEA_BLEND_DEG = 1.0


def gaussian_taps(sigma: float, radius: int = 2) -> np.ndarray:
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    return (k / k.sum()).astype(np.float32)


def _separable(image: Float[Array, "H W C"], taps: np.ndarray) -> Float[Array, "H W C"]:
    """Separable convolution with edge-reflecting borders (5 shifted adds per axis)."""
    r = len(taps) // 2
    h, w = image.shape[:2]
    padded = jnp.pad(image, ((r, r), (0, 0), (0, 0)), mode="reflect")
    image = sum(float(t) * padded[i : i + h] for i, t in enumerate(taps))
    padded = jnp.pad(image, ((0, 0), (r, r), (0, 0)), mode="reflect")
    return sum(float(t) * padded[:, i : i + w] for i, t in enumerate(taps))


def pull_push(image: Float[Array, "H W C"], valid: Bool[Array, "H W"]) -> Float[Array, "H W C"]:
    """Fill invalid pixels from valid ones (pull-push, Gortler et al. 1996): average valid
    pixels over 2x2 cells level by level up to one cell, then fill each level's empty cells
    from the coarser level on the way back down. A static number of levels, no pixel loop."""
    h, w = valid.shape
    levels = int(np.ceil(np.log2(max(h, w)))) if max(h, w) > 1 else 0
    size = 1 << levels
    weight = jnp.zeros((size, size), jnp.float32).at[:h, :w].set(valid.astype(jnp.float32))
    value = jnp.zeros((size, size, image.shape[-1]), jnp.float32).at[:h, :w].set(image)
    value = value * weight[..., None]
    pyramid = []
    for _ in range(levels):
        pyramid.append((value, weight))
        s = value.shape[0] // 2
        value = value.reshape(s, 2, s, 2, -1).sum((1, 3))
        weight = weight.reshape(s, 2, s, 2).sum((1, 3))
    colour = value / jnp.maximum(weight, 1e-30)[..., None]
    for value, weight in reversed(pyramid):
        up = jnp.repeat(jnp.repeat(colour, 2, axis=0), 2, axis=1)
        colour = jnp.where(weight[..., None] > 0, value / jnp.maximum(weight, 1e-30)[..., None], up)
    return colour[:h, :w]


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
    foveation,
) -> tuple[Float[Array, "H W 3"], Bool[Array, "H W"]]:
    """One pass: every pixel with no traced sample takes its block's top-left value, then a 5×5
    Gaussian (σ = foveation.blur_sigma) smooths everything outside the fovea, blending in over
    FOVEA_BLEND_DEG beyond ω0 so the fovea (and every traced foveal pixel) stays untouched;
    `blur_fovea=True` blurs every pixel instead. Returns (image, pixels that were blank)."""
    pix, n = resolve(colors, traced)
    return fill_and_blur_pixels(pix, n, region, ecc, foveation)


def _block_broadcast(x, b: int):
    """Each pixel takes the value of the top-left pixel of its aligned b × b block."""
    if b == 1:
        return x
    h, w = x.shape[:2]
    top = x[::b, ::b]
    up = jnp.repeat(jnp.repeat(top, b, axis=0), b, axis=1)
    return up[:h, :w]


def top_left_values(pix, n, region, foveation):
    """`pix` and `n` at each pixel's block's top-left pixel (`top_left`), from strided slices
    and repeats per block size (the block sizes are static): no per-pixel gather, which
    XLA:CPU runs several times slower over a screen."""
    sizes = (1, *foveation.blocks)
    by_region = [
        _block_broadcast(jnp.concatenate([pix, n[..., None].astype(pix.dtype)], -1), b) for b in sizes
    ]
    out = jnp.where(
        (region == FOVEA)[..., None],
        by_region[0],
        jnp.where((region == PERIPHERY)[..., None], by_region[1], by_region[2]),
    )
    return out[..., :-1], out[..., -1]


def fill_and_blur_pixels(
    pix: Float[Array, "H W 3"],
    n: Int[Array, "H W"],
    region: Int[Array, "H W"],
    ecc: Float[Array, "H W"],
    foveation,
) -> tuple[Float[Array, "H W 3"], Bool[Array, "H W"]]:
    """`fill_and_blur` from resolved pixels: the mean of each pixel's traced samples and how
    many there were."""
    blank = n == 0
    tl_pix, tl_n = top_left_values(pix, n, region, foveation)
    filled = jnp.where(blank[..., None], tl_pix, pix)
    # A block whose top-left was not traced (the "strict" rule, or samples dropped beyond the
    # ray budget) is still empty: fill it from the nearest traced pixels by pull-push.
    have = ~blank | (tl_n > 0)
    # Only when some block is empty (rare: the strict rule, or a budget overflow): the pyramid
    # is a dozen screen-sized passes.
    filled = jax.lax.cond(
        jnp.all(have),
        lambda f: f,
        lambda f: jnp.where(have[..., None], f, pull_push(f, have)),
        filled,
    )
    blurred = _separable(filled, gaussian_taps(foveation.blur_sigma))
    if foveation.blur_fovea:
        return blurred, blank
    t = jnp.clip((ecc - foveation.fovea_deg) / FOVEA_BLEND_DEG, 0.0, 1.0)
    weight = (t * t * (3 - 2 * t))[..., None]  # smoothstep
    return filled * (1 - weight) + blurred * weight, blank
