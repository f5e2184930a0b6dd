"""Guenter et al. 2012's frame: three nested layers at decreasing resolution, magnified and
blended (see `Guenter2012` for the method and its parameters). Stateless; one jitted program
per configuration, gaze, head pose, key and the layer radii (the fovea and periphery
thresholds) traced."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ...native.internal import on_platforms
from .._frame import FoveatedOutputs, FrameOptions, diagnostics_tuple, eccentricities
from .._native import native_layer_blend
from ._base import FrameInputs
from ._catalog import Guenter2012
from ._sparse import side_by_side, trace_pixels


def _on_grid(h: int, w: int, stride: int) -> Bool[Array, "H W"]:
    y = jnp.arange(h)[:, None]
    x = jnp.arange(w)[None, :]
    return (y % stride == 0) & (x % stride == 0)


def _dilate(mask: Bool[Array, "E H W"], radius: int) -> Bool[Array, "E H W"]:
    """Every pixel within `radius` pixels (a square) of a pixel of `mask` (separable max)."""
    if radius == 0:
        return mask
    _, h, w = mask.shape
    out = mask
    padded = jnp.pad(out, ((0, 0), (radius, radius), (0, 0)))
    out = jnp.any(jnp.stack([padded[:, k : k + h] for k in range(2 * radius + 1)]), axis=0)
    padded = jnp.pad(out, ((0, 0), (0, 0), (radius, radius)))
    return jnp.any(jnp.stack([padded[:, :, k : k + w] for k in range(2 * radius + 1)]), axis=0)


def magnify(pix: Float[Array, "E H W 3"], stride: int) -> Float[Array, "E H W 3"]:
    """A layer held at the pixels of a grid of `stride` (rows and columns divisible by it)
    magnified to every pixel by bilinear interpolation between the pixel centres of the grid
    (beyond the last grid row or column: that row's or column's value). `stride` 1: `pix`."""
    if stride == 1:
        return pix
    _, h, w, _ = pix.shape
    grid = pix[:, ::stride, ::stride]  # (E, Hg, Wg, 3)

    # Row k reads grid rows k // stride and the one after (clamped): each grid row repeated
    # `stride` times, not a gather (XLA:CPU runs a gather fused into the frame's last loop
    # element by element).
    fy = _fraction(h, stride)
    fx = _fraction(w, stride)
    below = _repeat(grid, _next(grid, 1), stride, h, fy, axis=1)
    return _repeat(below, _next(below, 2), stride, w, fx, axis=2)


def _fraction(n: int, stride: int):
    g = jnp.arange(n, dtype=jnp.float32) / stride
    return g - jnp.floor(g)


def _next(grid, axis: int):
    """`grid` one row (`axis` 1) or column (`axis` 2) on, the last repeated."""
    last = jax.lax.slice_in_dim(grid, grid.shape[axis] - 1, grid.shape[axis], axis=axis)
    return jnp.concatenate([jax.lax.slice_in_dim(grid, 1, grid.shape[axis], axis=axis), last], axis=axis)


def _repeat(grid, following, stride: int, n: int, f, axis: int):
    """Each grid row (or column) `stride` times, cut to `n`, blended towards the next by `f`."""
    a = jax.lax.slice_in_dim(jnp.repeat(grid, stride, axis=axis), 0, n, axis=axis)
    b = jax.lax.slice_in_dim(jnp.repeat(following, stride, axis=axis), 0, n, axis=axis)
    shape = [1, 1, 1, 1]
    shape[axis] = n
    f = f.reshape(shape)
    return a * (1 - f) + b * f


def _smoothstep(t):
    t = jnp.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t)


def layer_weights(ecc: Float[Array, "E H W"], radii, blend_deg: float):
    """Per pixel the weight of the finer layer at each of the two layer edges (1 within a
    layer's radius, falling to 0 over `blend_deg` beyond it)."""
    return [1.0 - _smoothstep((ecc - r) / blend_deg) for r in radii]


def composite(
    pix: Float[Array, "2 H W 3"],
    ecc: Float[Array, "2 H W"],
    radii: Float[Array, "2"],
    *,
    strides: tuple[int, int],
    blend_deg: float,
    native: bool = False,
) -> Float[Array, "H W2 3"]:
    """The three layers from each pixel's mean `pix`: the inner as it is, the middle and outer
    magnified from their grids of `strides`, blended by eccentricity across `blend_deg` beyond
    the inner and middle `radii`; both eyes side by side. `native`: on a CPU through the layers
    handler (`native_layer_blend`: the same arithmetic in the same order, a band of rows per
    task on both cores), chosen inside the program; derivatives are this function's."""

    def in_jax(pix, ecc, radii):
        inner, middle, outer = (magnify(pix, s) for s in (1, *strides))
        w_inner, w_middle = layer_weights(ecc, (radii[0], radii[1]), blend_deg)
        coarse = outer * (1 - w_middle)[..., None] + middle * w_middle[..., None]
        return side_by_side(coarse * (1 - w_inner)[..., None] + inner * w_inner[..., None])

    if not native:
        return in_jax(pix, ecc, radii)
    on_cpu = functools.partial(native_layer_blend, strides=strides, blend_deg=blend_deg)
    return on_platforms(in_jax, cpu=on_cpu)(pix, ecc, radii)


def guenter_stereo(
    method: Guenter2012, inputs: FrameInputs, history: None = None, *, options: FrameOptions
) -> tuple[FoveatedOutputs, Int[Array, ""], None]:
    """One stereo frame of Guenter et al. 2012 (`Guenter2012`): (the frame's outputs, 0 pixels
    reused, no history). Pure; jit with `options`
    (the `FrameOptions`: its spp, jitter, config and diagnostics) static."""
    scene, bvh, rig, head_pose, gaze, key, foveation, *_ = inputs  # no fidelity tables
    spp, jitter, config = options.spp, options.jitter, options.config
    diagnostics = diagnostics_tuple(options.diagnostics, "guenter_stereo")
    cameras = rig.eye_cameras(head_pose)
    h, w = rig.eye_height, rig.eye_width
    ecc = eccentricities(cameras, gaze, foveation)
    radii = (foveation.fovea_deg, foveation.periphery_deg)
    # Where each layer shows (its radius plus the blend beyond it; the outer layer everywhere),
    # and the pixels of its grid its magnification reads there: a grid pixel within one stride.
    strides = (1, *method.strides)
    # The outer layer shows everywhere: its whole grid is traced (as it is, not dilated: XLA
    # would fold the dilation of a constant mask at compile time).
    shown = [ecc <= r + method.blend_deg for r in radii]
    trace_pixel = jnp.broadcast_to(_on_grid(h, w, strides[-1])[None], ecc.shape)
    for stride, where in zip(strides[:-1], shown, strict=True):
        trace_pixel = trace_pixel | (_dilate(where, stride) & _on_grid(h, w, stride)[None])
    pixels = trace_pixels(
        scene, bvh, cameras, key, ecc, trace_pixel, foveation=foveation, spp=spp, jitter=jitter, config=config
    )
    from ...render.internal import integrator_plan

    native = integrator_plan(config).cpu  # the layers blended natively on a CPU
    image = composite(
        pixels.prefill,
        ecc,
        jnp.stack(radii),
        strides=method.strides,
        blend_deg=method.blend_deg,
        native=native,
    )
    outputs = pixels.outputs(image, diagnostics)
    return outputs, jnp.zeros((), jnp.int32), None
