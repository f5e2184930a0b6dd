"""From a WebXR frame's views to the `StereoRig` that renders them, and back to the page.

WebXR gives, per display frame, the headset's pose and one view per eye (position, orientation,
projection matrix) in the session's `local` reference space: metres, x right, y up, z backward
(the camera convention of `fovjax.scene.Camera`), its origin where the head was when the session
began. The scene takes that space at its default viewpoint (`origin`, a `CameraPose`), levelled:
the local origin at the viewpoint's position, local -z along the viewpoint's horizontal viewing
direction and local y along its up, so the scene's horizon stays level in the headset.

The rig (`xr_stereo`): the head at the viewer pose, the eyes at the views' midpoint and distance
(`ipd`, `eye_centre`), turned by the symmetric yaw that best matches the views' orientations
(`toe_out_deg`: canted displays), and each eye's frustum the smallest `Camera` frustum (one
vertical field of view and one resolution for both eyes, a principal point per eye: the rig's
`offsets`) that holds that eye's asymmetric projection. Pixels are square and as dense as the
headset's own at the frustum's centre, times `scale`. What the rig cannot express (eyes
displaced off the head's x axis, eye rotations other than a symmetric yaw) is measured
(`position_error_m`, `rotation_error_deg`): the page draws each frame with the rendered eye
cameras (`XRStereo.page_json`), so such a difference never shows as a wrong orientation.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from jaxtyping import ArrayLike, Real

from ..render import StereoRig
from ..scene import CameraPose, look_at_rotation

EYES = ("left", "right")
MAX_XR_EYE_PIXELS = 8192  # per side, as `fovjax view --width/--height`
MAX_POSITION_M = 1.0e4
# The projection's centre and field of view are rounded (degrees, Camera.offset units) so that a
# headset's views give the same rig shape, hence the same compiled program, frame after frame.
FOV_STEP_DEG = 1e-3
OFFSET_STEP = 1e-4


def quaternion_matrix(q) -> np.ndarray:
    """The rotation matrix (3, 3) of a unit quaternion (x, y, z, w), WebXR's order."""
    x, y, z, w = (float(v) for v in q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _rot_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def head_angles(rotation) -> tuple[float, float, float]:
    """(yaw, pitch, roll) in degrees, InertiaCube convention (`fovjax.render.head_rotation`), of
    a head rotation (3, 3) in the camera frame (x right, y up, z backward)."""
    r = np.asarray(rotation, np.float64)
    forward = -r[:, 2]
    yaw = math.atan2(forward[0], -forward[2])
    pitch = math.asin(float(np.clip(forward[1], -1.0, 1.0)))
    rest = (_rot_y(-yaw) @ _rot_x(pitch)).T @ r  # = rot_z(-roll)
    roll = -math.atan2(rest[1, 0], rest[0, 0])
    return math.degrees(yaw), math.degrees(pitch), math.degrees(roll)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle of the rotation between two rotation matrices, degrees."""
    cos = (np.trace(a.T @ b) - 1.0) / 2.0
    return math.degrees(math.acos(float(np.clip(cos, -1.0, 1.0))))


def _vector(value, size: int, name: str, limit: float | None = None) -> np.ndarray:
    array = np.asarray(value, np.float64)
    if array.shape != (size,) or not np.isfinite(array).all():
        raise ValueError(f"{name} must be {size} finite numbers, got {value!r}")
    if limit is not None and np.abs(array).max() > limit:
        raise ValueError(f"{name} must be within ±{limit:g}, got {array.tolist()}")
    return array


def _unit_quaternion(value, name: str) -> np.ndarray:
    q = _vector(value, 4, name)
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > 1e-2:
        raise ValueError(f"{name} must be a unit quaternion (x, y, z, w), got {q.tolist()} (norm {norm:.4g})")
    return q / norm


Vec3Like = Real[ArrayLike, " 3"] | Sequence[float]
QuaternionLike = Real[ArrayLike, " 4"] | Sequence[float]


@dataclasses.dataclass(frozen=True, init=False)
class XRView:
    """One eye's view of a WebXR frame (`XRView`), in the session's `local` reference space.

    Attributes:
        eye: "left" or "right".
        position: (3,) the eye's position, metres.
        orientation: (4,) the eye's orientation, a unit quaternion (x, y, z, w).
        projection: (16,) the projection matrix, column-major as WebXR gives it: a perspective
            frustum (asymmetric allowed, no skew).
        viewport: (width, height) of the eye's viewport in the headset's framebuffer, pixels.

    Raises:
        ValueError: a value that is not what its attribute says, named.
    """

    eye: str
    position: np.ndarray
    orientation: np.ndarray
    projection: np.ndarray
    viewport: tuple[int, int]

    def __init__(
        self,
        eye: str,
        position: Vec3Like,
        orientation: QuaternionLike,
        projection: Real[ArrayLike, " 16"] | Sequence[float],
        viewport: Sequence[int],
    ):
        if eye not in EYES:
            raise ValueError(f"view eye must be 'left' or 'right', got {eye!r}")
        name = f"{eye} view"
        p = _vector(projection, 16, f"{name} projection")
        # Column-major: p[0] = m00, p[5] = m11, p[8] = m02, p[9] = m12, p[11] = m32, p[15] = m33.
        if not (p[0] > 0 and p[5] > 0 and p[11] == -1.0 and p[15] == 0.0):
            raise ValueError(
                f"{name} projection is not a perspective frustum (expected m00 > 0, m11 > 0, m32 = -1, "
                f"m33 = 0), got {p.tolist()}"
            )
        if p[4] != 0.0 or p[1] != 0.0:
            raise ValueError(f"{name} projection has a skew (m01 = {p[4]:g}, m10 = {p[1]:g}): not supported")
        size = tuple(viewport)
        if len(size) != 2 or not all(
            isinstance(v, int | np.integer) and not isinstance(v, bool) and 1 <= v <= 65536 for v in size
        ):
            raise ValueError(
                f"{name} viewport must be (width, height) in pixels, 1 to 65536 each, got {size!r} "
                "(a zero viewport: a mono device, not a headset)"
            )
        object.__setattr__(self, "eye", eye)
        object.__setattr__(self, "position", _vector(position, 3, f"{name} position", MAX_POSITION_M))
        object.__setattr__(self, "orientation", _unit_quaternion(orientation, f"{name} orientation"))
        object.__setattr__(self, "projection", p)
        object.__setattr__(self, "viewport", (int(size[0]), int(size[1])))

    def rotation(self) -> np.ndarray:
        """(3, 3) local-from-eye rotation (columns: right, up, backward)."""
        return quaternion_matrix(self.orientation)

    def tangents(self) -> tuple[float, float, float, float]:
        """The frustum's (left, right, bottom, top) edges as tangents of their angles from the
        eye's -z axis (left and bottom negative for a frustum around the axis)."""
        p = self.projection
        return (
            float((p[8] - 1.0) / p[0]),
            float((p[8] + 1.0) / p[0]),
            float((p[9] - 1.0) / p[5]),
            float((p[9] + 1.0) / p[5]),
        )


@dataclasses.dataclass(frozen=True, init=False)
class XRPose:
    """The headset's pose and both eyes' views in one WebXR frame.

    Attributes:
        t: the frame's time on the page's clock (`performance.now()`, ms).
        position: (3,) the head (WebXR viewer pose) position, metres, `local` space.
        orientation: (4,) the head orientation, a unit quaternion (x, y, z, w).
        views: (left, right) `XRView`s (given in either order, kept left first).

    Raises:
        ValueError: a value that is not what its attribute says, named.
    """

    t: float
    position: np.ndarray
    orientation: np.ndarray
    views: tuple[XRView, XRView]

    def __init__(self, t: float, position: Vec3Like, orientation: QuaternionLike, views: Sequence[XRView]):
        if isinstance(t, bool) or not isinstance(t, int | float) or not 0 <= t < 1e12:
            raise ValueError(f"pose t must be a time in ms, 0 to 1e12, got {t!r}")
        eyes = sorted(v.eye for v in views)
        if eyes != ["left", "right"]:
            raise ValueError(f"a headset pose needs two views, left and right; got {[v.eye for v in views]}")
        left, right = sorted(views, key=lambda v: EYES.index(v.eye))
        object.__setattr__(self, "t", float(t))
        object.__setattr__(self, "position", _vector(position, 3, "head position", MAX_POSITION_M))
        object.__setattr__(self, "orientation", _unit_quaternion(orientation, "head orientation"))
        object.__setattr__(self, "views", (left, right))

    def rotation(self) -> np.ndarray:
        """(3, 3) local-from-head rotation."""
        return quaternion_matrix(self.orientation)


def level_frame(origin: CameraPose) -> tuple[np.ndarray, np.ndarray]:
    """(world-from-local rotation (3, 3), local origin in the world (3,)) for a viewpoint: local
    -z along its horizontal viewing direction, local y its up."""
    position = np.asarray(origin.position, np.float64)
    up = np.asarray(origin.up, np.float64)
    up = up / np.linalg.norm(up)
    forward = np.asarray(origin.look_at, np.float64) - position
    level = forward - np.dot(forward, up) * up
    if np.linalg.norm(level) < 1e-6 * np.linalg.norm(forward):  # looking straight up or down
        return look_at_rotation(position, position + forward, origin.up).astype(np.float64), position
    return look_at_rotation(position, position + level, up).astype(np.float64), position


@dataclasses.dataclass(frozen=True)
class XRStereo:
    """The rig that renders one `XRPose` (`xr_stereo`), and what the page needs to draw its frame.

    Attributes:
        rig: the `StereoRig` in the scene's coordinates (head pose zero: the headset's
            orientation is in its `rotation`).
        pose: the `XRPose` it was made from.
        eye_positions: (2, 3) the rendered eyes' positions, `local` space.
        eye_rotations: (2, 3, 3) the rendered eye cameras' local-from-eye rotations.
        tangents: (2, 4) each rendered eye's frustum (left, right, bottom, top) tangents.
        position_error_m: the largest distance between a rendered eye and its view's position.
        rotation_error_deg: the largest angle between a rendered eye and its view's orientation.
    """

    rig: StereoRig
    pose: XRPose
    eye_positions: np.ndarray
    eye_rotations: np.ndarray
    tangents: np.ndarray
    position_error_m: float
    rotation_error_deg: float

    @property
    def shape(self) -> tuple:
        """What a compiled frame program depends on: (eye width, eye height, fov, offsets)."""
        rig = self.rig
        return (
            rig.eye_width,
            rig.eye_height,
            float(rig.fov_deg),
            tuple(np.asarray(rig.offsets).reshape(-1).tolist()),
        )

    def _image_point(self, eye: int, direction) -> np.ndarray:
        """Normalised image coordinates (x right, y down) of a `local` direction in the rendered eye."""
        d = self.eye_rotations[eye].T @ np.asarray(direction, np.float64)
        if d[2] >= 0:
            raise ValueError(f"the direction {np.asarray(direction).tolist()} is behind the {EYES[eye]} eye")
        tx, ty = d[0] / -d[2], d[1] / -d[2]
        left, right, bottom, top = self.tangents[eye]
        return np.array([(tx - left) / (right - left), (top - ty) / (top - bottom)])

    def display_to_image(self, gaze) -> np.ndarray:
        """Per eye (x, y) in the headset's display (normalised over each view's own frustum, as a
        gaze tracker gives it) -> (x, y) in the rendered eye image, (2, 2)."""
        gaze = np.asarray(gaze, np.float64)
        out = np.empty((2, 2))
        for i, view in enumerate(self.pose.views):
            left, right, bottom, top = view.tangents()
            tangent = (left + gaze[i, 0] * (right - left), top - gaze[i, 1] * (top - bottom), -1.0)
            out[i] = self._image_point(i, view.rotation() @ np.asarray(tangent))
        return out

    def straight_ahead(self) -> np.ndarray:
        """Per eye, where the view's own -z axis (straight ahead of the eye, the centre of a
        headset's lens) falls in the rendered eye image, (2, 2): the fixed foveation's gaze."""
        return np.stack(
            [self._image_point(i, view.rotation()[:, 2] * -1.0) for i, view in enumerate(self.pose.views)]
        )

    def page_json(self) -> dict:
        """The rendered eye cameras for the page's reprojection (JSON-ready): per eye its
        local-from-eye rotation (row-major 3x3), position and frustum tangents."""
        return {
            "pose_t": self.pose.t,
            "head_orientation": [float(v) for v in self.pose.orientation],
            "eyes": [
                {
                    "eye": EYES[i],
                    "rotation": [float(v) for v in self.eye_rotations[i].reshape(-1)],
                    "position": [float(v) for v in self.eye_positions[i]],
                    "tangents": [float(v) for v in self.tangents[i]],
                }
                for i in range(2)
            ],
            "ipd_m": float(self.rig.ipd),
            "toe_out_deg": float(self.rig.toe_out_deg),
            "position_error_m": self.position_error_m,
            "rotation_error_deg": self.rotation_error_deg,
        }


def xr_stereo(pose: XRPose, origin: CameraPose, scale: float = 1.0) -> XRStereo:
    """The `XRStereo` (rig and rendered eye cameras) for a headset pose; see the module docstring.

    Args:
        pose: the `XRPose` (head and both views, `local` space).
        origin: the scene viewpoint the `local` origin is put at (levelled).
        scale: rendered pixels per headset pixel along each side (the headset's own resolution: 1).

    Raises:
        ValueError: a view's frustum reaches 90° or more from the rendered eye's axis, or the
            size at `scale` is over `MAX_XR_EYE_PIXELS` per side (naming it).
    """
    if not (isinstance(scale, int | float) and math.isfinite(scale) and scale > 0):
        raise ValueError(f"xr_stereo: scale must be a positive number, got {scale!r}")
    head_r = pose.rotation()
    eye_r = [view.rotation() for view in pose.views]
    eye_p = [view.position for view in pose.views]
    # The eyes in the head frame: their midpoint and distance.
    local = [head_r.T @ (p - pose.position) for p in eye_p]
    ipd = float(np.linalg.norm(local[1] - local[0]))
    centre = 0.5 * (local[0] + local[1])
    # The symmetric toe-out: the left eye turned left (+ about y) by it, the right eye right.
    yaws = []
    for r in eye_r:
        forward = -(head_r.T @ r)[:, 2]
        yaws.append(math.atan2(-forward[0], -forward[2]))
    toe = 0.5 * (yaws[0] - yaws[1])
    if not abs(toe) < math.radians(60):
        raise ValueError(f"the views are turned {math.degrees(toe):.1f}° apart each: not a headset's eyes")
    render_r = [head_r @ _rot_y(toe), head_r @ _rot_y(-toe)]
    half = np.array([0.5 * ipd, 0.0, 0.0])
    render_p = [pose.position + head_r @ (centre - half), pose.position + head_r @ (centre + half)]
    # Each view's frustum corners in its rendered eye: that eye's bounds.
    bounds, density = [], []
    for i, view in enumerate(pose.views):
        left, right, bottom, top = view.tangents()
        corners = np.array([[x, y, -1.0] for x in (left, right) for y in (bottom, top)])
        d = (render_r[i].T @ eye_r[i] @ corners.T).T
        if not (d[:, 2] < -1e-6).all():
            raise ValueError(f"the {view.eye} view's frustum reaches 90° or more from the eye's axis")
        tx, ty = d[:, 0] / -d[:, 2], d[:, 1] / -d[:, 2]
        bounds.append((tx.min(), tx.max(), ty.min(), ty.max()))
        density.append(view.viewport[1] / (top - bottom))  # pixels per unit tangent, vertically
    bounds = np.array(bounds)
    half_h = float(max((b[3] - b[2]) / 2 for b in bounds))
    half_w = float(max((b[1] - b[0]) / 2 for b in bounds))
    fov_deg = math.ceil(math.degrees(2 * math.atan(half_h)) / FOV_STEP_DEG) * FOV_STEP_DEG
    if not fov_deg < 180:
        raise ValueError(f"the views' vertical field of view {fov_deg:g}° is not below 180°")
    half_h = math.tan(math.radians(fov_deg) / 2)
    height = max(1, round(scale * max(density) * 2 * half_h))
    width = max(1, math.ceil(height * half_w / half_h - 1e-9))
    if max(width, height) > MAX_XR_EYE_PIXELS:
        raise ValueError(
            f"the headset's views at --xr-scale {scale:g} give {width}x{height} pixels per eye, over "
            f"{MAX_XR_EYE_PIXELS} per side; choose a smaller scale"
        )
    half_w = half_h * width / height
    offsets = np.array(
        [
            [
                round(((b[0] + b[1]) / 2) / half_w / OFFSET_STEP) * OFFSET_STEP,
                round(((b[2] + b[3]) / 2) / half_h / OFFSET_STEP) * OFFSET_STEP,
            ]
            for b in bounds
        ]
    )
    tangents = np.array(
        [[(-1 + ox) * half_w, (1 + ox) * half_w, (-1 + oy) * half_h, (1 + oy) * half_h] for ox, oy in offsets]
    )
    world_r, world_o = level_frame(origin)
    head_world = world_r @ head_r
    position = world_o + world_r @ pose.position
    rig = StereoRig.look_at(
        position,
        position - head_world[:, 2],
        head_world[:, 1],
        eye_width=width,
        eye_height=height,
        fov_deg=fov_deg,
        fov_axis="vertical",
        toe_out_deg=math.degrees(toe),
        ipd=ipd,
    ).with_eye_placement(offsets=offsets, eye_centre=centre)
    return XRStereo(
        rig=rig,
        pose=pose,
        eye_positions=np.stack(render_p),
        eye_rotations=np.stack(render_r),
        tangents=tangents,
        position_error_m=float(max(np.linalg.norm(render_p[i] - eye_p[i]) for i in range(2))),
        rotation_error_deg=float(max(_angle_deg(render_r[i], eye_r[i]) for i in range(2))),
    )
