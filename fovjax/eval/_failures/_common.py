"""What every failure case shares: the case names, the bench of memoised full renders and
metric maps, the per-ring and masked metrics, and the `FailureCase` / `FailureReport` results."""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import statistics
import time
from collections.abc import Callable, Mapping
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ...render import SceneArrays, StereoRig
from ...scene import Scene
from .._metrics import HmdDisplay, display_encode, error_by_eccentricity, flip, psnr
from .._pareto import write_csv
from .._stability import FullRenders

CASES = (
    "corner_gaze",
    "tracking_error",
    "after_saccade",
    "high_spp",
    "checkerboard",
    "acuity_models",
    "scanpath_flicker",
)
# What the eye resolves sharply around the gaze: the central 2° (the fovea proper is ~5° across).
CENTRAL_DEG = 2.0
SACCADE_POLICIES = ("perfect", "latest", "predicted")


# ---- shared helpers ---------------------------------------------------------------------------


def _has_flip() -> bool:
    return importlib.util.find_spec("flip_evaluator") is not None


def _side(eye_maps) -> np.ndarray:
    """(2, H, W) per-eye maps -> (H, 2W) side by side."""
    m = np.asarray(eye_maps)
    return np.concatenate([m[0], m[1]], axis=1)


def _true_eccentricity(rig, gaze, foveation) -> np.ndarray:
    """(H, 2W) eccentricity of every pixel from the *true* gaze (per eye), still head."""
    from ...foveate import eccentricity_map

    g = np.asarray(gaze, np.float32).reshape(2, 2)
    return _side([np.asarray(eccentricity_map(c, g[i], foveation)) for i, c in enumerate(rig.eye_cameras())])


def offset_gaze(rig, gaze, angle_deg: float, direction_deg: float = 0.0) -> np.ndarray:
    """Per-eye gaze points (2, 2) `angle_deg` degrees of visual angle away from `gaze`
    (normalised display coordinates, one point or one per eye) towards `direction_deg` on the
    display (0 right, 90 down, 180 left, 270 up), through each eye's own camera model. Raises
    ValueError when the point would leave the screen."""
    from ...foveate import eccentricity_angle

    if not (math.isfinite(angle_deg) and 0 <= angle_deg < 90):
        raise ValueError(f"offset_gaze: angle_deg must be in [0, 90), got {angle_deg}")
    g = np.broadcast_to(np.asarray(gaze, np.float64).reshape(-1, 2), (2, 2))
    out = np.empty((2, 2))
    direction = np.array([math.cos(math.radians(direction_deg)), math.sin(math.radians(direction_deg))])
    for i, cam in enumerate(rig.eye_cameras()):
        size = np.array([cam.width, cam.height], np.float64)
        centre = g[i] * size
        s = np.linspace(0.0, 4.0 * float(size.max()), 8001)
        px = (centre[None] + s[:, None] * direction[None]).astype(np.float32)
        angles = np.asarray(eccentricity_angle(cam, jnp.asarray(g[i], jnp.float32), px), np.float64)
        out[i] = (centre + float(np.interp(angle_deg, angles, s)) * direction) / size
    if not np.isfinite(out).all() or (out < 0).any() or (out > 1).any():
        raise ValueError(
            f"offset_gaze: {angle_deg}° towards {direction_deg}° from {g[0].tolist()} leaves the screen "
            f"({out.tolist()})"
        )
    return out.astype(np.float32)


def _gaze_angle(rig, a, b) -> float:
    """Degrees between the left eye's gaze rays through points a and b."""
    from ...foveate import eccentricity_angle

    cam = rig.eye_cameras()[0]
    a = np.asarray(a, np.float32).reshape(-1, 2)[0]
    b = np.asarray(b, np.float32).reshape(-1, 2)[0]
    px = (b * np.array([cam.width, cam.height], np.float32))[None]
    return float(np.asarray(eccentricity_angle(cam, jnp.asarray(a), px))[0])


def _scene_rig(full, where: str):
    """The scene and rig of a case's `FullRenders` (its render config and BVH are the case's too)."""
    if not isinstance(full, FullRenders):
        raise TypeError(
            f"{where}: the first argument must be a fovjax.eval.FullRenders(scene, rig, config), "
            f"got {type(full).__name__}"
        )
    return full.scene, full.rig


