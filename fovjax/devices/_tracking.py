"""What to render from when tracking is good, late, bad or gone: the gaze fallback state machine.

`GazeTracker.step(now, samples, display_time)` is called once per frame with whatever samples
arrived -- ``source.drain()`` gives every sample received since the previous call, for threaded
and paced sources alike, or pass ``[source.latest()]`` -- and returns a `TrackingFrame`: the
per-eye gaze to render from, a state label, and how far to widen the fovea.

States (`FallbackPolicy` holds the times):

``ok``        the newest good sample is at most ``stale_after`` s old. Gaze = that sample
              (filtered, and predicted to ``display_time`` when given). Widening 0.
``holding``   no fresh good sample, but the last one is at most ``hold_for`` s old. Gaze = the
              last good gaze, unchanged foveation. Widening 0.
``degraded``  the last good sample is older than ``hold_for``. Gaze stays at the last good gaze
              and the fovea widens one step every ``widen_every`` s:
              ``step = ceil((age - hold_for) / widen_every)``, widening = step / widen_steps.
``lost``      step reached ``widen_steps`` (widening 1: render everything at full quality), or no
              good sample was ever seen (gaze at the display centre).

A sample is *bad* -- counted by reason, never rendered from -- when its timestamp is not finite or
lies more than ``max_future`` s after ``now`` (a broken clock), or when an eye fails the
`QualityFilter` (invalid, NaN, confidence below ``min_confidence``, off screen by more than
``max_offscreen``). With ``mirror_single_eye`` a sample with one good eye is used with that eye's
gaze for both (per-eye display coordinates of the two eyes differ only by vergence); otherwise it is
bad. Stale data, a disconnected port, garbage bytes, a silent tracker all show up the same way: no
new good sample, so the state walks ok -> holding -> degraded -> lost.

Recovery: from ``ok`` or ``holding`` one good sample is enough. Once the fovea has widened
(``degraded`` or ``lost``), ``recover_after`` consecutive good samples are needed before their gaze
is used and the widening drops back to 0 -- a flickering tracker does not make the fovea jump.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import cast

import numpy as np

from ._filters import (
    ExponentialMovingAverage,
    GazeFilter,
    GazePredictor,
    OneEuroFilter,
    QualityFilter,
    VelocityThresholdDetector,
)
from ._samples import DISPLAY_CENTRE, EyeGaze, GazeSample, HeadPose


class TrackingState(StrEnum):
    OK = "ok"
    HOLDING = "holding"
    DEGRADED = "degraded"
    LOST = "lost"

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class FallbackPolicy:
    """Times in seconds; see the module docstring for what each does."""

    stale_after: float = 0.05
    hold_for: float = 0.15
    widen_every: float = 0.10
    widen_steps: int = 4
    recover_after: int = 3
    min_confidence: float = 0.5
    max_offscreen: float = 0.1
    max_future: float = 0.05
    mirror_single_eye: bool = True

    def __post_init__(self):
        if not (0 <= self.stale_after <= self.hold_for):
            raise ValueError(
                f"FallbackPolicy: need 0 <= stale_after <= hold_for, got {self.stale_after}, {self.hold_for}"
            )
        if not self.widen_every > 0 or self.widen_steps < 1:
            raise ValueError(
                f"FallbackPolicy: need widen_every > 0 and widen_steps >= 1, "
                f"got {self.widen_every}, {self.widen_steps}"
            )
        if self.recover_after < 1:
            raise ValueError(f"FallbackPolicy: recover_after must be >= 1, got {self.recover_after}")

    @property
    def quality(self) -> QualityFilter:
        return QualityFilter(self.min_confidence, self.max_offscreen)

    def time_to_lost(self) -> float:
        """Seconds from the last good sample after which widening is 1 (step 1 starts right after
        ``hold_for``, each further step ``widen_every`` later)."""
        return self.hold_for + (self.widen_steps - 1) * self.widen_every


def widen_thresholds(omega0: float, omega1: float, widening: float, omega_full: float) -> tuple[float, float]:
    """Fovea (`omega0`) and periphery (`omega1`) eccentricity thresholds in degrees widened by
    `widening` in [0, 1] towards `omega_full`, an eccentricity covering the whole display: at 0 they
    are unchanged, at 1 both equal `omega_full`, so every pixel is foveal (full rendering)."""
    w = min(max(float(widening), 0.0), 1.0)
    if not (0 <= omega0 <= omega1 <= omega_full):
        raise ValueError(
            f"widen_thresholds: need 0 <= omega0 <= omega1 <= omega_full, "
            f"got {omega0}, {omega1}, {omega_full}"
        )
    return omega0 + w * (omega_full - omega0), omega1 + w * (omega_full - omega1)


@dataclass(frozen=True)
class TrackingFrame:
    """The tracker's answer for one frame (see `GazeTracker.step`)."""

    time: float
    left: tuple[float, float]
    right: tuple[float, float]
    state: TrackingState
    widening: float
    widening_step: int
    sample_age: float
    sample_timestamp: float
    prediction_horizon: float
    saccade: bool
    rejected: dict[str, int] = field(default_factory=dict)

    def thresholds(self, omega0: float, omega1: float, omega_full: float) -> tuple[float, float]:
        """This frame's widened (fovea, periphery) eccentricity thresholds; see `widen_thresholds`."""
        return widen_thresholds(omega0, omega1, self.widening, omega_full)

    def stats(self) -> dict:
        """Flat per-frame statistics for a session log."""
        return {
            "tracking_state": self.state.value,
            "widening": self.widening,
            "widening_step": self.widening_step,
            "gaze_age_s": self.sample_age,
            "gaze_left": list(self.left),
            "gaze_right": list(self.right),
            "prediction_s": self.prediction_horizon,
            "saccade": self.saccade,
        }


