"""Gaze filtering and latency compensation: quality check, exponential moving average, One Euro
filter, velocity-threshold (I-VT) saccade detection and constant-velocity prediction.

All filters take the sample time explicitly (seconds) so they work with irregular sample spacing,
replays and injected clocks, and keep per-call state small; `reset()` forgets the past (used after
a tracking gap so nothing is smoothed across it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from ._samples import EyeGaze


@runtime_checkable
class GazeFilter(Protocol):
    """A smoothing filter of one eye's gaze: `filter(t, xy)` the smoothed point, `velocity` its
    latest velocity (per second), `reset()` forgets the past (`ExponentialMovingAverage`,
    `OneEuroFilter`, or a user's factory's product)."""

    velocity: np.ndarray

    def __call__(self, t: float, x) -> np.ndarray: ...

    def reset(self) -> None: ...


@dataclass(frozen=True)
class QualityFilter:
    """Accept an eye's gaze only when the source marked it valid, it is finite, its confidence is
    at least `min_confidence`, and it lies within `max_offscreen` of the display ([0, 1]^2)."""

    min_confidence: float = 0.5
    max_offscreen: float = 0.1

    def reason(self, eye: EyeGaze) -> str | None:
        """None when the eye is acceptable, else why not: invalid, nan, confidence, offscreen."""
        if not eye.valid:
            return "invalid"
        if not eye.is_finite():
            return "nan"
        if eye.confidence < self.min_confidence:
            return "confidence"
        lo, hi = -self.max_offscreen, 1.0 + self.max_offscreen
        if not (lo <= eye.x <= hi and lo <= eye.y <= hi):
            return "offscreen"
        return None

    def accepts(self, eye: EyeGaze) -> bool:
        return self.reason(eye) is None


class ExponentialMovingAverage:
    """``y += a (x - y)`` with ``a = 1 - exp(-dt / time_constant)``, so the smoothing is the same
    in seconds whatever the sample rate (``a`` is the classic fixed alpha at a fixed rate)."""

    def __init__(self, time_constant: float = 0.02):
        if not time_constant > 0:
            raise ValueError(f"ExponentialMovingAverage: time_constant must be > 0 s, got {time_constant}")
        self.time_constant = time_constant
        self.reset()

    def reset(self) -> None:
        self._t: float | None = None
        self._y: np.ndarray | None = None
        self.velocity = np.zeros(2)

    def __call__(self, t: float, x) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if self._y is None or self._t is None or t <= self._t:
            if self._y is None:
                self._y = x.copy()
                self.velocity = np.zeros_like(x)
            self._t = t if self._t is None else max(self._t, t)
            return self._y.copy()
        dt = t - self._t
        a = 1.0 - math.exp(-dt / self.time_constant)
        y = self._y + a * (x - self._y)
        self.velocity = (y - self._y) / dt
        self._y, self._t = y, t
        return y.copy()


def _smoothing_factor(cutoff: float, dt: float) -> float:
    tau = 1.0 / (2.0 * math.pi * cutoff)
    return 1.0 / (1.0 + tau / dt)


class OneEuroFilter:
    """The One Euro filter (Casiez, Roussel and Vogel, CHI 2012), per coordinate.

    A first-order low-pass whose cutoff rises with speed: ``cutoff = min_cutoff + beta * |dx/dt|``,
    the derivative itself low-passed at `d_cutoff`. Low `min_cutoff` (Hz) removes jitter during
    fixations; higher `beta` (per unit/s of the signal, here normalised display units) removes lag
    during saccades. Defaults are starting points for normalised gaze at 60--500 Hz: tune as the
    paper says (beta 0 first, lower min_cutoff until jitter is gone, then raise beta until lag is).
    """

    def __init__(self, min_cutoff: float = 1.0, beta: float = 0.5, d_cutoff: float = 1.0):
        if not (min_cutoff > 0 and d_cutoff > 0 and beta >= 0):
            raise ValueError(
                f"OneEuroFilter: need min_cutoff > 0, d_cutoff > 0, beta >= 0, "
                f"got {min_cutoff}, {d_cutoff}, {beta}"
            )
        self.min_cutoff = min_cutoff
        self.beta = beta
        self.d_cutoff = d_cutoff
        self.reset()

    def reset(self) -> None:
        self._t: float | None = None
        self._x: np.ndarray | None = None
        self.velocity = np.zeros(2)

    def __call__(self, t: float, x) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if self._x is None or self._t is None:
            self._x, self._t = x.copy(), t
            self.velocity = np.zeros_like(x)
            return x.copy()
        dt = t - self._t
        if dt <= 0:
            return self._x.copy()
        dx = (x - self._x) / dt
        a_d = _smoothing_factor(self.d_cutoff, dt)
        self.velocity = self.velocity + a_d * (dx - self.velocity)
        cutoff = self.min_cutoff + self.beta * np.abs(self.velocity)
        a = 1.0 / (1.0 + (1.0 / (2.0 * np.pi * cutoff)) / dt)
        self._x = self._x + a * (x - self._x)
        self._t = t
        return self._x.copy()


def angular_speed(xy0, xy1, dt: float, display_fov_deg: tuple[float, float]) -> float:
    """Speed in deg/s between two normalised positions `dt` s apart, with the linear
    normalised-to-degree scale `display_fov_deg` (horizontal, vertical)."""
    if not dt > 0:
        return 0.0
    dx = (xy1[0] - xy0[0]) * display_fov_deg[0]
    dy = (xy1[1] - xy0[1]) * display_fov_deg[1]
    return math.hypot(dx, dy) / dt


class VelocityThresholdDetector:
    """I-VT saccade detection (Salvucci and Goldberg 2000): a sample is in a saccade when the
    point-to-point angular speed from the previous sample exceeds `threshold` deg/s (30 deg/s by
    default, the usual I-VT setting)."""

    def __init__(self, threshold: float = 30.0, display_fov_deg: tuple[float, float] = (90.0, 90.0)):
        if not threshold > 0:
            raise ValueError(f"VelocityThresholdDetector: threshold must be > 0 deg/s, got {threshold}")
        self.threshold = threshold
        self.display_fov_deg = display_fov_deg
        self.reset()

    def reset(self) -> None:
        self._t: float | None = None
        self._xy: tuple[float, float] | None = None
        self.speed = 0.0
        self.in_saccade = False

    def __call__(self, t: float, xy) -> bool:
        xy = (float(xy[0]), float(xy[1]))
        if self._t is not None and t > self._t:
            self.speed = angular_speed(self._xy, xy, t - self._t, self.display_fov_deg)
            self.in_saccade = bool(self.speed > self.threshold)
        self._t, self._xy = t, xy
        return self.in_saccade


def ivt_classify(
    t, xy, threshold: float = 30.0, display_fov_deg: tuple[float, float] = (90.0, 90.0)
) -> np.ndarray:
    """Vectorised I-VT over a whole trace: ``t`` shape (N,), ``xy`` shape (N, 2) -> bool (N,),
    True where the speed from the previous sample exceeds `threshold` (the first sample is False)."""
    t = np.asarray(t, dtype=float)
    xy = np.asarray(xy, dtype=float)
    if t.ndim != 1 or xy.shape != (t.shape[0], 2):
        raise ValueError(
            f"ivt_classify: need t of shape (N,) and xy of shape (N, 2), got {t.shape}, {xy.shape}"
        )
    out = np.zeros(t.shape[0], dtype=bool)
    if t.shape[0] < 2:
        return out
    dt = np.diff(t)
    d = np.diff(xy, axis=0) * np.asarray(display_fov_deg, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        speed = np.where(dt > 0, np.hypot(d[:, 0], d[:, 1]) / np.where(dt > 0, dt, 1.0), 0.0)
    out[1:] = speed > threshold
    return out


@dataclass(frozen=True)
class GazePredictor:
    """Constant-velocity extrapolation of the gaze to the frame's display time.

    ``predicted = position + velocity * h`` with ``h = display_time - sample_time`` held to
    ``[0, max_horizon]`` (extrapolating further mostly adds error), and the result kept within
    `max_offscreen` of the display.
    """

    max_horizon: float = 0.05
    max_offscreen: float = 0.1

    def horizon(self, sample_time: float, display_time: float) -> float:
        return min(max(display_time - sample_time, 0.0), self.max_horizon)

    def __call__(self, xy, velocity, sample_time: float, display_time: float) -> tuple[float, float]:
        h = self.horizon(sample_time, display_time)
        lo, hi = -self.max_offscreen, 1.0 + self.max_offscreen
        x = min(max(float(xy[0]) + float(velocity[0]) * h, lo), hi)
        y = min(max(float(xy[1]) + float(velocity[1]) * h, lo), hi)
        return x, y
