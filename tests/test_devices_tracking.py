import dataclasses
import math
import re
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fovjax.devices import (
    MISSING_EYE,
    ExponentialMovingAverage,
    EyeGaze,
    FallbackPolicy,
    GazePredictor,
    GazeSample,
    GazeTracker,
    HeadPose,
    HeadTracker,
    OneEuroFilter,
    RigGeometry,
    Scanpath,
    TrackingState,
    VelocityThresholdDetector,
    ivt_classify,
    widen_thresholds,
)

POLICY = FallbackPolicy(stale_after=0.05, hold_for=0.15, widen_every=0.1, widen_steps=4, recover_after=3)


def good(t, x=0.3, y=0.6, q=1.0):
    return GazeSample(t, EyeGaze(x, y, q, True), EyeGaze(x + 0.01, y, q, True))


def test_no_sample_ever_means_lost_and_full_rendering_at_the_centre():
    frame = GazeTracker(POLICY).step(10.0)
    assert frame.state is TrackingState.LOST and frame.widening == 1.0
    assert frame.left == (0.5, 0.5) and math.isinf(frame.sample_age)


def test_stale_gaze_holds_then_widens_step_by_step_then_recovers():
    tracker = GazeTracker(POLICY, predictor=None)
    t0 = 100.0
    # Confirm tracking with a short run of good samples (the first start needs recover_after).
    for k in range(5):
        frame = tracker.step(t0 + k * 0.01, [good(t0 + k * 0.01)])
    assert frame.state is TrackingState.OK and frame.widening == 0.0
    last = t0 + 0.04
    # The source goes silent; walk the clock and record what the tracker says.
    seen = []
    for dt in np.arange(0.0, 0.70, 0.01):
        f = tracker.step(last + dt)
        seen.append((round(dt, 2), f.state, f.widening_step))
        assert f.left == (0.3, 0.6)  # always the last good gaze, never invented
    states = {dt: (state, step) for dt, state, step in seen}
    assert states[0.05] == (TrackingState.OK, 0)
    assert states[0.06] == (TrackingState.HOLDING, 0)
    assert states[0.15] == (TrackingState.HOLDING, 0)
    assert states[0.16] == (TrackingState.DEGRADED, 1)
    assert states[0.25] == (TrackingState.DEGRADED, 1)
    assert states[0.26] == (TrackingState.DEGRADED, 2)
    assert states[0.45] == (TrackingState.DEGRADED, 3)
    assert states[0.46] == (TrackingState.LOST, 4)
    steps = [step for _, _, step in seen]
    assert steps == sorted(steps)  # widening never goes back while silent
    assert POLICY.time_to_lost() == pytest.approx(0.45)

    # Good samples return: the first two do not yet narrow the fovea (recover_after=3).
    now = last + 1.0
    f = tracker.step(now, [good(now - 0.002, 0.7, 0.2)])
    assert f.state is TrackingState.LOST and f.left == (0.3, 0.6)
    f = tracker.step(now + 0.01, [good(now + 0.008, 0.7, 0.2)])
    assert f.state is TrackingState.LOST
    f = tracker.step(now + 0.02, [good(now + 0.018, 0.7, 0.2)])
    assert f.state is TrackingState.OK and f.widening == 0.0 and f.left == (0.7, 0.2)


def test_bad_samples_are_never_rendered_from():
    tracker = GazeTracker(FallbackPolicy(recover_after=1, single_eye="reject"), predictor=None)
    tracker.step(1.0, [good(1.0, 0.4, 0.4)])
    bad = [
        GazeSample(1.01, EyeGaze(math.nan, 0.5, 1.0), EyeGaze(0.9, 0.9, 1.0)),
        GazeSample(1.02, EyeGaze(0.9, 0.9, 0.1), EyeGaze(0.9, 0.9, 0.1)),  # low confidence
        GazeSample(1.03, EyeGaze(3.0, 0.9, 1.0), EyeGaze(3.0, 0.9, 1.0)),  # far off screen
        GazeSample(1.04, MISSING_EYE, MISSING_EYE),
        GazeSample(math.nan, EyeGaze(0.9, 0.9), EyeGaze(0.9, 0.9)),
        GazeSample(9.0, EyeGaze(0.9, 0.9), EyeGaze(0.9, 0.9)),  # from the future: a broken clock
        GazeSample(1.05, EyeGaze(0.9, 0.9), MISSING_EYE),  # one eye, single_eye="reject"
    ]
    frame = tracker.step(1.06, bad)
    assert frame.left[0] == pytest.approx(0.4) and frame.right[0] == pytest.approx(0.41)
    assert frame.state is TrackingState.HOLDING
    r = frame.rejected
    assert (
        r["nan"] >= 1
        and r["confidence"] >= 2
        and r["offscreen"] >= 2
        and r["invalid"] >= 2
        and r["clock"] == 2
    )