_DEFAULT_PREDICTOR = GazePredictor()
# Times are sums of floats; a boundary hit "exactly" should land on the side the docs promise.
_EPS = 1e-9


def _make_filter(smoothing) -> GazeFilter | None:
    if smoothing is None:
        return None
    if smoothing == "ema":
        return ExponentialMovingAverage()
    if smoothing == "one_euro":
        return OneEuroFilter()
    if callable(smoothing):
        return cast(GazeFilter, smoothing())  # a user's factory: used as the two above are
    raise ValueError(
        f"GazeTracker: smoothing must be None, 'ema', 'one_euro' or a factory, got {smoothing!r}"
    )


class GazeTracker:
    """The per-frame gaze state machine (module docstring), with optional smoothing (`smoothing`:
    None, ``"ema"``, ``"one_euro"`` or a zero-argument factory of a filter), I-VT saccade flag and
    constant-velocity prediction to the display time."""

    def __init__(
        self,
        policy: FallbackPolicy | None = None,
        *,
        smoothing=None,
        predictor: GazePredictor | None = _DEFAULT_PREDICTOR,
        saccade_threshold: float = 30.0,
        display_fov_deg: tuple[float, float] = (90.0, 90.0),
    ):
        self.policy = policy or FallbackPolicy()
        self.predictor = predictor
        self._quality = self.policy.quality
        self._filters = {eye: _make_filter(smoothing) for eye in ("left", "right")}
        self._ivt = VelocityThresholdDetector(saccade_threshold, display_fov_deg)
        self.rejected: dict[str, int] = {"clock": 0, "invalid": 0, "nan": 0, "confidence": 0, "offscreen": 0}
        self.accepted = 0
        self.reset()

    def reset(self) -> None:
        """Forget everything: as if no sample had ever arrived."""
        self._last_seen = -math.inf
        self._confirmed: GazeSample | None = None
        self._gaze: dict[str, tuple[float, float]] = {}
        self._velocity: dict[str, np.ndarray] = {"left": np.zeros(2), "right": np.zeros(2)}
        self._pending: list[GazeSample] = []
        self._step = self.policy.widen_steps
        for f in self._filters.values():
            if f is not None:
                f.reset()
        self._ivt.reset()

    # -- classification ---------------------------------------------------------------------
    def _clean(self, sample: GazeSample, now: float) -> GazeSample | None:
        """The sample with both eyes usable, or None (counting why)."""
        t = sample.timestamp
        if not math.isfinite(t) or t > now + self.policy.max_future:
            self.rejected["clock"] += 1
            return None
        reasons = {eye: self._quality.reason(sample.eye(eye)) for eye in ("left", "right")}
        for r in reasons.values():
            if r is not None:
                self.rejected[r] += 1
        good = [eye for eye, r in reasons.items() if r is None]
        if len(good) == 2:
            return sample
        if len(good) == 1 and self.policy.mirror_single_eye:
            eye = sample.eye(good[0])
            return GazeSample(t, eye, eye, sample.device_time)
        return None

    # -- filtering --------------------------------------------------------------------------
    def _use(self, sample: GazeSample) -> None:
        previous = self._confirmed
        gap = previous is None or sample.timestamp - previous.timestamp > self.policy.hold_for
        if gap:
            for f in self._filters.values():
                if f is not None:
                    f.reset()
            self._ivt.reset()
        for name in ("left", "right"):
            eye: EyeGaze = sample.eye(name)
            raw = np.array([eye.x, eye.y])
            f = self._filters[name]
            if f is not None:
                xy = f(sample.timestamp, raw)
                velocity = np.asarray(f.velocity, dtype=float)
            else:
                xy = raw
                if gap or previous is None or sample.timestamp <= previous.timestamp:
                    velocity = np.zeros(2)
                else:
                    old = np.asarray(self._gaze[name])
                    velocity = (raw - old) / (sample.timestamp - previous.timestamp)
            self._gaze[name] = (float(xy[0]), float(xy[1]))
            self._velocity[name] = velocity
        mid = ((sample.left.x + sample.right.x) / 2.0, (sample.left.y + sample.right.y) / 2.0)
        self._ivt(sample.timestamp, mid)
        self._confirmed = sample
        self.accepted += 1

    # -- the frame --------------------------------------------------------------------------
    def step(self, now: float, samples=(), display_time: float | None = None) -> TrackingFrame:
        """Feed the samples that arrived (any iterable, or a single sample, or None; ones already
        seen are ignored, so passing ``source.latest()`` every frame is fine) and get the gaze to
        render the frame shown at `display_time` (default `now`) with."""
        if samples is None:
            samples = ()
        elif isinstance(samples, GazeSample):
            samples = (samples,)
        policy = self.policy
        fresh = []
        for s in samples:
            if s is None:
                continue
            if not math.isfinite(s.timestamp):
                self.rejected["clock"] += 1
                self._pending.clear()
            elif s.timestamp > self._last_seen:
                fresh.append(s)
        fresh.sort(key=lambda s: s.timestamp)
        for sample in fresh:
            if sample.timestamp <= now + policy.max_future:
                self._last_seen = sample.timestamp
            clean = self._clean(sample, now)
            if clean is None:
                self._pending.clear()
                continue
            self._pending.append(clean)
            needed = 1 if self._step == 0 else policy.recover_after
            if len(self._pending) >= needed:
                for s in self._pending:
                    self._use(s)
                self._pending.clear()
                self._step = 0

        confirmed = self._confirmed
        if confirmed is None:
            self._step = policy.widen_steps
            return TrackingFrame(
                time=now,
                left=DISPLAY_CENTRE,
                right=DISPLAY_CENTRE,
                state=TrackingState.LOST,
                widening=1.0,
                widening_step=self._step,
                sample_age=math.inf,
                sample_timestamp=math.nan,
                prediction_horizon=0.0,
                saccade=False,
                rejected=dict(self.rejected),
            )
        age = now - confirmed.timestamp
        if age <= policy.hold_for + _EPS:
            step = 0
            state = TrackingState.OK if age <= policy.stale_after + _EPS else TrackingState.HOLDING
        else:
            step = min(policy.widen_steps, math.ceil((age - policy.hold_for) / policy.widen_every - 1e-6))
            step = max(step, 1)
            state = TrackingState.LOST if step >= policy.widen_steps else TrackingState.DEGRADED
        self._step = step
        left, right = self._gaze["left"], self._gaze["right"]
        horizon = 0.0
        if state is TrackingState.OK and self.predictor is not None and display_time is not None:
            horizon = self.predictor.horizon(confirmed.timestamp, display_time)
            left = self.predictor(left, self._velocity["left"], confirmed.timestamp, display_time)
            right = self.predictor(right, self._velocity["right"], confirmed.timestamp, display_time)
        return TrackingFrame(
            time=now,
            left=left,
            right=right,
            state=state,
            widening=step / policy.widen_steps,
            widening_step=step,
            sample_age=age,
            sample_timestamp=confirmed.timestamp,
            prediction_horizon=horizon,
            saccade=bool(self._ivt.in_saccade) and state is TrackingState.OK,
            rejected=dict(self.rejected),
        )


