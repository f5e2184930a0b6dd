"""`after_saccade`: the frames around a main-sequence saccade, foveated on the latest, the
predicted and the true gaze."""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence

import numpy as np

from .._stability import FullRenders
from ._common import (
    CENTRAL_DEG,
    SACCADE_POLICIES,
    FailureCase,
    _Bench,
    _case,
    _gaze_angle,
    _masked,
    _metric,
    _scene_rig,
    _side,
    _true_eccentricity,
    offset_gaze,
)


def _saccade_path(rig, start, amplitude_deg, direction_deg, onset_s):
    from ...devices import min_jerk, saccade_duration

    start = np.broadcast_to(np.asarray(start, np.float64).reshape(-1, 2), (2, 2))
    land = offset_gaze(rig, start, amplitude_deg, direction_deg).astype(np.float64)
    duration = saccade_duration(amplitude_deg)

    def at(t: float) -> np.ndarray:
        w = float(min_jerk((t - onset_s) / duration))
        return start + (land - start) * w

    return at, onset_s + duration, duration


@dataclasses.dataclass(frozen=True)
class SaccadeTrial:
    """The saccade `after_saccade` shows and how it is tracked: one saccade of `amplitude_deg`
    from `start` (normalised display coordinates) in `direction_deg`, displayed at `fps` from
    `before_frames` frames before its onset to `after_s` seconds after it lands; a tracker
    sampling at `tracker_hz` seen `latencies_s` late.

    Raises:
        ValueError: a bad field, naming it, its value and what was expected.
    """

    start: tuple = (0.3, 0.5)
    amplitude_deg: float = 20.0
    direction_deg: float = 0.0
    fps: float = 60.0
    latencies_s: Sequence[float] = (0.025, 0.05)
    tracker_hz: float = 120.0
    before_frames: int = 2
    after_s: float = 0.1

    def __post_init__(self):
        for name in ("fps", "tracker_hz", "amplitude_deg"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"SaccadeTrial: {name} must be > 0, got {value}")
        latencies = [float(x) for x in self.latencies_s]
        if not latencies or any(not (math.isfinite(x) and x >= 0) for x in latencies):
            raise ValueError(
                f"SaccadeTrial: latencies_s must be finite seconds >= 0, got {self.latencies_s!r}"
            )
        if not (self.after_s >= 0) or self.before_frames < 1:
            raise ValueError(
                "SaccadeTrial: need after_s >= 0 and before_frames >= 1, "
                f"got {self.after_s}, {self.before_frames}"
            )