# The thesis's rig: eyes turned 13° outwards, 90° horizontal field of view each. A far point
# straight ahead is at x = 0.615 in the left eye's display and 0.385 in the right's.
THESIS_RIG = RigGeometry()
AHEAD_LEFT, AHEAD_RIGHT = (tuple(float(v) for v in eye) for eye in THESIS_RIG.fixation((0.5, 0.5)))


def binocular(t, left, right):
    return GazeSample(t, EyeGaze(*left), EyeGaze(*right))


def test_a_far_point_ahead_lies_26_degrees_apart_in_the_two_eyes_displays():
    assert AHEAD_LEFT == (pytest.approx(0.6154, abs=1e-4), 0.5)
    assert AHEAD_RIGHT == (pytest.approx(0.3846, abs=1e-4), 0.5)
    # Copying one eye's position to the other moves that eye's fovea by twice the toe-out.
    assert THESIS_RIG.angle_deg("right", AHEAD_LEFT, AHEAD_RIGHT) == pytest.approx(26.0, abs=1e-9)


def test_a_bad_eye_keeps_its_own_last_gaze_on_the_thesis_rig():
    """The thesis's rule (Fig 45): an eye whose sample fails keeps its own last good point; it
    does not take the other eye's display position (0.615 for the right eye: 26° off)."""
    tracker = GazeTracker(FallbackPolicy(recover_after=1), predictor=GazePredictor(max_horizon=0.05))
    tracker.step(1.0, [binocular(1.0, AHEAD_LEFT, AHEAD_RIGHT)])
    frame = tracker.step(1.01, [binocular(1.01, AHEAD_LEFT, AHEAD_RIGHT)])
    assert frame.unmeasured_eye is None
    # The right eye fails while the left moves on: the right stays where it was, not predicted.
    moved = (AHEAD_LEFT[0] + 0.02, 0.5)
    frame = tracker.step(1.02, [GazeSample(1.02, EyeGaze(*moved), MISSING_EYE)], display_time=1.04)
    assert frame.state is TrackingState.OK and frame.unmeasured_eye == "right"
    assert frame.right == AHEAD_RIGHT
    assert frame.left[0] > moved[0]  # the measured eye is still predicted to the display time
    assert frame.stats()["unmeasured_eye"] == "right"
    # Both eyes again: the right eye's own gaze, no jump from the time it was kept.
    back = (AHEAD_RIGHT[0] + 0.02, 0.5)
    frame = tracker.step(1.03, [binocular(1.03, moved, back)], display_time=1.03)
    assert frame.right == back and frame.unmeasured_eye is None


def test_keep_has_nothing_to_keep_for_an_eye_never_seen():
    tracker = GazeTracker(FallbackPolicy(recover_after=1), predictor=None)
    frame = tracker.step(2.0, [GazeSample(2.0, MISSING_EYE, EyeGaze(0.25, 0.75, 0.9))])
    assert frame.state is TrackingState.LOST and frame.left == frame.right == (0.5, 0.5)
    assert frame.rejected["invalid"] == 1
    # Once both eyes were seen, a one-eye sample is used (the left keeps its point).
    tracker.step(2.01, [binocular(2.01, (0.6, 0.4), (0.4, 0.4))])
    frame = tracker.step(2.02, [GazeSample(2.02, MISSING_EYE, EyeGaze(0.45, 0.5, 0.9))])
    assert frame.state is TrackingState.OK and frame.left == (0.6, 0.4) and frame.right == (0.45, 0.5)


@pytest.mark.parametrize("distance", [math.inf, 0.8])
def test_map_puts_the_bad_eye_where_it_sees_the_good_eyes_point(distance):
    """``single_eye="map"``: the good eye's ray, `vergence_distance` along it, projected into the
    other eye -- exactly where the other eye sees a point the two eyes look at."""
    xy = (0.42, 0.55)
    left, right = THESIS_RIG.fixation(xy, distance)
    along = distance
    if math.isfinite(distance):  # the point's distance from the good (left) eye
        point = distance * THESIS_RIG.cyclopean_ray(xy)
        along = float(np.linalg.norm(point - THESIS_RIG.eye_position("left")))
    policy = FallbackPolicy(recover_after=1, single_eye="map", vergence_distance=along)
    tracker = GazeTracker(policy, predictor=None, geometry=THESIS_RIG)
    frame = tracker.step(3.0, [GazeSample(3.0, EyeGaze(*left), MISSING_EYE)])
    assert frame.state is TrackingState.OK and frame.unmeasured_eye == "right"
    assert frame.right == (pytest.approx(right[0], abs=1e-9), pytest.approx(right[1], abs=1e-9))
    assert abs(frame.right[0] - frame.left[0]) > 0.2  # not the left eye's display position


