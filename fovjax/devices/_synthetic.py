"""Synthetic gaze: fixed points, scanpaths of fixations and saccades, smooth pursuit.

Everything here is generated, not measured; recordings made from it say ``"synthetic": true``.

Scanpath model
--------------
Fixation durations are drawn from a gamma distribution with mean `fixation_mean` (0.218 s by
default, the mean fixation duration the issue asks for) and shape `fixation_shape` (4: a
right-skewed distribution; an assumption, change it freely). Each saccade goes to a new target
drawn uniformly inside the display less a margin, redrawn while its amplitude exceeds
`max_amplitude_deg`. Its duration follows the linear amplitude--duration main sequence
``D = 2.2 ms/deg * A + 21 ms`` (Carpenter 1988), held to the 30--120 ms range, and its position
follows the minimum-jerk profile ``10 s^3 - 15 s^4 + 6 s^5``, whose peak velocity is
``1.875 A / D``: it rises with amplitude and saturates, the main sequence's peak-velocity shape
(e.g. 436 deg/s at 10 deg, 688 deg/s at 40 deg). Amplitudes in degrees use a linear
normalised-coordinate-to-degree scale from `display_fov_deg` (an assumption about the HMD; set it
for yours).
"""

from __future__ import annotations

import bisect
import math
import time
from collections.abc import Callable, Sequence

import numpy as np

from ._correction import GazeCorrection
from ._geometry import RigGeometry, as_pair
from ._paced import PacedSource
from ._samples import EyeGaze, GazeSample, HeadPose
from ._source import Clock

MAIN_SEQUENCE_SLOPE = 0.0022  # s per degree (Carpenter 1988)
MAIN_SEQUENCE_INTERCEPT = 0.021  # s
SACCADE_DURATION_RANGE = (0.030, 0.120)  # s
MIN_JERK_PEAK = 1.875  # peak of d/ds of 10s^3 - 15s^4 + 6s^5, at s = 1/2


def saccade_duration(amplitude_deg: float) -> float:
    """Main-sequence duration in seconds of a saccade of `amplitude_deg` degrees."""
    d = MAIN_SEQUENCE_INTERCEPT + MAIN_SEQUENCE_SLOPE * abs(amplitude_deg)
    return min(max(d, SACCADE_DURATION_RANGE[0]), SACCADE_DURATION_RANGE[1])


def saccade_peak_velocity(amplitude_deg: float) -> float:
    """Peak angular velocity (deg/s) of the minimum-jerk saccade of that amplitude."""
    return MIN_JERK_PEAK * abs(amplitude_deg) / saccade_duration(amplitude_deg)


def min_jerk(s):
    s = np.clip(s, 0.0, 1.0)
    return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)


class GazeModel:
    """A gaze trajectory: ``position(t) -> (x, y)`` normalised, for t >= 0 seconds."""

    def position(self, t: float) -> tuple[float, float]:
        raise NotImplementedError