def after_saccade(
    full: FullRenders,
    foveation=None,
    *,
    saccade: SaccadeTrial | None = None,
    key: int = 0,
    central_deg: float = CENTRAL_DEG,
    policies: Sequence[str] = SACCADE_POLICIES,
    progress=None,
) -> FailureCase:
    """Frames around one saccade (`saccade`, default `SaccadeTrial()`: main-sequence duration,
    minimum-jerk profile, as `fovjax.devices.Scanpath`) of `amplitude_deg` from `start`,
    displayed at `fps`. The frame shown at time t is foveated on: "perfect" the true gaze at t;
    "latest" the last tracker sample (at `tracker_hz`) taken a latency before t, for each of
    `latencies_s`; "predicted" that sample extrapolated at the velocity of the last two samples
    to t (`fovjax.devices.GazePredictor`, horizon at most 50 ms). Error around the true gaze at
    t (true fovea, central `central_deg`), frame by frame; the key is fixed so a still frame
    with perfect tracking has no error in the fovea. `display` names policy and latency.
    `full`: the `FullRenders(scene, rig, config)` of what to render."""
    from ...devices import GazePredictor
    from ...foveate import Foveation

    scene, rig = _scene_rig(full, "after_saccade")
    t0 = time.perf_counter()
    foveation = foveation or Foveation.thesis(2)
    saccade = SaccadeTrial() if saccade is None else saccade
    if not isinstance(saccade, SaccadeTrial):
        raise TypeError(f"after_saccade: saccade must be a SaccadeTrial, got {type(saccade).__name__}")
    if any(p not in SACCADE_POLICIES for p in policies) or not policies:
        raise ValueError(f"after_saccade: policies must be among {SACCADE_POLICIES}, got {policies!r}")
    start, amplitude_deg, direction_deg = saccade.start, saccade.amplitude_deg, saccade.direction_deg
    fps, tracker_hz, after_s = saccade.fps, saccade.tracker_hz, saccade.after_s
    before_frames, latencies = saccade.before_frames, [float(x) for x in saccade.latencies_s]
    onset = (before_frames - 0.5) / fps
    path, landing, duration = _saccade_path(rig, start, amplitude_deg, direction_deg, onset)
    predictor = GazePredictor()
    bench = _Bench.make(full, progress)
    ref = bench.reference(key)
    n_frames = int(math.ceil((landing + after_s) * fps)) + 1
    records = []
    for f in range(n_frames):
        t = f / fps
        true = path(t)
        shown_by = {}
        for policy in policies:
            for latency in [0.0] if policy == "perfect" else latencies:
                if policy == "perfect":
                    shown = true
                else:
                    sample_t = math.floor((t - latency) * tracker_hz + 1e-9) / tracker_hz
                    shown = sample = path(sample_t)
                    if policy == "predicted":
                        velocity = (sample - path(sample_t - 1.0 / tracker_hz)) * tracker_hz
                        shown = np.array([predictor(sample[i], velocity[i], sample_t, t) for i in range(2)])
                label = policy if policy == "perfect" else f"{policy}, {1000 * latency:g} ms"
                shown_by[label] = (policy, latency, np.clip(shown, 0.0, 1.0).astype(np.float32))
        ecc = _true_eccentricity(rig, true, foveation)
        masks = {"true_fovea": ecc <= foveation.fovea_deg, "central": ecc <= central_deg}
        phase = "before" if t < onset else "saccade" if t < landing else "after"
        for label, (policy, latency, shown) in shown_by.items():
            frame = bench.foveated(shown, foveation, key)
            maps = bench.maps(frame.image, ref)
            row = {
                "display": label,
                "policy": policy,
                "latency_ms": 1000 * latency,
                "frame": f,
                "time_ms": 1000 * t,
                "since_landing_ms": 1000 * (t - landing),
                "phase": phase,
                "true_gaze_x": float(true[0, 0]),
                "true_gaze_y": float(true[0, 1]),
                "shown_gaze_x": float(shown[0, 0]),
                "shown_gaze_y": float(shown[0, 1]),
                "gaze_error_deg": _gaze_angle(rig, true, shown),
                "true_fovea_covered": float((_side(frame.regions)[masks["true_fovea"]] == 0).mean()),
            }
            for name, mask in masks.items():
                row.update(_masked(maps, mask, name))
            records.append(row)
    m = _metric(records, "flip_true_fovea")
    parts = []
    for label in dict.fromkeys(r["display"] for r in records):
        rows = [r for r in records if r["display"] == label and r["phase"] == "after"]
        values = ", ".join(f"{r[m]:.4f}" for r in rows[:4])
        parts.append(f"{label} [{values}]")
    finding = (
        f"{amplitude_deg:g}° saccade at {fps:g} Hz, {m} in the first frames after landing: "
        + "; ".join(parts)
    )
    params = {
        "start": tuple(np.ravel(start)),
        "amplitude_deg": amplitude_deg,
        "direction_deg": direction_deg,
        "fps": fps,
        "latencies_s": tuple(latencies),
        "tracker_hz": tracker_hz,
        "saccade_ms": 1000 * duration,
        "onset_ms": 1000 * onset,
        "landing_ms": 1000 * landing,
        "fovea_deg": foveation.fovea_deg,
    }
    return _case("after_saccade", f"frames around a {amplitude_deg:g}° saccade", records, finding, params, t0)
