"""Weier et al. 2016's frame: sparse tracing by eccentricity plus reprojection of the previous
frame's shaded samples (see `Weier2016` for the method and its parameters).

One jitted program per configuration; gaze, head pose, key, the fovea threshold and the
history are traced. The history is explicit: `weier_stereo` takes the previous frame's
`WeierHistory` and returns this frame's; `empty_history` is the reset (every pixel without a
sample, so the next frame traces them all: the full frame).
"""

from __future__ import annotations

from typing import NamedTuple, cast

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from .._frame import SAMPLING_STREAM, FoveatedOutputs, FrameOptions, diagnostics_tuple, eccentricities
from ._base import FrameInputs
from ._catalog import Weier2016
from ._sparse import side_by_side, trace_pixels

# A ray that misses keeps a point this many scene sizes along it: reprojected, it moves with
# the view's rotation only (the sky), never with its translation (float32 keeps the direction
# to ~1e-7 of that length).
MISS_DISTANCE = 1e3


class WeierHistory(NamedTuple):
    """Per eye and pixel: the shaded colour shown, the world-space point it came from and
    whether the pixel holds a sample (False everywhere after a reset)."""

    color: Float[Array, "2 H W 3"]
    point: Float[Array, "2 H W 3"]
    valid: Bool[Array, "2 H W"]


def empty_history(h: int, w: int) -> WeierHistory:
    """The reset: no pixel holds a sample."""
    return WeierHistory(
        jnp.zeros((2, h, w, 3), jnp.float32), jnp.zeros((2, h, w, 3), jnp.float32), jnp.zeros((2, h, w), bool)
    )


class Reprojected(NamedTuple):
    """The history forward-projected into this frame's cameras: per pixel the nearest sample
    that landed in it (colour, point, depth along the view axis) and whether one did."""

    color: Float[Array, "2 H W 3"]
    point: Float[Array, "2 H W 3"]
    depth: Float[Array, "2 H W"]
    landed: Bool[Array, "2 H W"]


def _reproject_eye(camera, color, point, valid, *, h: int, w: int):
    """One eye: every valid sample's point projected to a pixel; the nearest per pixel wins (a
    z-buffer by scatter-min, then the lowest source index among equal depths, so the result
    does not depend on the scatter's order)."""
    xy, depth = camera.project(point.reshape(-1, 3))
    col, row = jnp.floor(xy[:, 0]), jnp.floor(xy[:, 1])
    ok = valid.reshape(-1) & (depth > 0) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
    ok = ok & jnp.isfinite(depth)
    dump = h * w  # one extra entry that the samples landing nowhere write to
    target = jnp.where(ok, row.astype(jnp.int32) * w + col.astype(jnp.int32), dump)
    zbuf = jnp.full(h * w + 1, jnp.inf, jnp.float32).at[target].min(jnp.where(ok, depth, jnp.inf))
    winner = ok & (depth == zbuf[target])
    source = jnp.arange(h * w, dtype=jnp.int32)
    big = jnp.int32(h * w)
    pick = jnp.full(h * w + 1, big, jnp.int32).at[jnp.where(winner, target, dump)].min(source)[: h * w]
    landed = pick < big
    pick = jnp.minimum(pick, h * w - 1)
    return (
        color.reshape(-1, 3)[pick].reshape(h, w, 3),
        point.reshape(-1, 3)[pick].reshape(h, w, 3),
        jnp.where(landed, zbuf[: h * w], jnp.inf).reshape(h, w),
        landed.reshape(h, w),
    )


def reproject(history: WeierHistory, cameras, *, h: int, w: int) -> Reprojected:
    """The history in this frame's cameras (`_reproject_eye` per eye)."""
    parts = [
        _reproject_eye(cam, history.color[i], history.point[i], history.valid[i], h=h, w=w)
        for i, cam in enumerate(cameras)
    ]
    return Reprojected(*(jnp.stack(p) for p in zip(*parts, strict=True)))


def occluded_leaks(depth: Float[Array, "2 H W"], tolerance: float) -> Bool[Array, "2 H W"]:
    """Reprojected samples farther than (1 + tolerance) times the nearest reprojected sample of
    their 3×3 neighbourhood: background seen through a gap that a nearer surface's samples left
    (they would smear the background over the surface). Pixels without a sample have depth inf
    and never count as nearest."""
    # Made once: fused into the nine taps' minimum, the padding is evaluated per tap.
    padded = jax.lax.optimization_barrier(jnp.pad(depth, ((0, 0), (1, 1), (1, 1)), constant_values=jnp.inf))
    h, w = depth.shape[1:]
    nearest = depth
    for dy in range(3):
        for dx in range(3):
            nearest = jnp.minimum(nearest, padded[:, dy : dy + h, dx : dx + w])
    return jnp.isfinite(depth) & (depth > (1.0 + tolerance) * nearest)


def weier_stereo(
    method: Weier2016, inputs: FrameInputs, history: WeierHistory, *, options: FrameOptions
) -> tuple[FoveatedOutputs, Int[Array, ""], WeierHistory]:
    """One stereo frame of Weier et al. 2016 (`Weier2016`) from the previous frame's `history`:
    (the frame's outputs, the pixels shown from the history, this frame's history). Pure; jit
    with `options` (the `FrameOptions`: its spp, jitter, config and diagnostics) static."""
    scene, bvh, rig, head_pose, gaze, key, foveation, *_ = inputs  # no fidelity tables
    spp, jitter, config = options.spp, options.jitter, options.config
    diagnostics = diagnostics_tuple(options.diagnostics, "weier_stereo")
    cameras = rig.eye_cameras(head_pose)
    h, w = rig.eye_height, rig.eye_width
    ecc = eccentricities(cameras, gaze, foveation)
    back = reproject(history, cameras, h=h, w=w)
    usable = back.landed & ~occluded_leaks(back.depth, method.retrace_tolerance)
    keys = jax.random.split(jax.random.fold_in(key, SAMPLING_STREAM), 2)
    draws = jnp.stack([jax.random.uniform(keys[i], (h, w), jnp.float32) for i in range(2)])
    refresh = draws < foveation.probability(ecc)  # 1 in the fovea: always traced there
    trace_pixel = refresh | ~usable
    pixels = trace_pixels(
        scene,
        bvh,
        cameras,
        key,
        ecc,
        trace_pixel,
        foveation=foveation,
        spp=spp,
        jitter=jitter,
        config=config,
        first_points=MISS_DISTANCE,  # each pixel's point: sub-sample 0's hit
    )
    n, points = pixels.n, cast(Array, pixels.first_points)
    fresh = n > 0
    # Every pixel is traced or holds a usable reprojected sample: nothing to fill.
    eyes = jnp.where(fresh[..., None], pixels.prefill, back.color)
    history = WeierHistory(eyes, jnp.where(fresh[..., None], points, back.point), fresh | usable)
    outputs = pixels.outputs(side_by_side(eyes), diagnostics)
    reused = jnp.sum(~fresh, dtype=jnp.int32)
    return outputs, reused, history