@dataclass(frozen=True)
class HeadFrame:
    time: float
    yaw: float
    pitch: float
    roll: float
    state: TrackingState
    sample_age: float


class HeadTracker:
    """Head-pose fallback: the newest valid finite pose is used (``ok`` while at most
    `stale_after` s old, ``holding`` until `hold_for`); after that the last pose is kept and the
    state is ``lost`` -- the renderer keeps the last view instead of jumping. Before any valid
    pose the pose is (0, 0, 0) and the state ``lost``."""

    def __init__(self, stale_after: float = 0.05, hold_for: float = 0.5, max_future: float = 0.05):
        if not 0 <= stale_after <= hold_for:
            raise ValueError(f"HeadTracker: need 0 <= stale_after <= hold_for, got {stale_after}, {hold_for}")
        self.stale_after, self.hold_for, self.max_future = stale_after, hold_for, max_future
        self._pose: HeadPose | None = None
        self.rejected = 0

    def step(self, now: float, samples=()) -> HeadFrame:
        if samples is None:
            samples = ()
        elif isinstance(samples, HeadPose):
            samples = (samples,)
        for pose in samples:
            if pose is None or (self._pose is not None and pose.timestamp <= self._pose.timestamp):
                continue
            if (
                not (pose.valid and pose.is_finite() and math.isfinite(pose.timestamp))
                or pose.timestamp > now + self.max_future
            ):
                self.rejected += 1
                continue
            self._pose = pose
        if self._pose is None:
            return HeadFrame(now, 0.0, 0.0, 0.0, TrackingState.LOST, math.inf)
        age = now - self._pose.timestamp
        state = (
            TrackingState.OK
            if age <= self.stale_after
            else TrackingState.HOLDING
            if age <= self.hold_for
            else TrackingState.LOST
        )
        return HeadFrame(now, self._pose.yaw, self._pose.pitch, self._pose.roll, state, age)
