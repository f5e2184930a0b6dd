"""Eye-tracker calibration and validation against a synthetic observer whose tracker has a
known error: the fit undoes it, accuracy improves, bad points are re-presented or omitted, the
record round-trips, bad arguments are refused.

The synthetic tracker samples at 60 Hz (the thesis's ViewPoint rate) with Gaussian noise of
sd 0.002 (normalised units, per axis) on the thesis's rig, unpaced; each presentation drops
0.2 s and keeps 0.5 s (30 samples), so a 20-point calibration reads about 850 samples."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from fovjax.devices import (
    CalibrationError,
    CalibrationSettings,
    GazeCorrection,
    RigGeometry,
    SyntheticGazeSource,
    SyntheticHeadSource,
    TargetFollower,
    calibrate,
    calibration_targets,
    load_calibration,
    validate,
)

RIG = RigGeometry()  # the thesis's: eyes turned 13° outwards, 90° horizontal each
NOISE = 0.002
RATE = 60.0
# The tracker's systematic error: a shift of the left eye, a gain and a shear of the right.
DISTORTION = GazeCorrection(
    left=((1.0, 0.0, 0.03), (0.0, 1.0, -0.02)),
    right=((1.05, 0.0, -0.01), (0.02, 0.97, 0.01)),
)
# Degrees per normalised unit at the display centre, where a unit spans the most degrees:
# d/dx atan((2x - 1) tan(fov/2)) = 2 tan(fov/2) at x = 1/2, per axis.
TAN_X, TAN_Y = RIG.tan_half_fov
DEG_PER_UNIT = np.degrees(2.0 * np.hypot(TAN_X, TAN_Y))


class Observer(TargetFollower):
    """Looks at each target, except: `blinks[k]` presentations of target k with the eyes shut
    (no valid sample), `strays[k]` presentations looking 0.08 to the right of it."""

    def __init__(self, blinks=None, strays=None):
        super().__init__()
        self.blinks, self.strays = dict(blinks or {}), dict(strays or {})
        self.shown: dict[int, int] = {}

    def present(self, target):
        super().present(target)
        k = target.index
        self.shown[k] = self.shown.get(k, 0) + 1
        if self.shown[k] <= self.blinks.get(k, 0):
            self.target = (math.nan, math.nan)
        elif self.shown[k] <= self.strays.get(k, 0):
            self.target = (target.xy[0] + 0.08, target.xy[1])


# Shorter presentations than the defaults (0.5 s + 1 s): the same rules on fewer samples.
FAST = CalibrationSettings(settle_s=0.2, collect_s=0.5)
FAST_VALIDATION = CalibrationSettings(points=9, min_points=3, margin=0.2, settle_s=0.2, collect_s=0.5)


def tracker(observer, **kwargs):
    kwargs.setdefault("distortion", DISTORTION)
    return SyntheticGazeSource(observer, geometry=RIG, noise_sd=NOISE, rate=RATE, speed=None, **kwargs)


@pytest.fixture(scope="module")
def calibrated():
    observer = Observer()
    source = tracker(observer)
    return calibrate(source, observer.present, geometry=RIG, settings=FAST), source, observer


def test_the_targets_are_a_grid_both_eyes_see():
    targets = calibration_targets()
    assert len(targets) == 20
    xs = sorted({round(t.xy[0], 9) for t in targets})
    ys = sorted({round(t.xy[1], 9) for t in targets})
    assert len(xs) == 5 and len(ys) == 4
    for t in targets:
        left, right = RIG.fixation(t.xy)
        # One point against the grid's batch: numpy's vectorised arithmetic may round the
        # batch differently (by an ulp) on another CPU.
        np.testing.assert_allclose(t.left, left, rtol=0, atol=1e-12)
        np.testing.assert_allclose(t.right, right, rtol=0, atol=1e-12)
        for eye in (t.left, t.right):
            assert 0.1 - 1e-9 <= min(eye) and max(eye) <= 0.9 + 1e-9
    assert [len(calibration_targets(n)) for n in (4, 6, 9, 12, 16)] == [4, 6, 9, 12, 16]


def test_the_fit_undoes_a_known_tracker_error(calibrated):
    result, _, _ = calibrated
    inverse = {
        eye: np.linalg.inv(np.vstack([DISTORTION.matrix(eye), [0.0, 0.0, 1.0]]))[:2]
        for eye in ("left", "right")
    }
    for eye in ("left", "right"):
        # Each point's mean of 30 samples is off by about NOISE / sqrt(30) = 0.00037; the fit
        # over 20 points is within a few of those.
        np.testing.assert_allclose(result.correction.matrix(eye), inverse[eye], atol=0.005)
        accuracy = result.eye(eye)
        assert accuracy.points_used == 20 and accuracy.points_omitted == 0
        assert accuracy.uncorrected_accuracy_deg > 1.0  # the distortion: 0.01-0.03 units, 1-3°
        assert accuracy.accuracy_deg < 0.25  # the thesis tracker's best accuracy
        # RMS sample-to-sample of independent noise: 2 NOISE (normalised), at most DEG_PER_UNIT
        # degrees per unit (the display centre), less away from it (down to ~0.5 at the corners).
        assert 0.4 * 2 * NOISE * DEG_PER_UNIT < accuracy.precision_deg < 1.1 * 2 * NOISE * DEG_PER_UNIT
    assert all(p.presentations == 1 for p in result.points)


def test_a_noiseless_tracker_calibrates_exactly():
    observer = Observer()
    source = SyntheticGazeSource(observer, geometry=RIG, distortion=DISTORTION, rate=RATE, speed=None)
    result = calibrate(source, observer.present, geometry=RIG, settings=FAST)
    for eye in ("left", "right"):
        assert result.eye(eye).accuracy_deg < 1e-6 and result.eye(eye).precision_deg == 0.0


def test_the_correction_applied_to_later_gaze_improves_validated_accuracy(calibrated):
    result, source, observer = calibrated
    before = validate(source, observer.present, geometry=RIG, settings=FAST_VALIDATION)
    source.correction = result.correction
    try:
        after = validate(source, observer.present, geometry=RIG, settings=FAST_VALIDATION)
    finally:
        source.correction = None
    assert len(after.points) == 9
    assert {p.target.xy for p in after.points}.isdisjoint({p.target.xy for p in result.points})
    for eye in ("left", "right"):
        assert before.eye(eye).accuracy_deg > 1.0
        assert after.eye(eye).accuracy_deg < 0.25 < before.eye(eye).accuracy_deg


def test_calibration_reads_the_source_uncorrected_and_restores_its_correction():
    observer = Observer()
    source = tracker(observer)
    wrong = GazeCorrection(left=((1.0, 0.0, 0.2), (0.0, 1.0, 0.0)))
    source.correction = wrong
    result = calibrate(source, observer.present, geometry=RIG, settings=FAST)
    assert source.correction is wrong
    assert result.left.accuracy_deg < 0.25  # fitted to the raw gaze, not to the wrongly corrected


def test_a_point_without_valid_samples_is_presented_again():
    observer = Observer(blinks={3: 1})
    result = calibrate(tracker(observer), observer.present, geometry=RIG, settings=FAST)
    shown = {p.target.index: p.presentations for p in result.points}
    assert shown[3] == 2 and all(n == 1 for k, n in shown.items() if k != 3)
    assert result.points[3].left.status == result.points[3].right.status == "used"


def test_a_point_that_stays_bad_is_omitted_and_the_fit_is_unharmed():
    observer = Observer(blinks={5: 99}, strays={7: 99})
    settings = CalibrationSettings(settle_s=0.2, collect_s=0.5, max_presentations=2)
    result = calibrate(tracker(observer), observer.present, geometry=RIG, settings=settings)
    blinked, strayed = result.points[5], result.points[7]
    assert blinked.presentations == strayed.presentations == 2
    for eye in ("left", "right"):
        assert (
            blinked.eye(eye).status == "omitted" and "too few valid samples (0 of" in blinked.eye(eye).reason
        )
        assert (
            strayed.eye(eye).status == "omitted"
            and "from its target after the fit" in strayed.eye(eye).reason
        )
        assert strayed.eye(eye).offset_deg > settings.max_error_deg
        assert result.eye(eye).points_used == 18 and result.eye(eye).points_omitted == 2
        assert result.eye(eye).accuracy_deg < 0.25
    # A stray point once, then looked at: re-presented and used.
    observer = Observer(strays={7: 1})
    result = calibrate(tracker(observer), observer.present, geometry=RIG, settings=FAST)
    assert result.points[7].presentations == 2 and result.points[7].left.status == "used"


def test_too_few_usable_points_is_a_calibration_error_naming_them():
    observer = Observer(blinks={k: 99 for k in range(16)})
    settings = CalibrationSettings(settle_s=0.2, collect_s=0.5, max_presentations=1)
    with pytest.raises(
        CalibrationError, match=r"the left eye has 4 usable point\(s\) of 20, needs 6.*target 0: too few"
    ):
        calibrate(tracker(observer), observer.present, geometry=RIG, settings=settings)


def test_a_source_that_ends_is_a_calibration_error():
    observer = Observer()
    with pytest.raises(CalibrationError, match="ended while target 1 at"):
        calibrate(tracker(observer, duration=1.0), observer.present, geometry=RIG, settings=FAST)


def test_the_record_round_trips(calibrated, tmp_path):
    result, source, observer = calibrated
    source.correction = result.correction
    try:
        validation = validate(source, observer.present, geometry=RIG, settings=FAST_VALIDATION)
    finally:
        source.correction = None
    path = result.with_validation(validation).save(tmp_path / "calibration.json")
    data = json.loads(path.read_text())
    assert data["fovjax_calibration"] == 1 and len(data["points"]) == 20
    assert data["settings"]["collect_s"] == 0.5 and data["settings"]["distance"] is None  # infinitely far
    assert data["geometry"]["toe_out_deg"] == 13.0
    loaded = load_calibration(path)
    assert loaded == result.with_validation(validation)
    assert loaded.correction == result.correction


def test_a_bad_record_names_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file"):
        load_calibration(tmp_path / "missing.json")
    broken = tmp_path / "broken.json"
    broken.write_text('{\n  "fovjax_calibration": 1,\n  oops\n}\n')
    with pytest.raises(ValueError, match=re.escape(f"{broken}:3: not a JSON calibration record")):
        load_calibration(broken)
    other = tmp_path / "other.json"
    other.write_text('{"kind": "gaze"}')
    with pytest.raises(ValueError, match=re.escape(f"{other}: not a fovjax calibration record")):
        load_calibration(other)
    newer = tmp_path / "newer.json"
    newer.write_text('{"fovjax_calibration": 99}')
    with pytest.raises(ValueError, match="format 99"):
        load_calibration(newer)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"points": 3}, "points must be an integer >= 4, got 3"),
        ({"points": 7, "min_points": 3}, None),  # a settings value; the grid refuses it later
        ({"settle_s": -0.1}, "settle_s must be a finite number of seconds >= 0, got -0.1"),
        ({"collect_s": 0.0}, "collect_s must be a finite number of seconds > 0, got 0.0"),
        ({"min_valid_fraction": 1.5}, "min_valid_fraction must be in [0, 1], got 1.5"),
        ({"max_error_deg": 0.0}, "max_error_deg must be > 0 degrees, got 0.0"),
        ({"max_presentations": 0}, "max_presentations must be an integer >= 1, got 0"),
        ({"min_points": 2}, "min_points must be an integer >= 3, got 2"),
        ({"points": 9, "min_points": 12}, "min_points (12) cannot exceed points (9)"),
        ({"distance": -1.0}, "distance must be > 0 (math.inf: infinitely far), got -1.0"),
        ({"margin": 0.5}, "margin must be in [0, 0.5), got 0.5"),
    ],
)
@pytest.mark.no_typecheck
def test_bad_settings_are_refused(kwargs, message):
    if message is None:
        CalibrationSettings(**kwargs)
        with pytest.raises(
            ValueError, match=re.escape("points must make a grid of at least 2 x 2 (4, 6, 8, 9")
        ):
            calibration_targets(kwargs["points"])
        return
    with pytest.raises(ValueError, match=re.escape(f"CalibrationSettings: {message}")):
        CalibrationSettings(**kwargs)


@pytest.mark.no_typecheck
def test_bad_arguments_are_refused_before_anything_is_shown():
    observer = Observer()
    source = tracker(observer)
    with pytest.raises(TypeError, match="source must be a fovjax.devices gaze source, got str"):
        calibrate("synthetic:scanpath", observer.present)
    with pytest.raises(ValueError, match="source must be a gaze source, got a head source"):
        calibrate(SyntheticHeadSource(speed=None), observer.present)
    with pytest.raises(TypeError, match="present must be a callable"):
        calibrate(source, None)
    with pytest.raises(TypeError, match="geometry must be a fovjax.devices.RigGeometry"):
        calibrate(source, observer.present, geometry=13.0)
    with pytest.raises(TypeError, match="settings must be a CalibrationSettings"):
        calibrate(source, observer.present, settings={"points": 9})
    with pytest.raises(ValueError, match=r"min_points \(6\) is more than the 4 targets"):
        calibrate(source, observer.present, targets=[(0.4, 0.4), (0.6, 0.4), (0.4, 0.6), (0.6, 0.6)])
    with pytest.raises(ValueError, match="targets is empty"):
        calibrate(source, observer.present, targets=[])
    with pytest.raises(
        ValueError, match=r"position 1: expected a finite display position \(x, y\), got \(nan, 0.5\)"
    ):
        calibrate(source, observer.present, targets=[(0.5, 0.5), (math.nan, 0.5)])
    with pytest.raises(ValueError, match="points must make a grid of at least 2 x 2"):
        calibration_targets(7)
    assert observer.presented == 0 and not source.is_open
    with pytest.raises(ValueError, match="is not invertible"):
        GazeCorrection(left=((1.0, 2.0, 0.0), (0.5, 1.0, 0.0)))
    with pytest.raises(ValueError, match="must be a finite 2 x 3 affine map"):
        GazeCorrection(right=((1.0, 0.0), (0.0, 1.0)))
    with pytest.raises(
        TypeError, match="correction must be a fovjax.devices.GazeCorrection or None, got tuple"
    ):
        source.correction = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    with pytest.raises(ValueError, match="a gaze correction applies to gaze sources, not head"):
        SyntheticHeadSource(speed=None).correction = GazeCorrection()