@pytest.mark.no_typecheck
def test_map_needs_the_rig():
    tracker = GazeTracker(FallbackPolicy(single_eye="map"))
    with pytest.raises(ValueError, match=re.escape("geometry=RigGeometry.from_rig(rig)")):
        tracker.step(0.0, [])
    with pytest.raises(TypeError, match="geometry must be a fovjax.devices.RigGeometry"):
        GazeTracker(geometry=(13.0, 0.064))


@pytest.mark.no_typecheck
def test_the_one_eye_rule_and_vergence_distance_are_checked():
    with pytest.raises(ValueError, match="single_eye must be one of .* got 'mirror'"):
        FallbackPolicy(single_eye="mirror")
    for bad in (0.0, -1.0, math.nan):
        with pytest.raises(ValueError, match="vergence_distance must be > 0"):
            FallbackPolicy(vergence_distance=bad)


def test_mirror_single_eye_is_deprecated_for_the_rule_it_meant():
    with pytest.warns(DeprecationWarning, match="mirror_single_eye=True.*single_eye='keep'"):
        assert FallbackPolicy(mirror_single_eye=True).single_eye == "keep"
    with pytest.warns(DeprecationWarning, match="single_eye='reject'"):
        policy = FallbackPolicy(mirror_single_eye=False)
    assert policy.single_eye == "reject" and "mirror_single_eye" not in dataclasses.asdict(policy)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # `fovjax session` replaces fields: no warning, the rule kept
        assert dataclasses.replace(policy, hold_for=0.3).single_eye == "reject"


def test_latest_sample_passed_every_frame_is_used_once():
    tracker = GazeTracker(FallbackPolicy(recover_after=1), predictor=None)
    sample = good(5.0)
    for k in range(10):
        tracker.step(5.0 + 0.01 * k, sample)
    assert tracker.accepted == 1


def test_prediction_extrapolates_to_display_time_only_when_fresh():
    tracker = GazeTracker(FallbackPolicy(recover_after=1), predictor=GazePredictor(max_horizon=0.05))
    tracker.step(0.00, [good(0.00, 0.30, 0.5)])
    frame = tracker.step(0.01, [good(0.01, 0.31, 0.5)], display_time=0.03)  # 1 unit/s to the right
    assert frame.prediction_horizon == pytest.approx(0.02)
    assert frame.left[0] == pytest.approx(0.31 + 0.02, abs=1e-9)
    far = tracker.step(0.012, [], display_time=1.0)  # horizon capped at 50 ms
    assert far.left[0] == pytest.approx(0.31 + 0.05, abs=1e-9)
    held = tracker.step(0.1, [], display_time=0.12)
    assert held.state is TrackingState.HOLDING and held.prediction_horizon == 0.0
    assert held.left[0] == pytest.approx(0.31)


def test_widen_thresholds_reaches_full_rendering():
    assert widen_thresholds(5.0, 10.0, 0.0, 60.0) == (5.0, 10.0)
    assert widen_thresholds(5.0, 10.0, 1.0, 60.0) == (60.0, 60.0)
    assert widen_thresholds(5.0, 10.0, 0.5, 60.0) == (32.5, 35.0)
    with pytest.raises(ValueError, match="omega0 <= omega1"):
        widen_thresholds(10.0, 5.0, 0.5, 60.0)


def test_policy_rejects_inconsistent_times():
    with pytest.raises(ValueError, match="stale_after <= hold_for"):
        FallbackPolicy(stale_after=0.2, hold_for=0.1)


def test_one_euro_and_ema_reduce_fixation_jitter_and_follow_a_step():
    rng = np.random.default_rng(1)
    t = np.arange(0, 2, 1 / 250)
    truth = np.where(t < 1.0, 0.3, 0.7)
    noisy = truth + rng.normal(0, 0.01, t.shape)
    for make in (lambda: OneEuroFilter(min_cutoff=1.0, beta=0.5), lambda: ExponentialMovingAverage(0.03)):
        f = make()
        out = np.array([f(ti, [xi, 0.5])[0] for ti, xi in zip(t, noisy, strict=True)])
        fix = (t > 0.5) & (t < 1.0)
        assert np.std(out[fix] - truth[fix]) < 0.4 * np.std(noisy[fix] - truth[fix])
        assert abs(out[-1] - 0.7) < 0.01  # it got there after the step


