"""Patney et al. 2016's frame: shading rate falling with eccentricity, temporal antialiasing and
a contrast-preserving pre-filter of the periphery (see `Patney2016` for the method and its
parameters).

One jitted program per configuration; gaze, head pose, key, the thresholds and the history are
traced. The history is explicit: `patney_stereo` takes the previous frame's `TaaHistory` and
returns this frame's; `empty_history` is the reset (no pixel holds one: the next frame is shown
as traced). The filters are pure image functions of static size (`gaussian_blur`,
`contrast_preserving_filter`, `taa_blend`), tested on their own; `rates_and_history` and
`prefilter_and_blend` have native handlers on a CPU.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ...native.internal import on_platforms
from .._frame import FoveatedOutputs, FrameOptions, diagnostics_tuple, eccentricities
from .._native import native_patney_prefilter, native_taa_blend
from ._base import FrameInputs
from ._catalog import Patney2016
from ._guenter import layer_weights
from ._sparse import side_by_side, trace_pixels

# Rec. 709 luminance weights: the contrast gain is measured on luminance and applied to every
# channel alike, so the enhancement keeps a pixel's hue.
LUMINANCE = (0.2126, 0.7152, 0.0722)
# Below this local standard deviation of the blurred image a region is flat: its gain is 1
# (a ratio of two vanishing deviations is noise).
FLAT_STD = 1e-4


class TaaHistory(NamedTuple):
    """Per eye and pixel: the temporally antialiased colour of the previous frame (before the
    pre-filter, so the filter is never compounded) and whether the pixel holds one."""

    color: Float[Array, "2 H W 3"]
    valid: Bool[Array, "2 H W"]


def empty_history(h: int, w: int) -> TaaHistory:
    """The reset: no pixel holds a history."""
    return TaaHistory(jnp.zeros((2, h, w, 3), jnp.float32), jnp.zeros((2, h, w), bool))


def _made(x):
    """`x`, computed on its own rather than inside each of its consumers' loops."""
    return jax.lax.optimization_barrier(x)


def gaussian_blur(image: Float[Array, "E H W C"], sigma: float) -> Float[Array, "E H W C"]:
    """A separable Gaussian blur of standard deviation `sigma` pixels (static; 0: `image`),
    truncated at 3σ and normalised (`blur_taps`), the border pixels repeated beyond the
    image: down the columns, then along the rows, the taps added in their order."""
    if sigma == 0:
        return image
    taps = blur_taps(sigma)
    return _blur(image, taps=taps, radius=len(taps) // 2)


def blur_taps(sigma: float) -> list[float]:
    """`gaussian_blur`'s taps for `sigma` (static): truncated at 3σ and normalised; σ 0: one
    tap of 1 (the image itself)."""
    if sigma == 0:
        return [1.0]
    radius = max(1, math.ceil(3 * sigma))
    taps = [math.exp(-0.5 * (k / sigma) ** 2) for k in range(-radius, radius + 1)]
    total = sum(taps)
    return [t / total for t in taps]


def _blur(image, *, taps, radius):
    _, h, w, _ = image.shape
    # Each padded image is made once (the barriers): fused into the taps' sums, the edge
    # padding's concatenate is evaluated per tap and output element, several times slower.
    padded = _made(jnp.pad(image, ((0, 0), (radius, radius), (0, 0), (0, 0)), mode="edge"))
    out = taps[0] * padded[:, :h]
    for k in range(1, len(taps)):
        out = out + taps[k] * padded[:, k : k + h]
    padded = _made(jnp.pad(out, ((0, 0), (0, 0), (radius, radius), (0, 0)), mode="edge"))
    result = taps[0] * padded[:, :, :w]
    for k in range(1, len(taps)):
        result = result + taps[k] * padded[:, :, k : k + w]
    return result


def luminance(image: Float[Array, "E H W 3"]) -> Float[Array, "E H W 1"]:
    return image @ jnp.asarray(LUMINANCE, jnp.float32)[:, None]


def deviation(var):
    """sqrt(max(`var`, 0)), a standard deviation from a variance that rounding may have made
    negative; its derivative is 0 where the variance is not positive (a flat neighbourhood,
    such as a held block: the square root's infinite slope there would make it NaN)."""
    positive = var > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, var, 1.0)), 0.0)


def local_std(values: Float[Array, "E H W C"], window_sigma: float) -> Float[Array, "E H W C"]:
    """The standard deviation of `values` in a Gaussian window of `window_sigma` pixels around
    each pixel (E[x²] − E[x]², never negative)."""
    mean = gaussian_blur(values, window_sigma)
    var = gaussian_blur(values * values, window_sigma) - mean * mean
    return deviation(var)


