"""Default viewpoints for the built-in scenes (and a generic one for loaded scenes)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import SupportsFloat

import numpy as np

from ._cornell import CAMERA_FOV_DEG, CAMERA_POSITION_MM
from ._scene import Scene


@dataclasses.dataclass(frozen=True)
class CameraPose:
    """Where a pinhole camera stands and looks: world-space `position` and `look_at` points,
    an `up` vector, and the vertical field of view in degrees."""

    # Given as any three numbers (tuple, list, array); stored as a tuple of Python floats.
    position: Sequence[SupportsFloat] | np.ndarray
    look_at: Sequence[SupportsFloat] | np.ndarray
    up: Sequence[SupportsFloat] | np.ndarray = (0.0, 1.0, 0.0)
    vfov_deg: float = 60.0

    def __post_init__(self):
        for name in ("position", "look_at", "up"):
            value = np.asarray(getattr(self, name), np.float64)
            if value.shape != (3,) or not np.isfinite(value).all():
                raise ValueError(f"CameraPose.{name} must be 3 finite numbers, got {getattr(self, name)}")
            object.__setattr__(self, name, tuple(float(x) for x in value))
        forward = np.subtract(np.asarray(self.look_at), np.asarray(self.position))
        if np.linalg.norm(forward) == 0:
            raise ValueError("CameraPose: position and look_at coincide")
        if np.linalg.norm(np.cross(forward, np.asarray(self.up))) == 0:
            raise ValueError("CameraPose: up is parallel to the viewing direction")
        if not 0 < self.vfov_deg < 180:
            raise ValueError(f"CameraPose.vfov_deg must be in (0, 180), got {self.vfov_deg}")


def default_camera(scene: Scene | str) -> CameraPose:
    """A sensible viewpoint for a scene (or a built-in scene's name).

    - "atrium": standing in the court near its west end, eye height 1.7 m, looking east along
      the court between the colonnades (the usual Sponza view, as in the thesis's figure 48).
    - "cornell_box": the published camera (278, 273, -800) mm looking along +z, 39.3 degrees
      vertical field of view (focal length 35 mm, film 25 mm), in the scene's units.
    - "spheres": in front of the spheres, slightly above, looking at them.
    - anything else: outside the scene's bounds on the +z side, looking at the bounds' centre
      from far enough that the bounding sphere fits the 60 degree vertical field of view.
    """
    name = scene if isinstance(scene, str) else scene.name
    if name == "atrium":
        return CameraPose(position=(-11.5, 1.7, 0.0), look_at=(10.0, 4.5, 0.0), vfov_deg=60.0)
    if name == "cornell_box":
        scale = 1e-3
        if not isinstance(scene, str) and float(np.max(np.asarray(scene.vertices))) > 100.0:
            scale = 1.0  # built with units="mm"
        position = tuple(c * scale for c in CAMERA_POSITION_MM)
        look_at = (position[0], position[1], 0.0)
        return CameraPose(position=position, look_at=look_at, vfov_deg=CAMERA_FOV_DEG)
    if name == "spheres":
        return CameraPose(position=(0.0, 2.2, 6.5), look_at=(0.0, 0.7, 0.0), vfov_deg=45.0)
    if isinstance(scene, str):
        raise ValueError(f"default_camera: no built-in scene named {scene!r}")
    lo, hi = scene.bounds
    centre = (lo + hi) / 2
    radius = float(np.linalg.norm(hi - lo)) / 2 or 1.0
    distance = radius / np.sin(np.radians(60.0) / 2)
    return CameraPose(
        position=tuple(centre + (0.0, 0.0, hi[2] - centre[2] + distance)), look_at=tuple(centre)
    )
