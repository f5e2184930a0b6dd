"""Eccentricity of every pixel from an eye's gaze point."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._camera import Camera


def gaze_pixel(camera: Camera, gaze_xy: Float[Array, " 2"]) -> Float[Array, " 2"]:
    """Normalised display coordinates (x right, y down, [0, 1]) to continuous pixel coordinates."""
    return jnp.asarray(gaze_xy, jnp.float32) * jnp.array([camera.width, camera.height], jnp.float32)


def eccentricity_angle(camera: Camera, gaze_xy, pixel_xy) -> Float[Array, "..."]:
    """Degrees between the ray through each pixel position and the ray through the gaze point,
    both through the eye's own camera model (projection offset included). atan2 of the cross
    and dot products stays accurate near 0, where acos loses ~0.03° in float32."""
    g = camera.ray_directions(gaze_pixel(camera, gaze_xy))
    d = camera.ray_directions(pixel_xy)
    # Written out per component: jnp.cross, norm and a sum over the length-3 axis run several
    # times slower on XLA:CPU over a screen of pixels (as in Camera.ray_directions).
    d0, d1, d2 = d[..., 0], d[..., 1], d[..., 2]
    c0 = d1 * g[2] - d2 * g[1]
    c1 = d2 * g[0] - d0 * g[2]
    c2 = d0 * g[1] - d1 * g[0]
    cross = jnp.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    return jnp.rad2deg(jnp.arctan2(cross, d0 * g[0] + d1 * g[1] + d2 * g[2]))


def display_pixel_pitch_mm(camera: Camera, eye_display_mm: float) -> Float[Array, ""]:
    """Pixel pitch of a flat display at distance D that fills the camera's horizontal field of
    view: width = 2·D·tan(hfov/2), pitch = width / pixels."""
    tan_half_v = jnp.tan(jnp.deg2rad(camera.vfov_deg) / 2)
    tan_half_h = tan_half_v * camera.width / camera.height
    return 2 * eye_display_mm * tan_half_h / camera.width


def eccentricity_planar(camera: Camera, gaze_xy, pixel_xy, eye_display_mm=24.0, pixel_pitch_mm=None):
    """The thesis's eq. 4-5: S = Euclidean distance on the display (mm), V = 2·atan(S / 2D)."""
    pitch = display_pixel_pitch_mm(camera, eye_display_mm) if pixel_pitch_mm is None else pixel_pitch_mm
    s = jnp.linalg.norm(pixel_xy - gaze_pixel(camera, gaze_xy), axis=-1) * pitch
    return jnp.rad2deg(2 * jnp.arctan(s / (2 * eye_display_mm)))


def eccentricity_map(camera: Camera, gaze_xy, foveation) -> Float[Array, "H W"]:
    """Eccentricity (degrees) of every pixel centre, in the foveation's mode."""
    pixels = camera.pixel_centres()
    if foveation.eccentricity == "angle":
        return eccentricity_angle(camera, gaze_xy, pixels)
    return eccentricity_planar(camera, gaze_xy, pixels, foveation.eye_display_mm, foveation.pixel_pitch_mm)
