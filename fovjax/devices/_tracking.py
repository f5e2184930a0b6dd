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
``max_offscreen``). Stale data, a disconnected port, garbage bytes, a silent tracker all show up
the same way: no new good sample, so the state walks ok -> holding -> degraded -> lost.

One good eye (``FallbackPolicy.single_eye``): each eye's gaze is a position on that eye's own
display, and the two displays need not be parallel -- on the thesis's rig (eyes turned 13°
outwards) a far point straight ahead is at x = 0.615 in the left eye and 0.385 in the right, so
one eye's position copied to the other would put that eye's fovea about 26° from where it looks.

``"keep"``    (default; the thesis's rule, Fig 45: each eye's point is updated only when that
              eye's quality code is good) the sample is used for its good eye; the other eye
              keeps its own last good gaze (standing still: no velocity, no prediction). An eye
              that never had a good sample has nothing to keep: such a sample is bad.
``"map"``     the other eye's gaze is the good eye's mapped through the rig: the point
              ``vergence_distance`` along the good eye's ray, projected into the other eye
              (`RigGeometry.transfer`; the tracker's ``geometry``, which `run_session` sets from
              its renderer's rig). Right when the eyes verge at about that distance.
``"reject"``  the sample is bad.

Recovery: from ``ok`` or ``holding`` one good sample is enough. Once the fovea has widened
(``degraded`` or ``lost``), ``recover_after`` consecutive good samples are needed before their gaze
is used and the widening drops back to 0 -- a flickering tracker does not make the fovea jump.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import InitVar, dataclass, field
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
from ._geometry import RigGeometry
from ._samples import DISPLAY_CENTRE, EyeGaze, GazeSample, HeadPose


class TrackingState(StrEnum):
    OK = "ok"
    HOLDING = "holding"
    DEGRADED = "degraded"
    LOST = "lost"

    def __str__(self) -> str:
        return self.value


SINGLE_EYE_RULES = ("keep", "map", "reject")


@dataclass(frozen=True)
class FallbackPolicy:
    """What the `GazeTracker` does when tracking is late, bad or gone (module docstring).

    The hold-and-widen states are fovjax's: the thesis renders from the last gaze it received,
    with no hold time and no widening. Its one-eye rule is ``single_eye="keep"``, the default.

    Args:
        stale_after: seconds a good sample counts as fresh (state ``ok``).
        hold_for: seconds the last good gaze is held unchanged (``holding``).
        widen_every: seconds per widening step after `hold_for` (``degraded``).
        widen_steps: steps to full quality (``lost``).
        recover_after: consecutive good samples needed once the fovea has widened.
        min_confidence: an eye's confidence below this is bad.
        max_offscreen: an eye farther than this outside the display ([0, 1]^2) is bad.
        max_future: a timestamp more than this after `now` is a broken clock.
        single_eye: a sample with one good eye: ``"keep"`` the other eye's own last good gaze
            (the thesis's Fig 45), ``"map"`` the good eye's gaze through the rig into the other
            eye, or ``"reject"`` the sample.
        vergence_distance: with ``"map"``, how far along the good eye's ray the eyes are taken
            to converge, in the rig's units (`RigGeometry.ipd`'s; ``math.inf``: parallel).
        mirror_single_eye: deprecated (it copied the good eye's display position to the other
            eye, wrong on a toed-out rig): True means ``single_eye="keep"``, False
            ``"reject"``.

    Raises:
        ValueError: times out of order, fewer than one step or recovery sample, an unknown
            `single_eye`, a `vergence_distance` that is not > 0.
    """

    stale_after: float = 0.05
    hold_for: float = 0.15
    widen_every: float = 0.10
    widen_steps: int = 4
    recover_after: int = 3
    min_confidence: float = 0.5
    max_offscreen: float = 0.1
    max_future: float = 0.05
    single_eye: str = "keep"
    vergence_distance: float = math.inf
    mirror_single_eye: InitVar[bool | None] = None

    def __post_init__(self, mirror_single_eye: bool | None):
        if mirror_single_eye is not None:
            replacement = "keep" if mirror_single_eye else "reject"
            warnings.warn(
                f"FallbackPolicy(mirror_single_eye={mirror_single_eye!r}) is deprecated: copying one eye's "
                f"display position to the other is wrong on a toed-out rig; using "
                f"single_eye={replacement!r} (or 'map': the good eye's gaze through the rig)",
                DeprecationWarning,
                stacklevel=3,
            )
            object.__setattr__(self, "single_eye", replacement)
        if self.single_eye not in SINGLE_EYE_RULES:
            raise ValueError(
                f"FallbackPolicy: single_eye must be one of {SINGLE_EYE_RULES}, got {self.single_eye!r}"
            )
        try:
            distance = float(self.vergence_distance)
        except (TypeError, ValueError):
            distance = math.nan
        if not distance > 0:
            raise ValueError(
                f"FallbackPolicy: vergence_distance must be > 0 (math.inf: parallel eyes), "
                f"got {self.vergence_distance!r}"
            )
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
    # The eye whose gaze the newest sample used did not measure ("left" or "right": kept or
    # mapped, `FallbackPolicy.single_eye`); None when both were measured.
    unmeasured_eye: str | None = None

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
            "unmeasured_eye": self.unmeasured_eye,
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
    constant-velocity prediction to the display time.

    `geometry` (a `RigGeometry`) is the rig the gaze is on, which ``single_eye="map"`` maps
    through; `run_session` sets it from its renderer's rig when it is None. A ``"map"``
    policy with no geometry is refused at the first `step`.
    """

    def __init__(
        self,
        policy: FallbackPolicy | None = None,
        *,
        smoothing=None,
        predictor: GazePredictor | None = _DEFAULT_PREDICTOR,
        saccade_threshold: float = 30.0,
        display_fov_deg: tuple[float, float] = (90.0, 90.0),
        geometry: RigGeometry | None = None,
    ):
        if policy is not None and not isinstance(policy, FallbackPolicy):
            raise TypeError(f"GazeTracker: policy must be a FallbackPolicy, got {type(policy).__name__}")
        if geometry is not None and not isinstance(geometry, RigGeometry):
            raise TypeError(
                f"GazeTracker: geometry must be a fovjax.devices.RigGeometry "
                f"(RigGeometry.from_rig(rig)), got {type(geometry).__name__}"
            )
        self.policy = policy or FallbackPolicy()
        self.geometry = geometry
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
        self._pending: list[tuple[GazeSample, tuple[str, ...], str | None]] = []
        self._unmeasured: str | None = None
        self._eye_time: dict[str, float] = {}
        self._step = self.policy.widen_steps
        for f in self._filters.values():
            if f is not None:
                f.reset()
        self._ivt.reset()

    # -- classification ---------------------------------------------------------------------
    def _clean(self, sample: GazeSample, now: float) -> tuple[GazeSample, tuple[str, ...], str | None] | None:
        """The sample to use, the eyes whose gaze it gives and the eye it did not measure (or
        None), or None when it is bad (counting why). With one good eye the other is filled in
        by the policy's `single_eye` rule: kept (not taken from the sample) or mapped through
        the rig (taken from the sample, which holds the mapped gaze)."""
        t = sample.timestamp
        if not math.isfinite(t) or t > now + self.policy.max_future:
            self.rejected["clock"] += 1
            return None
        reasons = {eye: self._quality.reason(sample.eye(eye)) for eye in ("left", "right")}
        for r in reasons.values():
            if r is not None:
                self.rejected[r] += 1
        good = tuple(eye for eye, r in reasons.items() if r is None)
        if len(good) == 2:
            return sample, good, None
        if len(good) == 0 or self.policy.single_eye == "reject":
            return None
        (measured,) = good
        other = "right" if measured == "left" else "left"
        if self.policy.single_eye == "keep":
            # Nothing to keep for an eye never seen: its gaze would be made up.
            seen = other in self._gaze or any(other in eyes for _, eyes, _ in self._pending)
            return (sample, good, other) if seen else None
        eye = sample.eye(measured)
        if self.geometry is None:  # not reached: `step` checks it first
            raise ValueError("GazeTracker: single_eye='map' needs geometry=")
        x, y = self.geometry.transfer((eye.x, eye.y), measured, self.policy.vergence_distance)
        if not (math.isfinite(x) and math.isfinite(y)):
            return None
        mapped = EyeGaze(float(x), float(y), eye.confidence, True)
        left, right = (eye, mapped) if measured == "left" else (mapped, eye)
        return GazeSample(t, left, right, sample.device_time), ("left", "right"), other

    # -- filtering --------------------------------------------------------------------------
    def _use(self, sample: GazeSample, measured: tuple[str, ...], unmeasured: str | None) -> None:
        previous = self._confirmed
        gap = previous is None or sample.timestamp - previous.timestamp > self.policy.hold_for
        if gap:
            self._ivt.reset()
        used = {}
        for name in ("left", "right"):
            if name not in measured:  # a kept eye stands still where it was last seen
                used[name] = self._gaze[name]
                self._velocity[name] = np.zeros(2)
                continue
            eye: EyeGaze = sample.eye(name)
            used[name] = (eye.x, eye.y)
            raw = np.array([eye.x, eye.y])
            # Each eye's own gap: an eye kept for a while is not smoothed or differentiated
            # across the time it was not seen.
            since = sample.timestamp - self._eye_time.get(name, -math.inf)
            eye_gap = gap or not since <= self.policy.hold_for
            f = self._filters[name]
            if f is not None:
                if eye_gap:
                    f.reset()
                xy = f(sample.timestamp, raw)
                velocity = np.asarray(f.velocity, dtype=float)
            else:
                xy = raw
                if eye_gap or since <= 0:
                    velocity = np.zeros(2)
                else:
                    velocity = (raw - np.asarray(self._gaze[name])) / since
            self._gaze[name] = (float(xy[0]), float(xy[1]))
            self._velocity[name] = velocity
            self._eye_time[name] = sample.timestamp
        (lx, ly), (rx, ry) = used["left"], used["right"]
        self._ivt(sample.timestamp, ((lx + rx) / 2.0, (ly + ry) / 2.0))
        self._confirmed = sample
        self._unmeasured = unmeasured
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
        if policy.single_eye == "map" and self.geometry is None:
            raise ValueError(
                "GazeTracker: FallbackPolicy(single_eye='map') maps the good eye's gaze through the rig, "
                "but the tracker has no geometry: GazeTracker(policy, geometry=RigGeometry.from_rig(rig)) "
                "(run_session sets it from its renderer's rig)"
            )
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
                for pending in self._pending:
                    self._use(*pending)
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
            unmeasured_eye=self._unmeasured,
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