def contrast_preserving_filter(
    image: Float[Array, "E H W 3"],
    sigma: float,
    *,
    window_sigma: float,
    max_gain: float,
) -> Float[Array, "E H W 3"]:
    """The pre-filter: a Gaussian blur of `sigma` pixels, then the local contrast the blur
    removed restored. With B the blurred image, m its local mean (a Gaussian window of
    `window_sigma`) and s_I, s_B the local standard deviations of the luminance of `image` and
    of B in that window, the result is m + (B − m)·g with g = s_I / s_B clipped to [1,
    `max_gain`] (g = 1 where B is flat): a variance-preserving contrast enhancement, so
    the blur's low-pass shape is kept and its loss of contrast is not. A constant image is a
    fixed point (up to float rounding); the result is clipped at 0 (radiance)."""
    blurred = gaussian_blur(image, sigma)
    mean = gaussian_blur(blurred, window_sigma)
    s_image = local_std(luminance(image), window_sigma)
    # The window's mean of B's luminance is the luminance of its mean of B (both linear): one
    # blur fewer.
    l_blurred, mean_l_blurred = luminance(blurred), luminance(mean)
    var_blurred = gaussian_blur(l_blurred * l_blurred, window_sigma) - mean_l_blurred * mean_l_blurred
    s_blurred = deviation(var_blurred)
    gain = jnp.where(
        s_blurred > FLAT_STD, jnp.clip(s_image / jnp.maximum(s_blurred, FLAT_STD), 1.0, max_gain), 1.0
    )
    return jnp.maximum(mean + (blurred - mean) * gain, 0.0)


def rate_blend(fine, middle, coarse, w_inner, w_middle):
    """The shading rates' images blended by their weights (2, H, W): `middle` over `coarse` by
    `w_middle`, then `fine` over that by `w_inner`."""
    rest = coarse * (1 - w_middle)[..., None] + middle * w_middle[..., None]
    return rest * (1 - w_inner)[..., None] + fine * w_inner[..., None]


def prefilter_and_blend(
    image: Float[Array, "2 H W 3"],
    w_inner: Float[Array, "2 H W"],
    w_middle: Float[Array, "2 H W"],
    sigmas: tuple[float, float],
    *,
    window_per_sigma: float,
    max_gain: float,
    native: bool = False,
) -> Float[Array, "H W2 3"]:
    """The middle and coarse rates' pre-filters of `image` (`contrast_preserving_filter` of σ
    `sigmas`, the window `window_per_sigma`·σ) blended with it by the rates' weights
    (`rate_blend`), both eyes side by side. `native`: on a CPU through the pre-filter handler
    (`native_patney_prefilter`: each filter computed only in the rectangle where its weight is
    not 0, the blurs' taps added in their order), chosen inside the program; derivatives are
    this function's."""

    def in_jax(image, w_inner, w_middle):
        kw = {"max_gain": max_gain}
        middle, coarse = (
            contrast_preserving_filter(image, s, window_sigma=window_per_sigma * s, **kw) for s in sigmas
        )
        return side_by_side(rate_blend(image, middle, coarse, w_inner, w_middle))

    if not native:
        return in_jax(image, w_inner, w_middle)
    taps = tuple((blur_taps(s), blur_taps(window_per_sigma * s)) for s in sigmas)
    on_cpu = functools.partial(
        native_patney_prefilter, taps=taps, luminance=LUMINANCE, max_gain=max_gain, flat_std=FLAT_STD
    )
    return on_platforms(in_jax, cpu=on_cpu)(image, w_inner, w_middle)


def _neighbourhood(image: Float[Array, "E H W 3"]):
    """Per pixel the mean and standard deviation of its 3×3 neighbourhood (border repeated)."""
    _, h, w, _ = image.shape
    padded = _made(jnp.pad(image, ((0, 0), (1, 1), (1, 1), (0, 0)), mode="edge"))
    taps = [padded[:, dy : dy + h, dx : dx + w] for dy in range(3) for dx in range(3)]
    mean = sum(taps) / 9.0
    var = sum(t * t for t in taps) / 9.0 - mean * mean
    return mean, deviation(var)


def taa_blend(current, history: TaaHistory, *, alpha: float, gamma: float):
    """Temporal antialiasing: the history clamped per channel to the box mean ± `gamma`·std of
    the current frame's 3×3 neighbourhood (variance clipping), the box widened to contain the
    current pixel (so a still image is a fixed point), then blended, `alpha` of the current
    frame; where the history holds nothing, the current frame. Returns the blended image."""
    return _taa_blend(current, history.color, history.valid, alpha=alpha, gamma=gamma)


def rates_and_history(
    pix: Float[Array, "E H W 3"],
    w_inner: Float[Array, "E H W"],
    w_middle: Float[Array, "E H W"],
    history: TaaHistory,
    *,
    strides: tuple[int, int],
    alpha: float,
    gamma: float,
    native: bool = False,
) -> Float[Array, "E H W 3"]:
    """This frame's image from its traced pixels `pix`: the shading rates' images (`hold` at
    strides 1 and `strides`) blended by their weights (`rate_blend`), then the history blended
    in (`taa_blend`). `native`: on a CPU through the TAA handler (`native_taa_blend`: the same
    arithmetic in the same order, the rates' rows blended once per band of rows, a band per
    task), chosen inside the program; derivatives are this function's."""

    def in_jax(pix, w_inner, w_middle, color, valid):
        inner, middle, outer = (hold(pix, s) for s in (1, *strides))
        shaded = rate_blend(inner, middle, outer, w_inner, w_middle)
        return _taa_blend(shaded, color, valid, alpha=alpha, gamma=gamma)

    args = (pix, w_inner, w_middle, history.color, history.valid)
    if not native:
        return in_jax(*args)
    on_cpu = functools.partial(native_taa_blend, strides=strides, alpha=alpha, gamma=gamma)
    return on_platforms(in_jax, cpu=on_cpu)(*args)


