"""`checkerboard`: a fine high-contrast checkerboard filling the periphery against the same wall
in its mean grey; error per ring and flicker along a pursuit."""

from __future__ import annotations

import dataclasses
import math
import statistics
import time
from collections.abc import Sequence

import numpy as np

from .._stability import FullRenders, temporal_stability
from ._common import (
    FailureCase,
    _Bench,
    _case,
    _frame_metrics,
    _masked,
    _metric,
    _ring_rows,
    _side,
)


def checkerboard_scene(
    *,
    check_size: float = 0.02,
    distance: float = 1.0,
    smooth: bool = False,
    dark: float = 0.03,
    light: float = 0.9,
):
    """A wall `distance` metres in front of the viewer, wide enough to fill both eyes of an HMD
    rig (±71° horizontally, ±63° vertically), textured with a checkerboard of `check_size`-metre
    squares of linear albedo `dark` and `light` — fine high-contrast detail across the whole
    periphery — or, with `smooth`, the same wall in the checkerboard's mean albedo (same arrays'
    shapes, so both share compiled programs). Lit by one point light above and behind the
    viewer. Returns (scene, `fovjax.scenes.CameraPose`)."""
    from ...scene import CameraPose, make_lights, make_materials, make_scene

    for name, value in (("check_size", check_size), ("distance", distance)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"checkerboard_scene: {name} must be > 0 metres, got {value}")
    if not (0 <= dark <= 1 and 0 <= light <= 1):
        raise ValueError(f"checkerboard_scene: dark and light albedo must be in [0, 1], got {dark}, {light}")
    hw, hh = 3.0 * distance, 2.0 * distance
    vertices = np.array([(-hw, -hh, 0.0), (hw, -hh, 0.0), (hw, hh, 0.0), (-hw, hh, 0.0)])
    faces = np.array([(0, 1, 2), (0, 2, 3)])
    uvs = vertices[:, :2] / (2.0 * check_size)  # one texture tile holds 2x2 checks
    texels = 8  # per check: bilinear filtering blurs an edge over 1/8 of a check
    i = np.arange(2 * texels) // texels
    pattern = (i[:, None] + i[None, :]) % 2
    albedo = (
        np.where(pattern == 1, light, dark) if not smooth else np.full(pattern.shape, 0.5 * (dark + light))
    )
    texture = np.repeat(albedo[..., None], 3, axis=-1).astype(np.float32)
    scene = make_scene(
        vertices,
        faces,
        materials=make_materials([{"name": "wall", "kd": (1.0, 1.0, 1.0), "ka": (0.2,) * 3, "texture": 0}]),
        lights=make_lights([(0.4 * distance, 0.8 * distance, 1.5 * distance)], [(1.0, 1.0, 1.0)]),
        uvs=uvs,
        textures=(texture,),
        name="checkerboard" if not smooth else "checkerboard_smooth",
    )
    return scene, CameraPose(position=(0.0, 0.0, distance), look_at=(0.0, 0.0, 0.0))


def _rig_at(rig, pose):
    from ...render import StereoRig

    return StereoRig.from_pose(
        pose,
        eye_width=rig.eye_width,
        eye_height=rig.eye_height,
        fov_deg=float(rig.fov_deg),
        fov_axis=rig.fov_axis,
        toe_out_deg=float(rig.toe_out_deg),
        ipd=float(rig.ipd),
        offsets=np.asarray(rig.offsets),
        eye_centre=np.asarray(rig.eye_centre),
    )


@dataclasses.dataclass(frozen=True)
class PursuitFlicker:
    """The flicker half of `checkerboard`: `frames` frames at `fps` along a circular smooth
    pursuit of radius 0.1 (normalised display units) at `hz` laps per second.

    Raises:
        ValueError: fewer than 2 frames, or a non-positive or non-finite `fps` or `hz`.
    """

    frames: int = 8
    fps: float = 90.0
    hz: float = 0.5

    def __post_init__(self):
        if isinstance(self.frames, bool) or not isinstance(self.frames, int | np.integer) or self.frames < 2:
            raise ValueError(f"PursuitFlicker: frames must be a whole number >= 2, got {self.frames!r}")
        for name in ("fps", "hz"):
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float)
                or not (math.isfinite(value) and value > 0)
            ):
                raise ValueError(f"PursuitFlicker: {name} must be a finite number > 0, got {value!r}")


