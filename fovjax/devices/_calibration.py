"""Eye-tracker calibration and validation: targets, accuracy and precision in degrees, stray
points re-presented or omitted, an affine correction per eye, and its record.

The thesis (section 3.3.2) calibrated its ViewPoint tracker in ViewPoint's own software: a square
green target shown at different places of the screen on a blank background, 20 points ("at
least 9 but ... 16 or 20 points" give the best results), and stray points "re-presented on the
screen" or, when they cannot be recalibrated, "omitted". `calibrate` does the same with any gaze
source, on top of whatever mapping the tracker itself applies:

1. Present each target (`calibration_targets`: a grid inside the part of the view both eyes see)
   through the caller's `present` callback -- the application draws it, in each eye's display
   at that eye's position of the target -- and read the source: the first `settle_s` seconds of
   samples after the target appears are dropped (the eye's latency and saccade), the next
   `collect_s` seconds are the point's samples.
2. Per eye and point: the samples the source marked valid, finite and confident enough; their
   mean position; its offset from the target; the sample-to-sample precision.
3. Per eye, fit an affine map (least squares) from the measured mean positions to the targets,
   leaving out, one at a time, the point farthest from the fit while it is farther than
   `max_error_deg`.
4. A point with too few valid samples, or farther than `max_error_deg` from its eye's fit, is
   re-presented (new samples replace its old ones), up to `max_presentations` times in all;
   after that it is omitted for the eye that failed it. The thesis's operator chose the points
   by eye; these rules and thresholds are fovjax's.
5. The correction is the affine map per eye fitted to the points used; setting it on a source
   (``source.correction = result.correction``) corrects every later sample.

Angles are those the renderer uses for eccentricity: the angle between the eye's rays through
the two display positions (`RigGeometry.angle_deg`), so the rig's field of view, aspect,
offsets and toe-out all count. *Accuracy* is the mean over the points used of the angular offset
of the point's mean gaze from its target; *precision* is the root mean square of the angles
between successive valid samples (RMS sample-to-sample) over those points. The accuracy a
calibration reports after its correction is measured on the samples it was fitted to; `validate`
measures it on new targets.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ._correction import GazeCorrection
from ._filters import QualityFilter
from ._geometry import EYES, RigGeometry, as_pair
from ._samples import GazeSample
from ._source import DeviceError, Source

CALIBRATION_FORMAT = 1
# The thesis's number of calibration points (section 3.3.2).
THESIS_CALIBRATION_POINTS = 20


class CalibrationError(DeviceError):
    """A calibration could not be made: the source ended or too few points were usable."""


@dataclasses.dataclass(frozen=True)
class CalibrationTarget:
    """A target to look at: `xy` on the cyclopean display (a direction from the head,
    `RigGeometry.fixation`), `left` and `right` where it is drawn in each eye's display."""

    index: int
    xy: tuple[float, float]
    left: tuple[float, float]
    right: tuple[float, float]

    def eye(self, which: str) -> tuple[float, float]:
        """The target's position in `which` eye's display ("left" or "right")."""
        if which not in EYES:
            raise ValueError(f"CalibrationTarget.eye: which must be 'left' or 'right', got {which!r}")
        return self.left if which == "left" else self.right

    def to_dict(self) -> dict:
        return {"index": self.index, "xy": list(self.xy), "left": list(self.left), "right": list(self.right)}

    @classmethod
    def from_dict(cls, data: dict) -> CalibrationTarget:
        return cls(
            int(data["index"]),
            as_pair(data["xy"], "CalibrationTarget.xy"),
            as_pair(data["left"], "CalibrationTarget.left"),
            as_pair(data["right"], "CalibrationTarget.right"),
        )