@dataclasses.dataclass
class _Bench:
    """What every case needs: the scene, rig and config, memoised full renders, the display's
    ppd for FLIP, and a progress callback."""

    scene: Scene | SceneArrays
    rig: StereoRig
    full: FullRenders
    tick: Callable[[], None]
    use_flip: bool

    @classmethod
    def make(cls, full: FullRenders, progress=None, use_flip=None) -> _Bench:
        return cls(
            full.scene,
            full.rig,
            full,
            progress or (lambda: None),
            _has_flip() if use_flip is None else use_flip,
        )

    @property
    def ppd(self) -> float:
        return HmdDisplay.from_camera(self.rig.eye_cameras()[0]).ppd

    def foveated(self, gaze, foveation, key):
        from ...foveate import render_foveated

        frame = render_foveated(
            self.scene,
            self.rig,
            gaze=np.asarray(gaze, np.float32).reshape(2, 2),
            foveation=foveation,
            key=None if key is None else jax.random.key(int(key)),
            config=self.full.config,
            bvh=self.full.bvh,
        )
        self.tick()
        return frame

    def reference(self, key, spp: int = 1) -> np.ndarray:
        image = self.full.image(key, spp)
        return image

    def maps(self, test, ref) -> dict[str, np.ndarray]:
        """Per-pixel error maps (H, 2W): "abs" and, with flip-evaluator, "flip"."""
        maps = {"abs": np.abs(display_encode(test) - display_encode(ref)).mean(axis=-1)}
        if self.use_flip:
            maps["flip"] = flip(test, ref, ppd=self.ppd, return_map=True)[1]
        return maps


def _masked(maps: Mapping[str, np.ndarray], mask: np.ndarray, suffix: str) -> dict[str, float]:
    n = int(mask.sum())
    out: dict[str, float] = {f"pixels_{suffix}": n}
    for name, m in maps.items():
        out[f"{name}_{suffix}"] = float(m[mask].mean()) if n else math.nan
    return out


def _ring_rows(maps, test, ref, ecc, ring_deg: float) -> list[dict]:
    rings = error_by_eccentricity(test, ref, ecc, ring_deg=ring_deg, error_map=maps["abs"])
    flips = (
        error_by_eccentricity(test, ref, ecc, ring_deg=ring_deg, error_map=maps["flip"])
        if "flip" in maps
        else None
    )
    rows = []
    for i, row in enumerate(rings.rows()):
        out = {
            "ring_lower_deg": row["ring_lower_deg"],
            "ring_upper_deg": row["ring_upper_deg"],
            "ring_pixels": row["pixels"],
            "abs_error": row["mean_error"],
        }
        if flips is not None:
            out["flip"] = float(flips.mean_error[i])
        rows.append(out)
    return rows


def _frame_metrics(maps, test, ref) -> dict[str, float]:
    out = {"frame_psnr": psnr(test, ref).value, "frame_abs_error": float(maps["abs"].mean())}
    if "flip" in maps:
        out["frame_flip"] = float(maps["flip"].mean())
    return out


def _mean(records, column: str, **match) -> float:
    return statistics.mean(r[column] for r in records if all(r[k] == v for k, v in match.items()))


def _metric(records, name) -> str:
    """The error column to summarise by: FLIP when measured, else |error|."""
    return name if records and name in records[0] else name.replace("flip", "abs")


@dataclasses.dataclass(frozen=True)
class FailureCase:
    """One named experiment: its `records` (CSV rows; `kind` separates row types where a case
    has several), a `finding` sentence computed from them, the `parameters` it ran with, and
    its wall time in seconds (compiles included)."""

    name: str
    title: str
    records: list[dict]
    finding: str
    parameters: dict
    seconds: float

    def write(self, out_dir) -> dict[str, Path]:
        """`NAME.csv` and `NAME.png` in `out_dir`."""
        from .. import _charts

        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        chart = getattr(_charts, f"plot_{self.name}")
        return {
            "csv": write_csv(self.records, out / f"{self.name}.csv"),
            "chart": chart(self.records, out / f"{self.name}.png", title=self.title),
        }


@dataclasses.dataclass(frozen=True)
class FailureReport:
    """The cases that were run, by name."""

    cases: dict[str, FailureCase]

    def write(self, out_dir) -> dict[str, Path]:
        """Each case's CSV and chart, and `findings.csv` (one row per case)."""
        out = Path(out_dir)
        paths = {}
        for name, case in self.cases.items():
            for kind, path in case.write(out).items():
                paths[f"{name}_{kind}"] = path
        rows = [
            {
                "case": c.name,
                "title": c.title,
                "finding": c.finding,
                "seconds": c.seconds,
                "parameters": repr(c.parameters),
            }
            for c in self.cases.values()
        ]
        paths["findings"] = write_csv(rows, out / "findings.csv")
        return paths


# ---- a case's result ---------------------------------------------------------------------------


def _case(name, title, records, finding, parameters, t0) -> FailureCase:
    return FailureCase(name, title, records, finding, parameters, time.perf_counter() - t0)