def _taa_blend(current, color, valid, *, alpha: float, gamma: float):
    mean, std = _neighbourhood(current)
    lo = jnp.minimum(mean - gamma * std, current)
    hi = jnp.maximum(mean + gamma * std, current)
    clipped = jnp.clip(color, lo, hi)
    blended = alpha * current + (1.0 - alpha) * clipped
    return jnp.where(valid[..., None], blended, current)


def _block_any(mask: Bool[Array, "E H W"], stride: int) -> Bool[Array, "E H W"]:
    """Per pixel: whether any pixel of its stride×stride block (blocks from the top-left) is
    set in `mask`."""
    if stride == 1:
        return mask
    e, h, w = mask.shape
    hp, wp = -(-h // stride) * stride, -(-w // stride) * stride
    padded = jnp.pad(mask, ((0, 0), (0, hp - h), (0, wp - w)))
    blocks = padded.reshape(e, hp // stride, stride, wp // stride, stride).any(axis=(2, 4))
    return jnp.repeat(jnp.repeat(blocks, stride, axis=1), stride, axis=2)[:, :h, :w]


def _top_left(h: int, w: int, stride: int) -> Bool[Array, "H W"]:
    y = jnp.arange(h)[:, None]
    x = jnp.arange(w)[None, :]
    return (y % stride == 0) & (x % stride == 0)


def hold(pix: Float[Array, "E H W 3"], stride: int) -> Float[Array, "E H W 3"]:
    """Coarse pixel shading's reconstruction: every pixel shows its stride×stride block's
    top-left pixel. `stride` 1: `pix`."""
    if stride == 1:
        return pix
    _, h, w, _ = pix.shape
    rows = (jnp.arange(h) // stride) * stride
    cols = (jnp.arange(w) // stride) * stride
    return pix[:, rows][:, :, cols]


def patney_stereo(
    method: Patney2016, inputs: FrameInputs, history: TaaHistory, *, options: FrameOptions
) -> tuple[FoveatedOutputs, Int[Array, ""], TaaHistory]:
    """One stereo frame of Patney et al. 2016 (`Patney2016`) from the previous frame's
    `history`: (the frame's outputs, the pixels that blended a history, this frame's history).
    Pure; jit with `options` (the `FrameOptions`: its spp, jitter, config and diagnostics)
    static."""
    scene, bvh, rig, head_pose, gaze, key, foveation, *_ = inputs  # no fidelity tables
    spp, jitter, config = options.spp, options.jitter, options.config
    diagnostics = diagnostics_tuple(options.diagnostics, "patney_stereo")
    from ...render.internal import integrator_plan

    native = integrator_plan(config).cpu  # the history blend and the pre-filters natively on a CPU
    cameras = rig.eye_cameras(head_pose)
    h, w = rig.eye_height, rig.eye_width
    ecc = eccentricities(cameras, gaze, foveation)
    radii = (foveation.fovea_deg, foveation.periphery_deg)
    strides = (1, *method.strides)
    # Where each shading rate shows (its radius plus the blend; the outer rate everywhere):
    # the top-left pixel of each of its blocks there is traced. The outer rate's blocks all
    # show, so its top-lefts are taken as they are: the block reduction of a constant mask
    # would be folded by XLA at compile time (seconds per megapixel).
    shown = [ecc <= r + method.blend_deg for r in radii]
    trace_pixel = jnp.broadcast_to(_top_left(h, w, strides[-1])[None], ecc.shape)
    for stride, where in zip(strides[:-1], shown, strict=True):
        trace_pixel = trace_pixel | (_block_any(where, stride) & _top_left(h, w, stride)[None])
    pixels = trace_pixels(
        scene, bvh, cameras, key, ecc, trace_pixel, foveation=foveation, spp=spp, jitter=jitter, config=config
    )
    w_inner, w_middle = layer_weights(ecc, radii, method.blend_deg)
    accumulated = rates_and_history(
        pixels.prefill,
        w_inner,
        w_middle,
        history,
        strides=method.strides,
        alpha=method.taa_alpha,
        gamma=method.clip_gamma,
        native=native,
    )
    # The pre-filter per shading rate (σ grows with the block size), shown where that rate is.
    image = prefilter_and_blend(
        accumulated,
        w_inner,
        w_middle,
        (method.blur_per_stride * method.strides[0], method.blur_per_stride * method.strides[1]),
        window_per_sigma=method.window_per_sigma,
        max_gain=method.max_gain,
        native=native,
    )
    reused = jnp.sum(history.valid, dtype=jnp.int32)
    outputs = pixels.outputs(image, diagnostics)
    return outputs, reused, TaaHistory(accumulated, jnp.ones_like(history.valid))