def test_one_euro_lags_less_than_a_slow_ema_during_fast_movement():
    t = np.arange(0, 1, 1 / 500)
    x = 0.2 + 0.5 * t  # a steady 0.5 units/s sweep
    one_euro, ema = OneEuroFilter(min_cutoff=0.5, beta=5.0), ExponentialMovingAverage(0.3)
    lag_1e = [abs(one_euro(ti, [xi, 0])[0] - xi) for ti, xi in zip(t, x, strict=True)][-1]
    lag_ema = [abs(ema(ti, [xi, 0])[0] - xi) for ti, xi in zip(t, x, strict=True)][-1]
    assert lag_1e < 0.5 * lag_ema


def test_ivt_finds_the_saccades_of_a_synthetic_scanpath():
    model = Scanpath(seed=4)
    t = np.arange(0, 5, 1 / 500)
    xy = np.array([model.position(ti) for ti in t])
    flags = ivt_classify(t, xy, threshold=30.0, display_fov_deg=model.display_fov_deg)
    truth = np.array([model.in_saccade(ti) for ti in t])
    # Every sample flagged lies in (or one sample after) a true saccade, and most saccade samples
    # are flagged (the slow ends of a minimum-jerk profile are below 30 deg/s).
    shifted = truth | np.concatenate([[False], truth[:-1]])
    assert np.all(~flags | shifted)
    assert flags[truth].mean() > 0.6
    detector = VelocityThresholdDetector(30.0, model.display_fov_deg)
    online = np.array([detector(ti, p) for ti, p in zip(t, xy, strict=True)])
    assert np.array_equal(online, flags)


def test_head_tracker_holds_last_pose_then_reports_lost():
    head = HeadTracker(stale_after=0.05, hold_for=0.5)
    assert head.step(0.0).state is TrackingState.LOST
    assert head.step(1.0, HeadPose(1.0, 10.0, 2.0, 0.0)).state is TrackingState.OK
    bad = HeadPose(1.1, math.nan, 0.0, 0.0)
    frame = head.step(1.2, [bad])
    assert frame.state is TrackingState.HOLDING and frame.yaw == 10.0 and head.rejected == 1
    lost = head.step(2.0)
    assert lost.state is TrackingState.LOST and lost.yaw == 10.0


def _sample_of(kind, t, x, y):
    if kind == "good":
        return GazeSample(t, EyeGaze(x, y, 0.9), EyeGaze(x, y, 0.9))
    if kind == "nan":
        return GazeSample(t, EyeGaze(math.nan, y, 0.9), EyeGaze(x, math.inf, 0.9))
    if kind == "lowq":
        return GazeSample(t, EyeGaze(x, y, 0.1), EyeGaze(x, y, 0.2))
    if kind == "invalid":
        return GazeSample(t, MISSING_EYE, MISSING_EYE)
    if kind == "off":
        return GazeSample(t, EyeGaze(x + 2, y, 0.9), EyeGaze(x, y - 2, 0.9))
    return GazeSample(t + 10.0, EyeGaze(x, y, 0.9), EyeGaze(x, y, 0.9))  # "future": a broken clock


@settings(max_examples=80, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(0.001, 0.3),
            st.sampled_from(["good", "nan", "lowq", "invalid", "off", "future", "silence"]),
            st.floats(0, 1),
            st.floats(0, 1),
        ),
        min_size=1,
        max_size=60,
    )
)
def test_property_gaze_only_ever_comes_from_good_samples(events):
    tracker = GazeTracker(FallbackPolicy(recover_after=2), predictor=None)
    t, good_points, previous_state = 0.0, set(), None
    for dt, kind, x, y in events:
        t += dt
        samples = [] if kind == "silence" else [_sample_of(kind, t, x, y)]
        if kind == "good":
            good_points.add((x, y))
        frame = tracker.step(t + 0.001, samples)
        assert frame.left == frame.right
        assert frame.left in good_points or (frame.left == (0.5, 0.5) and frame.state is TrackingState.LOST)
        assert 0.0 <= frame.widening <= 1.0
        assert (frame.widening == 0.0) == (frame.state in (TrackingState.OK, TrackingState.HOLDING))
        assert (frame.widening == 1.0) == (frame.state is TrackingState.LOST)
        previous_state = frame.state
    assert previous_state is not None