def targets_at(
    positions: Sequence[tuple[float, float]], geometry: RigGeometry | None = None, distance: float = math.inf
) -> tuple[CalibrationTarget, ...]:
    """Targets at cyclopean display `positions`, each drawn in each eye where that eye sees the
    point `distance` away in that direction (`RigGeometry.fixation`; rig units, ``math.inf``:
    infinitely far). `geometry` None: the thesis's rig (`RigGeometry()`).

    Raises:
        ValueError: no positions, a position that is not two finite numbers, a bad distance.
    """
    geometry = RigGeometry() if geometry is None else geometry
    if not isinstance(geometry, RigGeometry):
        raise TypeError(f"targets_at: geometry must be a RigGeometry, got {type(geometry).__name__}")
    pairs = [as_pair(p, f"targets_at: position {k}") for k, p in enumerate(positions)]
    if not pairs:
        raise ValueError("targets_at: need at least one position")
    left, right = geometry.fixation(np.array(pairs), distance)
    return tuple(
        CalibrationTarget(k, xy, (float(lx), float(ly)), (float(rx), float(ry)))
        for k, (xy, (lx, ly), (rx, ry)) in enumerate(zip(pairs, left, right, strict=True))
    )


def _grid_shape(points: int) -> tuple[int, int]:
    """(columns, rows): the most nearly square grid of `points` with at least two rows."""
    shapes = [(points // rows, rows) for rows in range(2, math.isqrt(points) + 1) if points % rows == 0]
    if points < 4 or not shapes:
        raise ValueError(
            f"calibration_targets: points must make a grid of at least 2 x 2 (4, 6, 8, 9, 12, 16, 20, ...), "
            f"got {points!r}"
        )
    return shapes[-1]


def calibration_targets(
    points: int = THESIS_CALIBRATION_POINTS,
    geometry: RigGeometry | None = None,
    *,
    distance: float = math.inf,
    margin: float = 0.1,
) -> tuple[CalibrationTarget, ...]:
    """`points` targets (20 by default, the thesis's count) on an even grid (5 x 4 for 20),
    row by row from the top-left, spread as wide as both eyes see them: every target lies at
    least `margin` (a fraction of the display) inside both eyes' displays. Each is drawn in each
    eye where that eye sees it (`targets_at`). `geometry` None: the thesis's rig, where the eyes
    turned 13° outwards share the middle of the view only.

    Raises:
        ValueError: a count that makes no grid of at least 2 x 2 (4, 6, 8, 9, 12, 16, 20, ...; a
            prime above 3 does not), a margin outside [0, 0.5), a bad distance.
    """
    if isinstance(points, bool) or not isinstance(points, int | np.integer):
        raise ValueError(f"calibration_targets: points must be an integer, got {points!r}")
    columns, rows = _grid_shape(int(points))
    if not (isinstance(margin, int | float) and 0.0 <= margin < 0.5):
        raise ValueError(f"calibration_targets: margin must be in [0, 0.5), got {margin!r}")
    geometry = RigGeometry() if geometry is None else geometry
    lo, hi = margin, 1.0 - margin
    # Shrink the grid's half-width and half-height about the centre until both eyes see every
    # target inside their margins (the toe-out limits the width, not the height).
    half = [0.5 - margin, 0.5 - margin]
    for _ in range(2000):
        xs = 0.5 + half[0] * np.linspace(-1.0, 1.0, columns)
        ys = 0.5 + half[1] * np.linspace(-1.0, 1.0, rows)
        grid = np.array([(x, y) for y in ys for x in xs])
        seen = np.stack(geometry.fixation(grid, distance))  # (2 eyes, points, 2)
        outside_x = np.any(~((seen[..., 0] >= lo) & (seen[..., 0] <= hi)))
        outside_y = np.any(~((seen[..., 1] >= lo) & (seen[..., 1] <= hi)))
        if not (outside_x or outside_y):
            return targets_at([tuple(p) for p in grid], geometry, distance)
        if outside_x:
            half[0] *= 0.99
        if outside_y:
            half[1] *= 0.99
    raise ValueError(
        f"calibration_targets: no grid of {points} targets fits inside both eyes' displays with margin "
        f"{margin} on this rig (toe-out {geometry.toe_out_deg}°, field of view {geometry.fov_deg}°)"
    )


@dataclasses.dataclass(frozen=True)
class CalibrationSettings:
    """How a calibration (or validation) presents its targets and judges its points.

    Args:
        points: how many targets `calibration_targets` makes (20: the thesis's).
        settle_s: seconds of samples dropped after a target appears (latency and saccade).
        collect_s: seconds of samples kept per presentation.
        min_valid_fraction: a point needs at least this fraction of its samples valid (and at
            least 2) in an eye, else it is re-presented.
        min_confidence: a sample's eye below this confidence is not valid.
        max_error_deg: a point whose mean gaze lies farther than this from its target after the
            eye's fit is a stray, re-presented (fovjax's threshold: twice the 1° the thesis
            gives as the tracker's worst accuracy, §2.1.3).
        max_presentations: how many times a point is shown at most; still bad then: omitted.
        min_points: the fewest points an eye's fit may use (at least 3: an affine map).
        distance: how far away the targets are, in rig units (``math.inf``: infinitely far).
        margin: how far inside both eyes' displays the targets stay (fraction of a display).
        patience_s: seconds of the source's clock a presentation waits beyond `settle_s` +
            `collect_s` for samples that do not come.

    Raises:
        ValueError: naming the value that is out of range.
    """

    points: int = THESIS_CALIBRATION_POINTS
    settle_s: float = 0.5
    collect_s: float = 1.0
    min_valid_fraction: float = 0.5
    min_confidence: float = 0.5
    max_error_deg: float = 2.0
    max_presentations: int = 3
    min_points: int = 6
    distance: float = math.inf
    margin: float = 0.1
    patience_s: float = 2.0

    def __post_init__(self):
        def check(name, ok, expected):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.number) or not ok(value):
                raise ValueError(f"CalibrationSettings: {name} must be {expected}, got {value!r}")

        check("points", lambda v: float(v).is_integer() and v >= 4, "an integer >= 4")
        check("settle_s", lambda v: 0 <= v < math.inf, "a finite number of seconds >= 0")
        check("collect_s", lambda v: 0 < v < math.inf, "a finite number of seconds > 0")
        check("min_valid_fraction", lambda v: 0 <= v <= 1, "in [0, 1]")
        check("min_confidence", lambda v: 0 <= v <= 1, "in [0, 1]")
        check("max_error_deg", lambda v: v > 0, "> 0 degrees")
        check("max_presentations", lambda v: float(v).is_integer() and v >= 1, "an integer >= 1")
        check("min_points", lambda v: float(v).is_integer() and v >= 3, "an integer >= 3")
        check("distance", lambda v: v > 0, "> 0 (math.inf: infinitely far)")
        check("margin", lambda v: 0 <= v < 0.5, "in [0, 0.5)")
        check("patience_s", lambda v: 0 <= v < math.inf, "a finite number of seconds >= 0")
        if self.min_points > self.points:
            raise ValueError(
                f"CalibrationSettings: min_points ({self.min_points}) cannot exceed points ({self.points})"
            )


@dataclasses.dataclass(frozen=True)
class PointEye:
    """One eye at one target: its samples, their mean, offset and precision, and the verdict.

    `samples` counts the presentation's samples, `valid` the eye's usable ones; `mean` is their
    mean measured position (None without any); `offset_raw_deg` the mean's angle from the
    target as measured, `offset_deg` after the correction (a validation: as the source gave
    it); `precision_deg` the RMS sample-to-sample angle of the corrected samples; `status`
    "used" or "omitted", `reason` why a point was omitted ("" when used)."""

    samples: int
    valid: int
    mean: tuple[float, float] | None
    offset_raw_deg: float | None
    offset_deg: float | None
    precision_deg: float | None
    status: str
    reason: str = ""


@dataclasses.dataclass(frozen=True)
class CalibrationPoint:
    """A target, how many times it was presented, and each eye's `PointEye`."""

    target: CalibrationTarget
    presentations: int
    left: PointEye
    right: PointEye

    def eye(self, which: str) -> PointEye:
        if which not in EYES:
            raise ValueError(f"CalibrationPoint.eye: which must be 'left' or 'right', got {which!r}")
        return self.left if which == "left" else self.right


@dataclasses.dataclass(frozen=True)
class EyeAccuracy:
    """One eye's result in degrees: `accuracy_deg` (mean angular offset over the points used),
    `precision_deg` (RMS sample-to-sample), how many points were used and omitted, and for a
    calibration the accuracy before its correction (`uncorrected_accuracy_deg`)."""

    accuracy_deg: float
    precision_deg: float
    points_used: int
    points_omitted: int
    uncorrected_accuracy_deg: float | None = None


@dataclasses.dataclass(frozen=True)
class ValidationResult:
    """What `validate` measured: the points and each eye's `EyeAccuracy`."""

    points: tuple[CalibrationPoint, ...]
    left: EyeAccuracy
    right: EyeAccuracy

    def eye(self, which: str) -> EyeAccuracy:
        if which not in EYES:
            raise ValueError(f"ValidationResult.eye: which must be 'left' or 'right', got {which!r}")
        return self.left if which == "left" else self.right

    def to_dict(self) -> dict:
        return {
            "eyes": {eye: dataclasses.asdict(self.eye(eye)) for eye in EYES},
            "points": [_point_to_dict(p) for p in self.points],
        }

    @classmethod
    def from_dict(cls, data: dict) -> ValidationResult:
        return cls(
            points=tuple(_point_from_dict(p) for p in data["points"]),
            left=EyeAccuracy(**data["eyes"]["left"]),
            right=EyeAccuracy(**data["eyes"]["right"]),
        )


@dataclasses.dataclass(frozen=True)
class CalibrationResult:
    """What `calibrate` made: the `correction` to set on the source, the points, each eye's
    `EyeAccuracy` (on the calibration's own samples), the rig and settings it used, the source
    it read, and a `validation` when one was added (`with_validation`). `save` records it as
    JSON; `load_calibration` reads it back."""

    correction: GazeCorrection
    points: tuple[CalibrationPoint, ...]
    left: EyeAccuracy
    right: EyeAccuracy
    geometry: RigGeometry
    settings: CalibrationSettings
    source: str = ""
    validation: ValidationResult | None = None

    def eye(self, which: str) -> EyeAccuracy:
        if which not in EYES:
            raise ValueError(f"CalibrationResult.eye: which must be 'left' or 'right', got {which!r}")
        return self.left if which == "left" else self.right

    def with_validation(self, validation: ValidationResult) -> CalibrationResult:
        """This calibration with a `validate` result recorded beside it."""
        if not isinstance(validation, ValidationResult):
            raise TypeError(f"with_validation: expected a ValidationResult, got {type(validation).__name__}")
        return dataclasses.replace(self, validation=validation)

    def to_dict(self) -> dict:
        return {
            "fovjax_calibration": CALIBRATION_FORMAT,
            "source": self.source,
            "geometry": dataclasses.asdict(self.geometry),
            "settings": dataclasses.asdict(self.settings),
            "correction": self.correction.to_dict(),
            "eyes": {eye: dataclasses.asdict(self.eye(eye)) for eye in EYES},
            "points": [_point_to_dict(p) for p in self.points],
            "validation": None if self.validation is None else self.validation.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: dict) -> CalibrationResult:
        geometry = dict(data["geometry"])
        geometry["offsets"] = tuple(tuple(row) for row in geometry["offsets"])
        validation = data.get("validation")
        return cls(
            correction=GazeCorrection.from_dict(data["correction"]),
            points=tuple(_point_from_dict(p) for p in data["points"]),
            left=EyeAccuracy(**data["eyes"]["left"]),
            right=EyeAccuracy(**data["eyes"]["right"]),
            geometry=RigGeometry(**geometry),
            settings=CalibrationSettings(**_settings_fields(data["settings"])),
            source=str(data.get("source", "")),
            validation=None if validation is None else ValidationResult.from_dict(validation),
        )

    def save(self, path: str | Path) -> Path:
        """Write the record as JSON to `path` (replaced whole: a reader never sees half a file)."""
        path = Path(path)
        text = json.dumps(_jsonable(self.to_dict()), indent=1, allow_nan=False)
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(text + "\n", encoding="utf-8")
        os.replace(tmp, path)
        return path


def _settings_fields(data: dict) -> dict:
    """A recorded `CalibrationSettings`' fields as its constructor takes them."""
    return {k: _number(v) for k, v in data.items()}


def _number(value):
    """JSON's null for an infinite distance back to math.inf; other values unchanged."""
    return math.inf if value is None else value


def _jsonable(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    return value


def _point_to_dict(point: CalibrationPoint) -> dict:
    return {
        "target": point.target.to_dict(),
        "presentations": point.presentations,
        "left": dataclasses.asdict(point.left),
        "right": dataclasses.asdict(point.right),
    }


def _point_eye_from_dict(data: dict) -> PointEye:
    data = dict(data)
    if data.get("mean") is not None:
        data["mean"] = as_pair(data["mean"], "PointEye.mean")
    return PointEye(**data)


def _point_from_dict(data: dict) -> CalibrationPoint:
    return CalibrationPoint(
        target=CalibrationTarget.from_dict(data["target"]),
        presentations=int(data["presentations"]),
        left=_point_eye_from_dict(data["left"]),
        right=_point_eye_from_dict(data["right"]),
    )


def load_calibration(path: str | Path) -> CalibrationResult:
    """Read a calibration record written by `CalibrationResult.save`.

    Raises:
        FileNotFoundError: no such file.
        ValueError: the file is not JSON (naming file:line), not a fovjax calibration record,
            of another format version, or holds a bad value (naming the file).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"load_calibration: no such file {path}")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}:{err.lineno}: not a JSON calibration record ({err.msg})") from None
    if not isinstance(data, dict) or "fovjax_calibration" not in data:
        raise ValueError(f"{path}: not a fovjax calibration record (no 'fovjax_calibration' field)")
    if data["fovjax_calibration"] != CALIBRATION_FORMAT:
        raise ValueError(
            f"{path}: calibration record format {data['fovjax_calibration']!r}, this fovjax reads "
            f"{CALIBRATION_FORMAT}"
        )
    try:
        return CalibrationResult.from_dict(data)
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{path}: bad calibration record: {type(err).__name__}: {err}") from None


# -- collecting --------------------------------------------------------------------------------
def _collect(source: Source, present: Callable, target: CalibrationTarget, settings: CalibrationSettings):
    """Present `target`, then the samples from `settle_s` to `settle_s + collect_s` seconds
    after the first sample that follows it (sample timestamps: the source's timeline)."""
    present(target)
    source.drain()  # received before the target appeared: they belong to the last one
    window_end = settings.settle_s + settings.collect_s
    deadline = source.clock() + window_end + settings.patience_s
    start = None
    kept: list[GazeSample] = []
    while True:
        sample = source.read(timeout=0.05)
        if sample is None:
            if source.exhausted:
                raise CalibrationError(
                    f"calibration: the source {source.spec or source.describe()} ended while target "
                    f"{target.index} at {target.xy} was shown"
                )
            if source.clock() > deadline:
                return kept
            continue
        if not math.isfinite(sample.timestamp):
            continue
        if start is None:
            start = sample.timestamp
        age = sample.timestamp - start
        if age >= window_end:
            return kept
        if age >= settings.settle_s:
            kept.append(sample)


def _valid_xy(samples: list[GazeSample], eye: str, quality: QualityFilter) -> np.ndarray:
    rows = [(s.eye(eye).x, s.eye(eye).y) for s in samples if quality.accepts(s.eye(eye))]
    return np.array(rows, dtype=float).reshape(-1, 2)


def _precision(geometry: RigGeometry, eye: str, xy: np.ndarray) -> float | None:
    """RMS of the angles between successive positions, or None with fewer than two."""
    if len(xy) < 2:
        return None
    angles = geometry.angle_deg(eye, xy[:-1], xy[1:])
    return float(np.sqrt(np.mean(angles**2)))


def _affine_fit(measured: np.ndarray, targets: np.ndarray) -> np.ndarray | None:
    """The 2 x 3 least-squares affine map from `measured` (m, 2) to `targets` (m, 2), or None
    when the points do not span the plane (fewer than 3, or on one line)."""
    design = np.column_stack([measured, np.ones(len(measured))])
    if len(measured) < 3 or np.linalg.matrix_rank(design, tol=1e-6) < 3:
        return None
    solution, *_ = np.linalg.lstsq(design, targets, rcond=None)
    return solution.T


def _apply(matrix: np.ndarray, xy: np.ndarray) -> np.ndarray:
    return xy @ matrix[:, :2].T + matrix[:, 2]


class _EyeVerdict:
    """One eye's state over the points: each point's valid samples and mean, the fit, strays."""

    def __init__(self, eye, geometry, settings, targets, samples, quality, fit: bool):
        self.eye = eye
        self.failures: dict[int, str] = {}
        self.xy: dict[int, np.ndarray] = {}
        self.counts: dict[int, int] = {}
        for target in targets:
            k = target.index
            taken = samples[k]
            xy = _valid_xy(taken, eye, quality)
            self.counts[k], self.xy[k] = len(taken), xy
            needed = max(2, math.ceil(settings.min_valid_fraction * len(taken)))
            if len(xy) < needed:
                self.failures[k] = f"too few valid samples ({len(xy)} of {len(taken)}, need {needed})"
        self.matrix = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        usable = [t for t in targets if t.index not in self.failures]
        if not fit:
            return
        goal = {t.index: np.asarray(t.eye(eye)) for t in targets}
        means = {k: self.xy[k].mean(axis=0) for k in (t.index for t in usable)}
        kept = [t.index for t in usable]
        while True:
            matrix = _affine_fit(
                np.array([means[k] for k in kept]).reshape(-1, 2),
                np.array([goal[k] for k in kept]).reshape(-1, 2),
            )
            if matrix is None:
                self.matrix = None
                return
            errors = {k: float(geometry.angle_deg(eye, _apply(matrix, means[k]), goal[k])) for k in kept}
            worst = max(errors, key=errors.__getitem__)
            if errors[worst] <= settings.max_error_deg or len(kept) <= 3:
                break
            kept.remove(worst)
        self.matrix = matrix
        for k in means:
            error = float(geometry.angle_deg(eye, _apply(matrix, means[k]), goal[k]))
            if error > settings.max_error_deg:
                self.failures[k] = f"{error:.2f}° from its target after the fit (> {settings.max_error_deg}°)"


def _check_source(source, where: str) -> None:
    if not isinstance(source, Source):
        raise TypeError(f"{where}: source must be a fovjax.devices gaze source, got {type(source).__name__}")
    if source.kind != "gaze":
        raise ValueError(f"{where}: source must be a gaze source, got a {source.kind} source")


def _prepare(
    source, present, geometry, settings, targets, where
) -> tuple[RigGeometry, tuple[CalibrationTarget, ...]]:
    """Every argument checked before anything is presented; the targets to show."""
    _check_source(source, where)
    if not callable(present):
        raise TypeError(f"{where}: present must be a callable drawing a CalibrationTarget, got {present!r}")
    geometry = RigGeometry() if geometry is None else geometry
    if not isinstance(geometry, RigGeometry):
        raise TypeError(
            f"{where}: geometry must be a fovjax.devices.RigGeometry, got {type(geometry).__name__}"
        )
    if not isinstance(settings, CalibrationSettings):
        raise TypeError(f"{where}: settings must be a CalibrationSettings, got {type(settings).__name__}")
    if targets is None:
        return geometry, tuple(
            calibration_targets(settings.points, geometry, distance=settings.distance, margin=settings.margin)
        )
    given = tuple(targets)
    if not given:
        raise ValueError(f"{where}: targets is empty")
    if all(isinstance(t, CalibrationTarget) for t in given):
        chosen = tuple(t for t in given if isinstance(t, CalibrationTarget))
    else:
        chosen = tuple(targets_at(given, geometry, settings.distance))
    indices = [t.index for t in chosen]
    if len(set(indices)) != len(indices):
        raise ValueError(f"{where}: target indices must be distinct, got {indices}")
    return geometry, chosen


def _run(source, present, targets, settings, geometry, fit: bool):
    """Present, judge, re-present; per eye: the verdict; per point: its samples and count."""
    quality = QualityFilter(settings.min_confidence, max_offscreen=math.inf)
    samples: dict[int, list[GazeSample]] = {}
    shown = {t.index: 0 for t in targets}
    pending = list(targets)
    source.open()
    while True:
        for target in pending:
            samples[target.index] = _collect(source, present, target, settings)
            shown[target.index] += 1
        verdicts = {eye: _EyeVerdict(eye, geometry, settings, targets, samples, quality, fit) for eye in EYES}
        failed = {k for v in verdicts.values() for k in v.failures}
        pending = [t for t in targets if t.index in failed and shown[t.index] < settings.max_presentations]
        if not pending:
            return verdicts, samples, shown


def _points(targets, verdicts, shown, geometry, matrices) -> tuple[CalibrationPoint, ...]:
    out = []
    for target in targets:
        k = target.index
        eyes = {}
        for eye in EYES:
            v = verdicts[eye]
            xy, goal = v.xy[k], np.asarray(target.eye(eye))
            corrected = _apply(matrices[eye], xy) if len(xy) else xy
            centre = xy.mean(axis=0) if len(xy) else None
            mean = None if centre is None else (float(centre[0]), float(centre[1]))
            eyes[eye] = PointEye(
                samples=v.counts[k],
                valid=len(xy),
                mean=mean,
                offset_raw_deg=float(geometry.angle_deg(eye, xy.mean(axis=0), goal)) if len(xy) else None,
                offset_deg=float(geometry.angle_deg(eye, corrected.mean(axis=0), goal)) if len(xy) else None,
                precision_deg=_precision(geometry, eye, corrected),
                status="omitted" if k in v.failures else "used",
                reason=v.failures.get(k, ""),
            )
        out.append(CalibrationPoint(target, shown[k], eyes["left"], eyes["right"]))
    return tuple(out)


def _eye_accuracy(points, eye, geometry, matrix, verdict, uncorrected: bool) -> EyeAccuracy:
    used = [p for p in points if p.eye(eye).status == "used"]
    angles = []
    for p in used:
        xy = _apply(matrix, verdict.xy[p.target.index])
        if len(xy) >= 2:
            angles.append(geometry.angle_deg(eye, xy[:-1], xy[1:]))
    precision = float(np.sqrt(np.mean(np.concatenate(angles) ** 2))) if angles else math.nan
    return EyeAccuracy(
        accuracy_deg=float(np.mean([p.eye(eye).offset_deg for p in used])) if used else math.nan,
        precision_deg=precision,
        points_used=len(used),
        points_omitted=len(points) - len(used),
        uncorrected_accuracy_deg=float(np.mean([p.eye(eye).offset_raw_deg for p in used]))
        if uncorrected and used
        else None,
    )


def calibrate(
    source: Source,
    present: Callable[[CalibrationTarget], object],
    *,
    geometry: RigGeometry | None = None,
    settings: CalibrationSettings | None = None,
    targets: Sequence[CalibrationTarget] | Sequence[tuple[float, float]] | None = None,
) -> CalibrationResult:
    """Calibrate a gaze source (module docstring): present each target, collect its samples,
    re-present or omit bad points, fit an affine correction per eye.

    The source's samples are read as it measures them: its own `correction` is switched off
    while the calibration runs and put back afterwards. The source is opened if it is not
    (and left open). A synthetic observer: `TargetFollower`.

    Args:
        source: a gaze source (`fovjax.devices`); a live device or a paced source runs in real
            time (about (`settle_s` + `collect_s`) x points seconds, 30 s by default).
        present: called with each `CalibrationTarget` as it is to appear (and again when it is
            re-presented): draw it at ``target.left`` in the left eye's display and
            ``target.right`` in the right's, until the next call.
        geometry: the rig (`RigGeometry.from_rig(rig)`); None: the thesis's rig.
        settings: `CalibrationSettings` (20 points, thresholds, timings).
        targets: `CalibrationTarget`s or cyclopean display positions to use instead of
            `calibration_targets(settings.points, ...)`.

    Returns:
        A `CalibrationResult`: ``result.correction`` to set on the source
        (``source.correction = result.correction``), per eye accuracy before and after it and
        precision in degrees, every point's verdict; ``result.save(path)`` records it.

    Raises:
        TypeError: a source, callback, geometry or settings of the wrong kind.
        ValueError: bad targets or settings (naming the value).
        CalibrationError: the source ended, or an eye has fewer than `settings.min_points`
            usable points (naming each omitted point's reason).
    """
    settings = CalibrationSettings() if settings is None else settings
    geometry, shown_targets = _prepare(source, present, geometry, settings, targets, "calibrate")
    targets = shown_targets
    if settings.min_points > len(targets):
        raise ValueError(
            f"calibrate: settings.min_points ({settings.min_points}) is more than the {len(targets)} targets"
        )
    previous, source.correction = source.correction, None
    try:
        verdicts, _, shown = _run(source, present, targets, settings, geometry, fit=True)
    finally:
        source.correction = previous
    matrices = {}
    for eye in EYES:
        v = verdicts[eye]
        used = [t for t in targets if t.index not in v.failures]
        matrix = None
        if len(used) >= settings.min_points:
            matrix = _affine_fit(
                np.array([v.xy[t.index].mean(axis=0) for t in used]), np.array([t.eye(eye) for t in used])
            )
        if matrix is None:
            reasons = (
                "; ".join(f"target {k}: {why}" for k, why in sorted(v.failures.items())) or "none omitted"
            )
            raise CalibrationError(
                f"calibrate: the {eye} eye has {len(used)} usable point(s) of {len(targets)}, needs "
                f"{settings.min_points} not all on one line ({reasons})"
            )
        matrices[eye] = matrix
    points = _points(targets, verdicts, shown, geometry, matrices)
    return CalibrationResult(
        correction=GazeCorrection(left=matrices["left"].tolist(), right=matrices["right"].tolist()),
        points=points,
        left=_eye_accuracy(points, "left", geometry, matrices["left"], verdicts["left"], True),
        right=_eye_accuracy(points, "right", geometry, matrices["right"], verdicts["right"], True),
        geometry=geometry,
        settings=settings,
        source=source.spec or source.describe(),
    )


def validate(
    source: Source,
    present: Callable[[CalibrationTarget], object],
    *,
    geometry: RigGeometry | None = None,
    settings: CalibrationSettings | None = None,
    targets: Sequence[CalibrationTarget] | Sequence[tuple[float, float]] | None = None,
) -> ValidationResult:
    """Measure a gaze source's accuracy and precision in degrees on targets, as the source gives
    its samples (its `correction` applied): after a calibration, on new targets.

    Points with too few valid samples are re-presented up to `settings.max_presentations`
    times, then omitted; there is no fit, so no stray rule. `settings` None:
    ``CalibrationSettings(points=9, min_points=3, margin=0.2)``; `targets` None:
    ``calibration_targets(settings.points, ..., margin=settings.margin)`` (with the default
    settings a 3 x 3 grid inside the default 5 x 4 calibration grid, on none of its points).

    Raises:
        TypeError, ValueError: as `calibrate`.
        CalibrationError: the source ended, or an eye has no usable point.
    """
    settings = CalibrationSettings(points=9, min_points=3, margin=0.2) if settings is None else settings
    geometry, shown_targets = _prepare(source, present, geometry, settings, targets, "validate")
    targets = shown_targets
    verdicts, _, shown = _run(source, present, targets, settings, geometry, fit=False)
    identity = {eye: np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]) for eye in EYES}
    points = _points(targets, verdicts, shown, geometry, identity)
    for eye in EYES:
        if not any(p.eye(eye).status == "used" for p in points):
            raise CalibrationError(f"validate: the {eye} eye has no usable point of {len(points)}")
    return ValidationResult(
        points=points,
        left=_eye_accuracy(points, "left", geometry, identity["left"], verdicts["left"], False),
        right=_eye_accuracy(points, "right", geometry, identity["right"], verdicts["right"], False),
    )
