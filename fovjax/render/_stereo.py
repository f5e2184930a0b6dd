"""The stereo HMD rig: two pinhole eyes, toed out, on a head that yaws, pitches and rolls.

Defaults are the thesis's NVIS SX111 set-up (section 4.3): per eye 1280 x 1024 pixels and a 90°
field of view, the two eye cameras rotated 13° outwards (left eye to the left, right eye to the
right), 64 mm apart, written side by side (left eye in the left half) into one 2560 x 1024 image.

Field of view. The thesis gives one number, 90°, for "the field of view of each camera-eye". We
take it as the *horizontal* field of view of each eye (`fov_axis="horizontal"`, vertical then
2·atan(tan 45° · 1024/1280) = 77.3°), because the thesis quotes HMD fields of view horizontal
first (the SX111's "102 degrees horizontal by 64 vertical") and because this reading is the one
closer to the headset: the SX111's panels cover 76° x 64° each and 102° together, which is
exactly 76° + 2 x 13° of toe-out, so the ±13° is the panels' cant and 90° horizontal per eye is
a modest overscan of 76°, whereas 90° vertical would mean 103° x 90° per eye. The OptiX camera
code that would settle it is not in the thesis; `fov_axis="vertical"` gives the other reading.

Head pose (InertiaCube convention, as `fovjax.devices.HeadPose`): yaw about the up axis,
positive turning right (seen from above); pitch about the right axis, positive looking up; roll
about the forward axis, positive tilting the right ear down; applied intrinsically in the order
yaw, then pitch, then roll (the InertiaCube's z-y-x Euler angles in its x-forward, y-right,
z-down frame). The head frame at zero pose is the rig's `rotation` (columns: right, up,
backward, as `Camera.rotation`); the head turns about `position` (the head centre), and the eyes
sit at `position + R_head @ (eye_centre ± (ipd/2, 0, 0))`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any, NamedTuple, Protocol, SupportsFloat, TypeAlias, runtime_checkable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Real

from ..scene import Camera, CameraPose, look_at_rotation, pixel_sample_positions, vfov_from_hfov

# Thesis / NVIS SX111 defaults.
EYE_WIDTH = 1280
EYE_HEIGHT = 1024
FOV_DEG = 90.0
TOE_OUT_DEG = 13.0
IPD_M = 0.064
FOV_AXES = ("horizontal", "vertical")


@runtime_checkable
class Orientation(Protocol):
    """Anything with a yaw, pitch and roll in degrees (a `fovjax.devices.HeadPose`)."""

    @property
    def yaw(self) -> float: ...

    @property
    def pitch(self) -> float: ...

    @property
    def roll(self) -> float: ...


# A head pose: (yaw, pitch, roll) degrees as a sequence or a (3,) array (traced under jit), a
# `fovjax.devices.HeadPose`, or None (level, looking ahead).
HeadPoseLike: TypeAlias = Orientation | Real[ArrayLike, " 3"] | Sequence[float] | None
# A point in space, or a direction: 3 numbers.
Vec3Like: TypeAlias = Real[ArrayLike, " 3"] | Sequence[SupportsFloat]


def _rot_x(a):
    c, s = jnp.cos(a), jnp.sin(a)
    one, zero = jnp.ones_like(a), jnp.zeros_like(a)
    return jnp.stack([jnp.stack([one, zero, zero]), jnp.stack([zero, c, -s]), jnp.stack([zero, s, c])])


def _rot_y(a):
    c, s = jnp.cos(a), jnp.sin(a)
    one, zero = jnp.ones_like(a), jnp.zeros_like(a)
    return jnp.stack([jnp.stack([c, zero, s]), jnp.stack([zero, one, zero]), jnp.stack([-s, zero, c])])


def _rot_z(a):
    c, s = jnp.cos(a), jnp.sin(a)
    one, zero = jnp.ones_like(a), jnp.zeros_like(a)
    return jnp.stack([jnp.stack([c, -s, zero]), jnp.stack([s, c, zero]), jnp.stack([zero, zero, one])])


def head_pose_angles(head_pose: HeadPoseLike) -> Float[np.ndarray | Array, " 3"]:
    """(yaw, pitch, roll) in degrees from a `fovjax.devices.HeadPose`, a 3-sequence or None
    (= level, looking ahead)."""
    if head_pose is None:
        return np.zeros(3, np.float32)
    if isinstance(head_pose, Orientation):
        head_pose = (head_pose.yaw, head_pose.pitch, head_pose.roll)
    if isinstance(head_pose, jax.Array):  # concrete or traced: keep it on the device
        if head_pose.shape != (3,):
            raise ValueError(f"head_pose must be (yaw, pitch, roll) in degrees, got shape {head_pose.shape}")
        return head_pose.astype(jnp.float32)
    angles = np.asarray(head_pose, np.float32)
    if angles.shape != (3,) or not np.isfinite(angles).all():
        raise ValueError(
            f"head_pose must be 3 finite angles (yaw, pitch, roll) in degrees, got {head_pose!r}"
        )
    return angles


def head_rotation(head_pose: HeadPoseLike) -> Float[Array, "3 3"]:
    """Head-from-neutral rotation, in the camera-style head frame (x right, y up, z backward),
    for yaw, pitch, roll in degrees (InertiaCube convention, see the module docstring)."""
    yaw, pitch, roll = jnp.deg2rad(jnp.asarray(head_pose_angles(head_pose), jnp.float32))
    # yaw right = about -y; pitch up = about +x; roll right-ear-down = about the forward axis -z.
    return _rot_y(-yaw) @ _rot_x(pitch) @ _rot_z(-roll)


class StereoRig(eqx.Module):
    """Two pinhole eyes on a head. Array fields can be traced (and differentiated); the
    resolution and the field-of-view axis are static.

    - `position` (3,): the head centre (the point the head turns about), world units;
    - `rotation` (3, 3): world-from-head at zero head pose (columns right, up, backward);
    - `ipd`: distance between the eyes, in scene units (metres for the built-in scenes);
    - `toe_out_deg`: each eye camera turned this far outwards about the head's up axis;
    - `fov_deg`: each eye's field of view along `fov_axis` ("horizontal" or "vertical");
    - `offsets` (2, 2): per-eye projection-centre shift (left, right), in `Camera.offset` units
      (fractions of the image plane's half-extent; canted or off-axis displays);
    - `eye_centre` (3,): the eyes' midpoint in the head frame, relative to `position`
      (e.g. (0, 0.1, -0.08) to turn about a neck below and behind the eyes);
    - `eye_width`, `eye_height`: pixels per eye.
    """

    position: Float[np.ndarray | Array, " 3"]
    rotation: Float[np.ndarray | Array, "3 3"]
    ipd: Float[np.ndarray | np.number | Array, ""]
    toe_out_deg: Float[np.ndarray | np.number | Array, ""]
    fov_deg: Float[np.ndarray | np.number | Array, ""]
    offsets: Float[np.ndarray | Array, "2 2"]
    eye_centre: Float[np.ndarray | Array, " 3"]
    eye_width: int = eqx.field(static=True, default=EYE_WIDTH)
    eye_height: int = eqx.field(static=True, default=EYE_HEIGHT)
    fov_axis: str = eqx.field(static=True, default="horizontal")

    def __check_init__(self):
        # The smallest frame this rig makes (full, SPP 1, the leaner integrator) must fit the
        # machine's memory: a rig that cannot render is refused where it is made.
        from ._memory import check_frame_memory

        check_frame_memory(self.eye_width, self.eye_height, 1, integrator="native", where="StereoRig")

    @classmethod
    def look_at(
        cls,
        position: Vec3Like,
        look_at: Vec3Like,
        up: Vec3Like = (0.0, 1.0, 0.0),
        *,
        eye_width: int = EYE_WIDTH,
        eye_height: int = EYE_HEIGHT,
        fov_deg: float = FOV_DEG,
        fov_axis: str = "horizontal",
        toe_out_deg: float = TOE_OUT_DEG,
        ipd: float = IPD_M,
    ) -> StereoRig:
        """A rig whose head centre is at `position`, looking at `look_at` at zero head pose, its
        eyes centred on the head centre with no projection offsets (`with_eye_placement` moves
        them)."""
        if int(eye_width) <= 0 or int(eye_height) <= 0:
            raise ValueError(f"StereoRig: eye resolution must be positive, got {eye_width}x{eye_height}")
        if fov_axis not in FOV_AXES:
            raise ValueError(f"StereoRig: fov_axis must be one of {FOV_AXES}, got {fov_axis!r}")
        if not 0 < float(fov_deg) < 180:
            raise ValueError(f"StereoRig: fov_deg must be in (0, 180), got {fov_deg}")
        if fov_axis == "horizontal" and not 0 < float(vfov_from_hfov(fov_deg, eye_width, eye_height)) < 180:
            raise ValueError(f"StereoRig: fov_deg {fov_deg} gives no valid vertical field of view")
        for name, value in (("ipd", ipd), ("toe_out_deg", toe_out_deg)):
            if not np.isfinite(float(value)):
                raise ValueError(f"StereoRig: {name} must be finite, got {value}")
        pos = np.asarray(position, np.float32)
        if pos.shape != (3,) or not np.isfinite(pos).all():
            raise ValueError(f"StereoRig: position must be 3 finite numbers, got {position}")
        return cls(
            position=pos,
            rotation=look_at_rotation(position, look_at, up),
            ipd=np.float32(ipd),
            toe_out_deg=np.float32(toe_out_deg),
            fov_deg=np.float32(fov_deg),
            offsets=np.zeros((2, 2), np.float32),
            eye_centre=np.zeros(3, np.float32),
            eye_width=int(eye_width),
            eye_height=int(eye_height),
            fov_axis=fov_axis,
        )

    def with_eye_placement(
        self,
        *,
        offsets: Real[ArrayLike, "2 2"] | Sequence[Sequence[float]] | None = None,
        eye_centre: Vec3Like | None = None,
    ) -> StereoRig:
        """This rig with other per-eye projection-centre `offsets` ((x, y) left, (x, y) right, in
        `Camera.offset` units: canted or off-axis displays) and/or another `eye_centre` (the
        eyes' midpoint in the head frame relative to `position`, e.g. (0, 0.1, -0.08) to turn
        about a neck below and behind the eyes); None keeps the rig's."""
        if offsets is not None:
            offsets = np.asarray(offsets, np.float32)
            if offsets.shape != (2, 2) or not np.isfinite(offsets).all():
                raise ValueError(
                    f"StereoRig: offsets must be ((x, y) left, (x, y) right), got {offsets.tolist()}"
                )
        if eye_centre is not None:
            centre = np.asarray(eye_centre, np.float32)
            if centre.shape != (3,) or not np.isfinite(centre).all():
                raise ValueError(f"StereoRig: eye_centre must be 3 finite numbers, got {eye_centre}")
            eye_centre = centre
        return dataclasses.replace(
            self,
            offsets=self.offsets if offsets is None else offsets,
            eye_centre=self.eye_centre if eye_centre is None else eye_centre,
        )

    @classmethod
    def from_pose(cls, pose: CameraPose, **kwargs: Any) -> StereoRig:
        """From a `fovjax.scenes.CameraPose` (its field of view is not used: the rig has its own;
        `kwargs` are `look_at`'s)."""
        return cls.look_at(pose.position, pose.look_at, pose.up, **kwargs)

    @property
    def width(self) -> int:
        """Width of the side-by-side image (both eyes)."""
        return 2 * self.eye_width

    @property
    def height(self) -> int:
        return self.eye_height

    def vfov_deg(self) -> Float[Array, ""]:
        if self.fov_axis == "vertical":
            return jnp.asarray(self.fov_deg, jnp.float32)
        return vfov_from_hfov(self.fov_deg, self.eye_width, self.eye_height)

    def eye_cameras(self, head_pose: HeadPoseLike = None) -> tuple[Camera, Camera]:
        """The (left, right) eye cameras for a head pose (yaw, pitch, roll in degrees, or a
        `HeadPose`). Jittable: the pose may be a traced (3,) array."""
        world_from_head = jnp.asarray(self.rotation, jnp.float32) @ head_rotation(head_pose)
        toe = jnp.deg2rad(jnp.asarray(self.toe_out_deg, jnp.float32))
        half_ipd = 0.5 * jnp.asarray(self.ipd, jnp.float32)
        vfov = self.vfov_deg()
        cameras = []
        for eye, side in ((0, -1.0), (1, 1.0)):
            local = jnp.asarray(self.eye_centre, jnp.float32) + jnp.stack(
                [side * half_ipd, jnp.float32(0.0), jnp.float32(0.0)]
            )
            cameras.append(
                Camera(
                    position=jnp.asarray(self.position, jnp.float32) + world_from_head @ local,
                    # left eye turns left (+ about up), right eye right
                    rotation=world_from_head @ _rot_y(-side * toe),
                    vfov_deg=vfov,
                    offset=jnp.asarray(self.offsets, jnp.float32)[eye],
                    width=self.eye_width,
                    height=self.eye_height,
                )
            )
        return cameras[0], cameras[1]


class SampleRays(NamedTuple):
    """Per-sample primary rays of a stereo frame: `origins` and unit `directions`
    (2, spp, H, W, 3), eye 0 the left; `pixel_xy` (spp, H, W, 2) the continuous pixel
    coordinates of each sample within its eye's image (the same for both eyes)."""

    origins: Float[np.ndarray | Array, "2 spp H W 3"]
    directions: Float[np.ndarray | Array, "2 spp H W 3"]
    pixel_xy: Float[np.ndarray | Array, "spp H W 2"]


def stereo_sample_rays(
    rig: StereoRig, head_pose: HeadPoseLike = None, spp: int = 1, key: jax.Array | None = None
) -> SampleRays:
    """The primary rays of a stereo frame: `spp` stratified samples per pixel (jittered per
    pixel from `key`, cell centres without one) through both eyes. Static shapes; jittable."""
    xy = pixel_sample_positions(rig.eye_width, rig.eye_height, spp, key)
    left, right = rig.eye_cameras(head_pose)
    directions = jnp.stack([left.ray_directions(xy), right.ray_directions(xy)])
    origins = jnp.broadcast_to(
        jnp.stack([left.position, right.position])[:, None, None, None, :], directions.shape
    )
    return SampleRays(origins, directions, xy)