class FixedPoints(GazeModel):
    """Look at each point for `dwell` seconds in turn (jumping instantly), cycling forever."""

    def __init__(self, points: Sequence[tuple[float, float]] = ((0.5, 0.5),), dwell: float = 1.0):
        if not points:
            raise ValueError("FixedPoints: need at least one point")
        if not dwell > 0:
            raise ValueError(f"FixedPoints: dwell must be > 0 s, got {dwell}")
        self.points = [(float(x), float(y)) for x, y in points]
        self.dwell = dwell

    def position(self, t: float) -> tuple[float, float]:
        return self.points[int(t // self.dwell) % len(self.points)]


class TargetFollower(GazeModel):
    """A synthetic observer who looks at whatever target was presented last: pass its
    `present` as a calibration's ``present`` (`calibrate`); ``position(t)`` is that target's
    position (a `CalibrationTarget`'s ``xy``, or any (x, y)) from then on, `start` before any.
    The eye arrives at once: a calibration's settle time stands for a real eye's latency and
    saccade."""

    def __init__(self, start: tuple[float, float] = (0.5, 0.5)):
        self.target = as_pair(start, "TargetFollower: start")
        self.presented = 0

    def present(self, target) -> None:
        """Look at `target` (a `CalibrationTarget` or a display position (x, y)) from now on."""
        self.target = as_pair(getattr(target, "xy", target), "TargetFollower.present")
        self.presented += 1

    def position(self, t: float) -> tuple[float, float]:
        return self.target


class SmoothPursuit(GazeModel):
    """Follow a target on an ellipse around `centre` with semi-axes `radius`, `frequency` laps per
    second (``path="circle"``), or back and forth horizontally (``path="horizontal"``)."""

    def __init__(
        self,
        centre: tuple[float, float] = (0.5, 0.5),
        radius: tuple[float, float] = (0.25, 0.25),
        frequency: float = 0.1,
        path: str = "circle",
    ):
        if path not in ("circle", "horizontal"):
            raise ValueError(f"SmoothPursuit: path must be 'circle' or 'horizontal', got {path!r}")
        self.centre = centre
        self.radius = radius
        self.frequency = frequency
        self.path = path

    def position(self, t: float) -> tuple[float, float]:
        phase = 2.0 * math.pi * self.frequency * t
        if self.path == "circle":
            return self.centre[0] + self.radius[0] * math.cos(phase), self.centre[1] + self.radius[
                1
            ] * math.sin(phase)
        return self.centre[0] + self.radius[0] * math.sin(phase), self.centre[1]


class Scanpath(GazeModel):
    """Fixations and main-sequence saccades with an explicit seed (see the module docstring).

    The schedule is built lazily and deterministically from `seed`: the same seed gives the same
    scanpath whatever the order of queries.
    """

    def __init__(
        self,
        seed: int,
        *,
        fixation_mean: float = 0.218,
        fixation_shape: float = 4.0,
        display_fov_deg: tuple[float, float] = (90.0, 90.0),
        margin: float = 0.1,
        max_amplitude_deg: float = 40.0,
        start: tuple[float, float] = (0.5, 0.5),
    ):
        if not fixation_mean > 0 or not fixation_shape > 0:
            raise ValueError(
                f"Scanpath: fixation_mean and fixation_shape must be > 0, "
                f"got {fixation_mean}, {fixation_shape}"
            )
        if not 0 <= margin < 0.5:
            raise ValueError(f"Scanpath: margin must be in [0, 0.5), got {margin}")
        self.seed = seed
        self.fixation_mean = fixation_mean
        self.fixation_shape = fixation_shape
        self.display_fov_deg = display_fov_deg
        self.margin = margin
        self.max_amplitude_deg = max_amplitude_deg
        self._rng = np.random.default_rng(seed)
        # Segment k spans [starts[k], starts[k+1]); kind 0 = fixation at p0, 1 = saccade p0 -> p1.
        self.starts: list[float] = [0.0]
        self.kinds: list[int] = []
        self.p0: list[tuple[float, float]] = []
        self.p1: list[tuple[float, float]] = []
        self.amplitudes: list[float] = []
        self._here = (float(start[0]), float(start[1]))
        self._next_is_fixation = True

    def amplitude_deg(self, a: tuple[float, float], b: tuple[float, float]) -> float:
        return math.hypot((b[0] - a[0]) * self.display_fov_deg[0], (b[1] - a[1]) * self.display_fov_deg[1])

    def _extend(self) -> None:
        t = self.starts[-1]
        if self._next_is_fixation:
            duration = float(self._rng.gamma(self.fixation_shape, self.fixation_mean / self.fixation_shape))
            self.kinds.append(0)
            self.p0.append(self._here)
            self.p1.append(self._here)
            self.amplitudes.append(0.0)
        else:
            lo, hi = self.margin, 1.0 - self.margin
            for _ in range(1000):
                target = (float(self._rng.uniform(lo, hi)), float(self._rng.uniform(lo, hi)))
                amplitude = self.amplitude_deg(self._here, target)
                if amplitude <= self.max_amplitude_deg:
                    break
            duration = saccade_duration(amplitude)
            self.kinds.append(1)
            self.p0.append(self._here)
            self.p1.append(target)
            self.amplitudes.append(amplitude)
            self._here = target
        self.starts.append(t + duration)
        self._next_is_fixation = not self._next_is_fixation

    def _segment(self, t: float) -> int:
        while self.starts[-1] <= t:
            self._extend()
        return bisect.bisect_right(self.starts, t) - 1

    def position(self, t: float) -> tuple[float, float]:
        k = self._segment(max(t, 0.0))
        if self.kinds[k] == 0:
            return self.p0[k]
        s = (t - self.starts[k]) / (self.starts[k + 1] - self.starts[k])
        w = float(min_jerk(s))
        (x0, y0), (x1, y1) = self.p0[k], self.p1[k]
        return x0 + (x1 - x0) * w, y0 + (y1 - y0) * w

    def in_saccade(self, t: float) -> bool:
        return self.kinds[self._segment(max(t, 0.0))] == 1

    def segments_until(self, t: float) -> list[tuple[str, float, float, float]]:
        """(kind, start, end, amplitude_deg) of every segment starting before `t`."""
        self._segment(t)
        return [
            ("fixation" if kind == 0 else "saccade", self.starts[k], self.starts[k + 1], self.amplitudes[k])
            for k, kind in enumerate(self.kinds)
            if self.starts[k] < t
        ]


# The synthetic gaze source's default sampling rate (Hz): an idealised tracker, twice the
# thesis's fastest ViewPoint setting (60 Hz; see `SyntheticGazeSource`).
DEFAULT_GAZE_RATE = 120.0


class SyntheticGazeSource(PacedSource):
    """Gaze samples at `rate` Hz from a `GazeModel`.

    Where each eye looks: with a `geometry` (a `RigGeometry`, e.g.
    ``RigGeometry.from_rig(rig)``) the model's point is a position on the rig's cyclopean display
    (a direction from the head, `RigGeometry.fixation`), and each eye's gaze is the display
    position of the point `fixation_distance` away that way, in that eye's own display (rig
    units; ``math.inf``: infinitely far). On the thesis's rig the point straight ahead is at
    x = 0.615 in the left eye and 0.385 in the right. Without a geometry both eyes are at the
    model's point -- true only of a rig whose displays are parallel, looking infinitely far --
    and a non-zero `vergence_offset` moves the left eye's point right and the right eye's left by
    that much, as a near target does.

    `distortion` (a `GazeCorrection`) moves each eye's position by that eye's affine map before
    the noise: a tracker with a known systematic error, for testing a calibration.

    `duration` ends the stream (None: endless). `noise_sd` adds seeded Gaussian noise (normalised
    units) per eye; `dropouts` lists ``(start, end)`` intervals of the timeline with no samples at
    all -- a silent tracker, for exercising the fallback. Pacing as in every `PacedSource`:
    ``speed=1.0`` real time on `clock`, ``None`` as fast as read with timestamps
    ``start_time + i / rate``.

    The defaults are an idealised tracker, not the thesis's: 120 Hz (`DEFAULT_GAZE_RATE`) and
    no noise, where the thesis's ViewPoint tracker ran at 60 or 30 Hz (selectable) with
    0.25°-1.0° accuracy (§2.1.3). For that tracker pass ``rate=60`` (or 30) and a `noise_sd` of
    the accuracy in normalised units (degrees over the display's field of view, e.g.
    0.5 / 64 vertically on the SX111).

    Raises:
        ValueError: a rate or duration that is not > 0, a `fixation_distance` that is not > 0,
            a `vergence_offset` together with a `geometry` (the geometry gives each eye's
            point).
        TypeError: a `geometry` that is not a `RigGeometry`.
    """

    kind = "gaze"

    def __init__(
        self,
        model: GazeModel,
        *,
        rate: float = DEFAULT_GAZE_RATE,
        duration: float | None = None,
        noise_sd: float = 0.0,
        vergence_offset: float = 0.0,
        geometry: RigGeometry | None = None,
        fixation_distance: float = math.inf,
        distortion: GazeCorrection | None = None,
        dropouts: Sequence[tuple[float, float]] = (),
        seed: int = 0,
        speed: float | None = 1.0,
        start_time: float = 0.0,
        clock: Clock = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ):
        super().__init__(speed=speed, clock=clock, sleep=sleep, start_time=start_time)
        if not rate > 0:
            raise ValueError(f"SyntheticGazeSource: rate must be > 0 Hz, got {rate}")
        if duration is not None and not duration > 0:
            raise ValueError(f"SyntheticGazeSource: duration must be > 0 s or None, got {duration}")
        if geometry is not None and not isinstance(geometry, RigGeometry):
            raise TypeError(
                "SyntheticGazeSource: geometry must be a fovjax.devices.RigGeometry, "
                f"got {type(geometry).__name__}"
            )
        if geometry is not None and vergence_offset != 0:
            raise ValueError(
                f"SyntheticGazeSource: give vergence_offset ({vergence_offset}) or geometry, not both: "
                "the geometry puts each eye's point where it sees the fixation point"
            )
        if distortion is not None and not isinstance(distortion, GazeCorrection):
            raise TypeError(
                f"SyntheticGazeSource: distortion must be a fovjax.devices.GazeCorrection, "
                f"got {type(distortion).__name__}"
            )
        if not (isinstance(fixation_distance, int | float) and fixation_distance > 0):
            raise ValueError(
                f"SyntheticGazeSource: fixation_distance must be > 0 (math.inf: infinitely far), "
                f"got {fixation_distance!r}"
            )
        self.model = model
        self.rate = float(rate)
        self.duration = duration
        self.noise_sd = noise_sd
        self.vergence_offset = vergence_offset
        self.geometry = geometry
        self.fixation_distance = float(fixation_distance)
        self.distortion = distortion
        self._last_positions = None
        self.dropouts = sorted((float(a), float(b)) for a, b in dropouts)
        self.seed = seed

    def eye_positions(self, xy: tuple[float, float]) -> tuple[tuple[float, float], tuple[float, float]]:
        """(left, right) display positions, without noise, of the model's point `xy` (the
        `distortion` applied)."""
        x, y = xy
        if self._last_positions is not None and self._last_positions[0] == (x, y):
            return self._last_positions[1]  # a fixation: the same point sample after sample
        if self.geometry is None:
            left, right = np.array([x + self.vergence_offset, y]), np.array([x - self.vergence_offset, y])
        else:
            left, right = self.geometry.fixation((x, y), self.fixation_distance)
        if self.distortion is not None:
            left, right = self.distortion.apply_xy("left", left), self.distortion.apply_xy("right", right)
        positions = (float(left[0]), float(left[1])), (float(right[0]), float(right[1]))
        self._last_positions = ((x, y), positions)
        return positions

    def _count(self) -> int | None:
        return None if self.duration is None else int(math.floor(self.duration * self.rate + 1e-9)) + 1

    def _offset(self, i: int) -> float:
        return i / self.rate

    def _index_at(self, elapsed: float) -> int:
        return int(math.floor(elapsed * self.rate + 1e-9))

    def _skip(self, i: int) -> bool:
        t = i / self.rate
        return any(a <= t < b for a, b in self.dropouts)

    def _sample(self, i: int, timestamp: float) -> GazeSample:
        t = i / self.rate
        (lx, ly), (rx, ry) = self.eye_positions(self.model.position(t))
        if self.noise_sd > 0:
            # Per-sample generator keyed by (seed, i): the same sample whenever it is asked for.
            n = np.random.default_rng([self.seed, i]).normal(0.0, self.noise_sd, 4)
            lx, ly, rx, ry = lx + float(n[0]), ly + float(n[1]), rx + float(n[2]), ry + float(n[3])
        return GazeSample(timestamp, EyeGaze(lx, ly, 1.0, True), EyeGaze(rx, ry, 1.0, True), device_time=t)


class SyntheticHeadSource(PacedSource):
    """Head poses at `rate` Hz: a slow sinusoidal look-around (yaw amplitude `yaw_deg`, pitch
    `pitch_deg`, period `period` s), no roll. For demos and tests; pacing as `SyntheticGazeSource`."""

    kind = "head"

    def __init__(
        self,
        *,
        yaw_deg: float = 20.0,
        pitch_deg: float = 5.0,
        period: float = 8.0,
        rate: float = 180.0,
        duration: float | None = None,
        speed: float | None = 1.0,
        start_time: float = 0.0,
        clock: Clock = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ):
        super().__init__(speed=speed, clock=clock, sleep=sleep, start_time=start_time)
        self.yaw_deg, self.pitch_deg, self.period, self.rate, self.duration = (
            yaw_deg,
            pitch_deg,
            period,
            rate,
            duration,
        )

    def _count(self) -> int | None:
        return None if self.duration is None else int(math.floor(self.duration * self.rate + 1e-9)) + 1

    def _offset(self, i: int) -> float:
        return i / self.rate

    def _index_at(self, elapsed: float) -> int:
        return int(math.floor(elapsed * self.rate + 1e-9))

    def _sample(self, i: int, timestamp: float) -> HeadPose:
        t = i / self.rate
        phase = 2.0 * math.pi * t / self.period
        return HeadPose(
            timestamp, self.yaw_deg * math.sin(phase), self.pitch_deg * math.sin(2 * phase), 0.0, t
        )
