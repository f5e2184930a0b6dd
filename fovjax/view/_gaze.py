"""Both eyes' gaze from one eye's: the mouse points with one eye, the other eye looks at the
same scene point.

The ray from the pointing eye through the mouse position is traced to the nearest surface (the
fixated point; with nothing hit, a point `miss_distance` scene units along the ray) and that
point is projected into the other eye's display. Both eye cameras come from the rig and head
pose, so toe-out, the interpupillary distance and the projection offsets are all taken into
account."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..trace import closest_hit


def _binocular(bvh, rig, head_pose, eye, xy, miss_distance):
    """(2, 2) gaze, (left, right) rows, normalised display coordinates, clipped to [0, 1]; and
    the distance to the fixated point. `eye` 0 (left) or 1 (right) is the pointing eye."""
    left, right = rig.eye_cameras(head_pose)
    size = jnp.array([rig.eye_width, rig.eye_height], jnp.float32)
    pixel = xy * size
    d_left, d_right = left.ray_directions(pixel), right.ray_directions(pixel)
    pointing = eye == 0
    origin = jnp.where(pointing, left.position, right.position)
    direction = jnp.where(pointing, d_left, d_right)
    hit = closest_hit(bvh, origin, direction)
    t = jnp.where(jnp.isfinite(hit.t), hit.t, miss_distance)
    point = origin + t * direction
    other_xy = jnp.where(pointing, right.project(point)[0], left.project(point)[0]) / size
    other_xy = jnp.clip(other_xy, 0.0, 1.0)
    gaze = jnp.where(pointing, jnp.stack([xy, other_xy]), jnp.stack([other_xy, xy]))
    return gaze, t


_binocular_jit = jax.jit(_binocular)


def binocular_gaze(bvh, rig, head_pose, eye: str, xy, *, miss_distance: float = 10.0) -> np.ndarray:
    """((lx, ly), (rx, ry)) for a gaze `xy` in the `eye` ("left"/"right") display: the other
    eye's gaze looks at the scene point the pointing eye sees there. Compiled once per rig
    resolution and BVH shape; head pose, eye and position are traced."""
    if eye not in ("left", "right"):
        raise ValueError(f"binocular_gaze: eye must be 'left' or 'right', got {eye!r}")
    xy = np.asarray(xy, np.float32)
    if xy.shape != (2,) or not np.isfinite(xy).all():
        raise ValueError(f"binocular_gaze: xy must be two finite numbers, got {xy!r}")
    pose = np.asarray(head_pose if head_pose is not None else (0.0, 0.0, 0.0), np.float32)
    gaze, _ = _binocular_jit(
        bvh, rig, pose, np.int32(0 if eye == "left" else 1), xy, np.float32(miss_distance)
    )
    return np.asarray(gaze)
