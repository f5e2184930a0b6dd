"""The two eyes of a stereo HMD as plain numbers: rays through display positions, projections of
points, and the angle between two gaze positions in degrees.

Gaze is given in each eye's own display (`GazeSample`), and the eyes' displays are not parallel
on every headset: the thesis's rig turns each eye camera 13° outwards, so a far point straight
ahead is at x = 0.615 in the left eye's display and 0.385 in the right's. Whatever relates the
two eyes' gaze (the one-eye fallback, a synthetic observer, calibration targets) goes through
this geometry.

`RigGeometry` holds the same numbers as `fovjax.render.StereoRig` (`RigGeometry.from_rig`
reads them) and uses the same pinhole model as the renderer's `Camera`, in the head frame
(x right, y up, z backward; origin halfway between the eyes): the head pose and the rig's
placement in the world turn both eyes alike, so they do not enter here. Display positions are
normalised (x right, y down, (0, 0) the top-left corner, (1, 1) the bottom-right).

The *cyclopean display* is a pinhole between the eyes looking straight ahead of the head, with
an eye's field of view and aspect, no toe-out and no offset: a position on it names a direction
from the head, which `fixation` turns into each eye's display position.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

EYES = ("left", "right")
# The thesis's NVIS SX111 set-up (section 4.3), as `fovjax.render.StereoRig`'s defaults.
THESIS_EYE_SIZE = (1280, 1024)
THESIS_FOV_DEG = 90.0
THESIS_TOE_OUT_DEG = 13.0
THESIS_IPD_M = 0.064


def eye_index(eye) -> int:
    """0 for "left" (or 0), 1 for "right" (or 1)."""
    if eye in ("left", 0):
        return 0
    if eye in ("right", 1):
        return 1
    raise ValueError(f"eye must be 'left' or 'right', got {eye!r}")


def _rot_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _finite(value, name: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"RigGeometry: {name} must be a number, got {value!r}") from None
    if not math.isfinite(number):
        raise ValueError(f"RigGeometry: {name} must be finite, got {value!r}")
    return number


@dataclasses.dataclass(frozen=True)
class RigGeometry:
    """Both eyes of a stereo rig: resolution, field of view, toe-out, eye distance, offsets.

    The defaults are the thesis's rig (`fovjax.render.StereoRig`'s defaults: 1280 x 1024 per
    eye, 90° horizontal field of view, each eye turned 13° outwards, 64 mm apart).

    Args:
        eye_width: pixels per eye, horizontally (with `eye_height`: the display's aspect).
        eye_height: pixels per eye, vertically.
        fov_deg: each eye's field of view in degrees along `fov_axis`.
        fov_axis: "horizontal" or "vertical".
        toe_out_deg: each eye turned this far outwards about the head's up axis (degrees).
        ipd: the distance between the eyes, in the units of every distance given to the
            methods (scene units: metres for the built-in scenes).
        offsets: per-eye projection-centre shift ((x, y) left, (x, y) right), in
            `fovjax.Camera.offset` units (fractions of the image plane's half-extent).

    Raises:
        ValueError: a resolution that is not a positive integer, a field of view outside
            (0°, 180°), an unknown axis, a non-finite number or a negative `ipd`.
    """

    eye_width: int = THESIS_EYE_SIZE[0]
    eye_height: int = THESIS_EYE_SIZE[1]
    fov_deg: float = THESIS_FOV_DEG
    fov_axis: str = "horizontal"
    toe_out_deg: float = THESIS_TOE_OUT_DEG
    ipd: float = THESIS_IPD_M
    offsets: tuple[tuple[float, float], tuple[float, float]] | Sequence[Sequence[float]] | np.ndarray = (
        (0.0, 0.0),
        (0.0, 0.0),
    )

    def __post_init__(self):
        for name in ("eye_width", "eye_height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0:
                raise ValueError(f"RigGeometry: {name} must be a positive integer, got {value!r}")
            object.__setattr__(self, name, int(value))
        if self.fov_axis not in ("horizontal", "vertical"):
            raise ValueError(
                f"RigGeometry: fov_axis must be 'horizontal' or 'vertical', got {self.fov_axis!r}"
            )
        fov = _finite(self.fov_deg, "fov_deg")
        if not 0.0 < fov < 180.0:
            raise ValueError(f"RigGeometry: fov_deg must be in (0, 180), got {self.fov_deg!r}")
        ipd = _finite(self.ipd, "ipd")
        if ipd < 0:
            raise ValueError(f"RigGeometry: ipd must be >= 0, got {self.ipd!r}")
        offsets = np.asarray(self.offsets, dtype=float)
        if offsets.shape != (2, 2) or not np.isfinite(offsets).all():
            raise ValueError(
                f"RigGeometry: offsets must be ((x, y) left, (x, y) right), finite, got {self.offsets!r}"
            )
        object.__setattr__(self, "fov_deg", fov)
        object.__setattr__(self, "toe_out_deg", _finite(self.toe_out_deg, "toe_out_deg"))
        object.__setattr__(self, "ipd", ipd)
        object.__setattr__(self, "offsets", tuple((float(x), float(y)) for x, y in offsets))

    @classmethod
    def from_rig(cls, rig) -> RigGeometry:
        """The geometry of a `fovjax.render.StereoRig` (or anything with its fields:
        `eye_width`, `eye_height`, `fov_deg`, `fov_axis`, `toe_out_deg`, `ipd`, `offsets`).

        Raises:
            ValueError: `rig` lacks one of those fields (naming it) or holds a bad value.
        """
        names = ("eye_width", "eye_height", "fov_deg", "fov_axis", "toe_out_deg", "ipd", "offsets")
        missing = [name for name in names if not hasattr(rig, name)]
        if missing:
            raise ValueError(
                f"RigGeometry.from_rig: expected a fovjax.render.StereoRig, got {type(rig).__name__} "
                f"without {', '.join(missing)}"
            )
        return cls(
            eye_width=rig.eye_width,
            eye_height=rig.eye_height,
            fov_deg=float(rig.fov_deg),
            fov_axis=rig.fov_axis,
            toe_out_deg=float(rig.toe_out_deg),
            ipd=float(rig.ipd),
            offsets=tuple(tuple(float(v) for v in row) for row in np.asarray(rig.offsets)),
        )

    def matches(self, other: RigGeometry, rel: float = 1e-5) -> bool:
        """Whether `other` relates display positions as this rig does: the same aspect, field of
        view, toe-out, eye distance and offsets to a relative `rel` (a `StereoRig`'s float32
        fields read back differ from the decimals they were given in). The resolution itself
        does not count: positions are normalised."""
        if self.fov_axis != other.fov_axis:
            return False
        mine = [
            self.eye_width / self.eye_height,
            self.fov_deg,
            self.toe_out_deg,
            self.ipd,
            *np.ravel(self.offsets),
        ]
        theirs = [
            other.eye_width / other.eye_height,
            other.fov_deg,
            other.toe_out_deg,
            other.ipd,
            *np.ravel(other.offsets),
        ]
        return bool(np.allclose(mine, theirs, rtol=rel, atol=rel))

    # -- the pinhole model ----------------------------------------------------------------
    @property
    def tan_half_fov(self) -> tuple[float, float]:
        """(horizontal, vertical) tangent of half an eye's field of view."""
        tan = math.tan(math.radians(self.fov_deg) / 2.0)
        aspect = self.eye_width / self.eye_height
        return (tan, tan / aspect) if self.fov_axis == "horizontal" else (tan * aspect, tan)

    @property
    def hfov_deg(self) -> float:
        """Each eye's horizontal field of view in degrees."""
        return 2.0 * math.degrees(math.atan(self.tan_half_fov[0]))

    @property
    def vfov_deg(self) -> float:
        """Each eye's vertical field of view in degrees."""
        return 2.0 * math.degrees(math.atan(self.tan_half_fov[1]))

    def eye_position(self, eye) -> np.ndarray:
        """The eye's centre in the head frame (x right; the eyes' midpoint is the origin)."""
        side = -1.0 if eye_index(eye) == 0 else 1.0
        return np.array([side * self.ipd / 2.0, 0.0, 0.0])

    def eye_rotation(self, eye) -> np.ndarray:
        """Head-from-eye rotation (columns: the eye's right, up, backward): the left eye turned
        left by `toe_out_deg`, the right eye right."""
        side = -1.0 if eye_index(eye) == 0 else 1.0
        return _rot_y(-side * math.radians(self.toe_out_deg))

    def _camera_ray(self, xy, offset) -> np.ndarray:
        xy = np.asarray(xy, dtype=float)
        if xy.shape[-1:] != (2,):
            raise ValueError(f"RigGeometry: display positions must be (..., 2) (x, y), got shape {xy.shape}")
        tan_x, tan_y = self.tan_half_fov
        sx = (2.0 * xy[..., 0] - 1.0 + offset[0]) * tan_x
        sy = (1.0 - 2.0 * xy[..., 1] + offset[1]) * tan_y
        d = np.stack([sx, sy, -np.ones_like(sx)], axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def _camera_project(self, pc: np.ndarray, offset) -> np.ndarray:
        tan_x, tan_y = self.tan_half_fov
        depth = -pc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = 0.5 * (pc[..., 0] / depth / tan_x - offset[0] + 1.0)
            y = 0.5 * (1.0 + offset[1] - pc[..., 1] / depth / tan_y)
        xy = np.stack([x, y], axis=-1)
        return np.where((depth > 0)[..., None], xy, np.nan)

    def ray(self, eye, xy) -> np.ndarray:
        """Unit directions in the head frame through display positions `xy` (..., 2) of `eye`."""
        i = eye_index(eye)
        return self._camera_ray(xy, self.offsets[i]) @ self.eye_rotation(i).T

    def project(self, eye, points, *, at_infinity: bool = False) -> np.ndarray:
        """Display positions (..., 2) in `eye` of head-frame `points` (..., 3); with
        `at_infinity` the points are directions (points infinitely far that way). NaN for a
        point behind the eye."""
        i = eye_index(eye)
        points = np.asarray(points, dtype=float)
        if points.shape[-1:] != (3,):
            raise ValueError(f"RigGeometry.project: points must be (..., 3), got shape {points.shape}")
        relative = points if at_infinity else points - self.eye_position(i)
        return self._camera_project(relative @ self.eye_rotation(i), self.offsets[i])

    def angle_deg(self, eye, a, b) -> np.ndarray:
        """Degrees between the rays of `eye` through display positions `a` and `b` (each
        (..., 2), broadcasting): the exact-angle eccentricity the renderer uses
        (`fovjax.foveate.Foveation(eccentricity="angle")`)."""
        i = eye_index(eye)
        da = self._camera_ray(a, self.offsets[i])
        db = self._camera_ray(b, self.offsets[i])
        cross = np.linalg.norm(np.cross(da, db), axis=-1)
        return np.asarray(np.degrees(np.arctan2(cross, np.sum(da * db, axis=-1))))

    def transfer(self, xy, from_eye, distance: float = math.inf) -> np.ndarray:
        """The position in the other eye's display of the point `distance` along `from_eye`'s
        ray through `xy` (infinity: the direction alone, both eyes looking the same way)."""
        i = eye_index(from_eye)
        distance = _distance(distance, "RigGeometry.transfer")
        d = self.ray(i, xy)
        if math.isinf(distance):
            return self.project(1 - i, d, at_infinity=True)
        return self.project(1 - i, self.eye_position(i) + distance * d)

    def cyclopean_ray(self, xy) -> np.ndarray:
        """Unit directions in the head frame through positions `xy` (..., 2) of the cyclopean
        display (module docstring)."""
        return self._camera_ray(xy, (0.0, 0.0))

    def fixation(self, xy, distance: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
        """(left, right) display positions of the point `distance` from the eyes' midpoint
        along the cyclopean ray through `xy` (infinity: that direction): where each eye's
        gaze lands when both look at that point."""
        distance = _distance(distance, "RigGeometry.fixation")
        d = self.cyclopean_ray(xy)
        if math.isinf(distance):
            return self.project(0, d, at_infinity=True), self.project(1, d, at_infinity=True)
        point = distance * d
        return self.project(0, point), self.project(1, point)


def _distance(distance, where: str) -> float:
    try:
        value = float(distance)
    except (TypeError, ValueError):
        value = math.nan
    if not value > 0:
        raise ValueError(f"{where}: distance must be > 0 (math.inf: infinitely far), got {distance!r}")
    return value


def as_pair(xy: Sequence[float] | np.ndarray, where: str) -> tuple[float, float]:
    """Two finite floats from `xy`, or a ValueError naming `where` and the value."""
    try:
        x, y = (float(v) for v in xy)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: expected a display position (x, y), got {xy!r}") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ValueError(f"{where}: expected a finite display position (x, y), got {xy!r}")
    return x, y
