"""Eccentricity of every pixel from an eye's gaze point."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TypeAlias

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Real

from ..scene import Camera
from ._config import Foveation

# One eye's gaze point in normalised display coordinates (x right, y down, [0, 1]).
PointLike: TypeAlias = Real[ArrayLike, " 2"] | Sequence[float]


def gaze_pixel(camera: Camera, gaze_xy: PointLike) -> Float[Array, " 2"]:
    """Normalised display coordinates (x right, y down, [0, 1]) to continuous pixel coordinates."""
    return jnp.asarray(gaze_xy, jnp.float32) * jnp.array([camera.width, camera.height], jnp.float32)


def eccentricity_angle(
    camera: Camera, gaze_xy: PointLike, pixel_xy: Real[ArrayLike, "*batch 2"]
) -> Float[Array, "*batch"]:
    """Degrees between the ray through each pixel position and the ray through the gaze point,
    both through the eye's own camera model (projection offset included). atan2 of the cross
    and dot products stays accurate near 0, where acos loses ~0.03° in float32."""
    pixel_xy = jnp.asarray(pixel_xy)
    return _angle_to_gaze(camera, gaze_xy, pixel_xy[..., 0], pixel_xy[..., 1])


def _angle_to_gaze(camera: Camera, gaze_xy, x, y) -> Float[Array, "..."]:
    """`eccentricity_angle` of pixel coordinates `x` and `y` (broadcasting against each other).
    The angle between two rays does not change under the camera's rotation, so it is taken
    between their image-plane vectors (sx, sy, -1) and (gx, gy, -1), neither normalised (atan2
    of cross and dot does not need it): fewer roundings than in world space, and a few
    operations per pixel, where the rotated, normalised directions cost the frame a pass over
    the screen each."""
    gaze = gaze_pixel(camera, gaze_xy)
    gx, gy = camera.image_plane(gaze[0], gaze[1])
    sx, sy = camera.image_plane(x, y)
    # (sx, sy, -1) × (gx, gy, -1) and their dot product, written out: jnp.cross, norm and a
    # sum over a length-3 axis run several times slower on XLA:CPU over a screen of pixels.
    c0 = gy - sy
    c1 = sx - gx
    c2 = sx * gy - sy * gx
    cross = jnp.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    return jnp.rad2deg(_atan2_nonnegative(cross, sx * gx + sy * gy + 1.0))


def _atan2_nonnegative(y, x):
    """atan2(y, x) for y ≥ 0, as accurate as `jnp.arctan2` (2.7e-7 rad at most against float64,
    2.2e-7 relative near 0, over 1.3M random pairs), from Cephes' `atanf`: the ratio of the
    smaller to the larger magnitude, above tan(π/8) moved by π/4, a degree-9 odd polynomial,
    then the octant. XLA:CPU's own atan2 is an order of magnitude slower over an eye's
    pixels."""
    ax = jnp.abs(x)
    big, small = jnp.maximum(ax, y), jnp.minimum(ax, y)
    a = small / jnp.where(big > 0, big, 1.0)  # [0, 1]
    shifted = a > np.float32(0.41421356237309503)  # tan(π/8)
    t = jnp.where(shifted, (a - 1.0) / (a + 1.0), a)
    z = t * t
    p = ((8.05374449538e-2 * z - 1.38776856032e-1) * z + 1.99777106478e-1) * z - 3.33329491539e-1
    r = p * z * t + t
    r = jnp.where(shifted, r + np.float32(np.pi / 4), r)
    r = jnp.where(y > ax, np.float32(np.pi / 2) - r, r)
    return jnp.where(x < 0, np.float32(np.pi) - r, r)


def display_pixel_pitch_mm(camera: Camera, eye_display_mm: float) -> Float[Array, ""]:
    """Pixel pitch of a flat display at distance D that fills the camera's horizontal field of
    view: width = 2·D·tan(hfov/2), pitch = width / pixels."""
    tan_half_v = jnp.tan(jnp.deg2rad(camera.vfov_deg) / 2)
    tan_half_h = tan_half_v * camera.width / camera.height
    return 2 * eye_display_mm * tan_half_h / camera.width


# The thesis's HMD, the NVIS SX111 (thesis 2.1.3): 1280 x 1024 per display, 64° vertical.
SX111_VFOV_DEG = 64.0
SX111_ROWS = 1024


def thesis_pixel_pitch_mm(
    rows: int = SX111_ROWS, display_vfov_deg: float = SX111_VFOV_DEG, eye_display_mm: float = 24.0
) -> float:
    """The pixel pitch under which the planar formula (thesis eq. 4-5, D = `eye_display_mm`)
    reproduces the region sizes behind the thesis's Table 2: each pixel subtends the display's
    mean angular pixel size, `display_vfov_deg / rows` (the SX111: 64° / 1024 = 1/16°, i.e.
    16 pixels per degree), at D: pitch = D·tan(vfov / rows) (0.02618 mm for the SX111).

    A flat display at D spanning the same 64° would have a pitch of 2·D·tan(32°)/1024 =
    0.0293 mm, i.e. 14.3 pixels per degree at its centre; the thesis's regions are larger,
    see docs/thesis.md, "Table 2: what its ray counts imply"."""
    return float(eye_display_mm * np.tan(np.deg2rad(display_vfov_deg / rows)))


def eccentricity_planar(
    camera: Camera,
    gaze_xy: PointLike,
    pixel_xy: Real[ArrayLike, "*batch 2"],
    eye_display_mm: float = 24.0,
    pixel_pitch_mm: float | None = None,
) -> Float[Array, "*batch"]:
    """The thesis's eq. 4-5: S = Euclidean distance on the display (mm), V = 2·atan(S / 2D)."""
    pitch = display_pixel_pitch_mm(camera, eye_display_mm) if pixel_pitch_mm is None else pixel_pitch_mm
    s = jnp.linalg.norm(jnp.asarray(pixel_xy) - gaze_pixel(camera, gaze_xy), axis=-1) * pitch
    return jnp.rad2deg(2 * jnp.arctan(s / (2 * eye_display_mm)))


def eccentricity_map(camera: Camera, gaze_xy: PointLike, foveation: Foveation) -> Float[Array, "H W"]:
    """Eccentricity (degrees) of every pixel centre, in the foveation's mode."""
    if foveation.eccentricity == "angle":  # the pixel centres as a row and a column: one fused pass
        x = jnp.arange(camera.width, dtype=jnp.float32)[None, :] + 0.5
        y = jnp.arange(camera.height, dtype=jnp.float32)[:, None] + 0.5
        return jnp.broadcast_to(_angle_to_gaze(camera, gaze_xy, x, y), (camera.height, camera.width))
    pixels = camera.pixel_centres()
    return eccentricity_planar(camera, gaze_xy, pixels, foveation.eye_display_mm, foveation.pixel_pitch_mm)


def full_eccentricity(rig, foveation) -> float:
    """The largest eccentricity (degrees) any pixel of either eye's display can have for any
    gaze on that display -- the fovea that covers the whole screen -- rounded up to 0.1°.
    Eccentricity is measured in the eye's own camera, so the head pose does not matter."""
    corners = ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0))
    worst = 0.0
    for camera in rig.eye_cameras(None):
        for corner in corners:
            worst = max(worst, float(jnp.max(eccentricity_map(camera, jnp.asarray(corner), foveation))))
    return min(180.0, math.ceil(worst * 10.0 + 1e-6) / 10.0)