def checkerboard(
    rig,
    foveation=None,
    *,
    check_size: float = 0.02,
    keys: Sequence[int] = (0, 1),
    gaze=(0.5, 0.5),
    ring_deg: float = 5.0,
    flicker: PursuitFlicker | None = None,
    config=None,
    progress=None,
) -> FailureCase:
    """A fine checkerboard filling the periphery (`checkerboard_scene`) against the same wall
    in its mean grey, seen with `rig`'s intrinsics: error per ring at `gaze` ("ring" rows) and
    flicker along a circular pursuit (`flicker`, default `PursuitFlicker()`: 8 frames at 90 Hz,
    0.5 laps per second), fresh against fixed key ("flicker" rows, see `temporal_stability`)."""
    from ...devices import SmoothPursuit
    from ...foveate import Foveation, check_gaze

    t0 = time.perf_counter()
    foveation = foveation or Foveation.thesis(2)
    flicker = PursuitFlicker() if flicker is None else flicker
    if not isinstance(flicker, PursuitFlicker):
        raise TypeError(f"checkerboard: flicker must be a PursuitFlicker, got {type(flicker).__name__}")
    frames, fps, pursuit_hz = flicker.frames, flicker.fps, flicker.hz
    if not keys:
        raise ValueError("checkerboard: need at least one key")
    g = check_gaze(np.broadcast_to(np.asarray(gaze, np.float64).reshape(-1, 2), (2, 2)), "checkerboard gaze")
    records = []
    for smooth in (False, True):
        scene, pose = checkerboard_scene(check_size=check_size, smooth=smooth)
        wall_rig = _rig_at(rig, pose)
        bench = _Bench.make(FullRenders(scene, wall_rig, config), progress)
        label = "smooth" if smooth else "checkerboard"
        for k in keys:
            frame = bench.foveated(g, foveation, k)
            ref = bench.reference(k)
            maps = bench.maps(frame.image, ref)
            region = _side(frame.regions)
            common = {"kind": "ring", "scene": label, "key": int(k), **_frame_metrics(maps, frame.image, ref)}
            common.update(_masked(maps, region != 0, "beyond_fovea"))
            rows = _ring_rows(maps, frame.image, ref, _side(frame.eccentricity), ring_deg)
            records += [{**common, **row} for row in rows]
        pursuit = SmoothPursuit(centre=(0.5, 0.5), radius=(0.1, 0.1), frequency=pursuit_hz)
        result = temporal_stability(
            bench.full, pursuit, foveation, frames=frames, fps=fps, seed=int(keys[0]), progress=bench.tick
        )
        for row in result.summary:
            records.append({"kind": "flicker", "scene": label, **row})
    m = _metric([r for r in records if r["kind"] == "ring"], "flip_beyond_fovea")

    def pick(scene, kind, col, mode=None):
        rows = [
            r
            for r in records
            if r["scene"] == scene and r["kind"] == kind and (mode is None or r["key_mode"] == mode)
        ]
        return statistics.mean(r[col] for r in rows)

    finding = (
        f"{m}: checkerboard {pick('checkerboard', 'ring', m):.4f} vs smooth {pick('smooth', 'ring', m):.4f}; "
        f"flicker beyond the fovea relative to the full fresh-key render: fresh key "
        f"{pick('checkerboard', 'flicker', 'ratio_beyond_fovea', 'fresh'):.2f} (checkerboard) vs "
        f"{pick('smooth', 'flicker', 'ratio_beyond_fovea', 'fresh'):.2f} (smooth), fixed key "
        f"{pick('checkerboard', 'flicker', 'ratio_beyond_fovea', 'fixed'):.2f} vs "
        f"{pick('smooth', 'flicker', 'ratio_beyond_fovea', 'fixed'):.2f}"
    )
    params = {
        "check_size_m": check_size,
        "keys": tuple(keys),
        "frames": frames,
        "fps": fps,
        "pursuit_hz": pursuit_hz,
        "fovea_deg": foveation.fovea_deg,
        "periphery_deg": foveation.periphery_deg,
    }
    return _case("checkerboard", "fine checkerboard periphery vs smooth wall", records, finding, params, t0)
