import math

import numpy as np
import pytest
from fakes.clock import FakeClock

from fovjax.devices import (
    FixedPoints,
    Scanpath,
    SmoothPursuit,
    SyntheticGazeSource,
    SyntheticHeadSource,
    saccade_duration,
    saccade_peak_velocity,
    source_from_spec,
)


def test_main_sequence_duration_and_peak_velocity():
    assert saccade_duration(10.0) == pytest.approx(0.043)
    assert saccade_duration(0.5) == 0.030 and saccade_duration(80.0) == 0.120
    amplitudes = np.array([2, 5, 10, 20, 30, 40.0])
    peaks = np.array([saccade_peak_velocity(a) for a in amplitudes])
    assert np.all(np.diff(peaks) > 0)  # rises with amplitude ...
    assert np.all(np.diff(np.diff(peaks[2:])) < 0)  # ... and saturates
    assert saccade_peak_velocity(10.0) == pytest.approx(1.875 * 10 / 0.043)


def test_scanpath_statistics_follow_the_model():
    model = Scanpath(seed=11)
    segments = model.segments_until(400.0)
    fixations = [end - start for kind, start, end, _ in segments if kind == "fixation"]
    saccades = [(end - start, amp) for kind, start, end, amp in segments if kind == "saccade"]
    assert len(fixations) > 500
    assert np.mean(fixations) == pytest.approx(0.218, rel=0.05)
    durations = np.array([d for d, _ in saccades])
    assert durations.min() >= 0.030 - 1e-12 and durations.max() <= 0.120 + 1e-12
    for d, amp in saccades:
        assert d == pytest.approx(saccade_duration(amp))
        assert amp <= model.max_amplitude_deg
    # Samples stay inside the display less the margin and alternate fixation / saccade.
    kinds = [kind for kind, *_ in segments]
    assert all(a != b for a, b in zip(kinds, kinds[1:], strict=False))


def test_scanpath_saccade_peak_speed_matches_the_profile():
    model = Scanpath(seed=2)
    kind, start, end, amp = next(s for s in model.segments_until(5.0) if s[0] == "saccade" and s[3] > 10)
    t = np.linspace(start, end, 2001)
    xy = np.array([model.position(ti) for ti in t])
    step = np.diff(xy, axis=0) * np.array(model.display_fov_deg)
    speed = np.hypot(step[:, 0], step[:, 1]) / np.diff(t)
    assert speed.max() == pytest.approx(saccade_peak_velocity(amp), rel=1e-3)


def test_same_seed_same_scanpath_in_any_query_order():
    a, b = Scanpath(seed=7), Scanpath(seed=7)
    times = np.linspace(0, 20, 500)
    forward = [a.position(t) for t in times]
    backward = [b.position(t) for t in times[::-1]][::-1]
    assert forward == backward
    assert forward != [Scanpath(seed=8).position(t) for t in times]


def test_fixed_points_and_pursuit():
    fixed = FixedPoints([(0.2, 0.2), (0.8, 0.4)], dwell=0.5)
    assert (
        fixed.position(0.1) == (0.2, 0.2)
        and fixed.position(0.6) == (0.8, 0.4)
        and fixed.position(1.1) == (0.2, 0.2)
    )
    pursuit = SmoothPursuit(radius=(0.25, 0.25), frequency=0.1)
    pts = np.array([pursuit.position(t) for t in np.linspace(0, 10, 1000)])
    assert np.allclose(np.hypot(pts[:, 0] - 0.5, pts[:, 1] - 0.5), 0.25)


def test_fast_synthetic_source_is_deterministic_with_noise():
    def run():
        src = SyntheticGazeSource(Scanpath(3), rate=200, duration=1.0, noise_sd=0.002, seed=5, speed=None)
        with src:
            return [(s.timestamp, s.left.x, s.right.y) for s in src]

    first, second = run(), run()
    assert len(first) == 201 and first == second
    assert first[-1][0] == pytest.approx(1.0)


def test_paced_source_releases_samples_on_its_clock():
    clock = FakeClock(50.0)
    src = SyntheticGazeSource(FixedPoints(), rate=100, duration=0.5, clock=clock, sleep=clock.sleep)
    with src:
        assert src.latest().timestamp == 50.0
        clock.advance(0.0351)
        assert src.latest().timestamp == pytest.approx(50.03)  # sample 3 is the newest due
        samples = list(src)
    assert len(samples) == 51
    assert [round(s.timestamp - 50.0, 6) for s in samples[:4]] == [0.0, 0.01, 0.02, 0.03]
    assert clock.t == pytest.approx(50.5)  # it slept until the last sample was due


def test_dropouts_make_the_source_silent():
    clock = FakeClock(0.0)
    src = SyntheticGazeSource(
        FixedPoints(), rate=100, duration=2.0, dropouts=[(0.5, 1.0)], clock=clock, sleep=clock.sleep
    )
    with src:
        clock.advance(0.8)
        latest = src.latest()
        assert latest.timestamp == pytest.approx(0.49)  # nothing newer was released in the gap
        times = [s.timestamp for s in src]
    assert not any(0.5 <= t < 1.0 - 1e-9 for t in times)
    assert len(times) == 201 - 50


def test_synthetic_head_and_specs():
    head = SyntheticHeadSource(duration=1.0, speed=None)
    with head:
        poses = list(head)
    assert len(poses) == 181 and max(abs(p.yaw) for p in poses) <= 20.0
    src = source_from_spec("synthetic:fixed:0.25,0.75", "gaze", duration=0.1)
    with src:
        assert src.read().left.xy == (0.25, 0.75)
    with pytest.raises(ValueError, match="unknown synthetic gaze model"):
        source_from_spec("synthetic:nonsense")
    with pytest.raises(ValueError, match="unknown scheme"):
        source_from_spec("carrier-pigeon:1")
    with pytest.raises(ValueError, match="not an integer"):
        source_from_spec("synthetic:scanpath:x")
    assert math.isfinite(Scanpath(0).amplitude_deg((0, 0), (1, 1)))


def test_drain_hands_out_each_due_sample_once():
    clock = FakeClock(0.0)
    src = SyntheticGazeSource(
        FixedPoints(), rate=100, duration=1.0, dropouts=[(0.1, 0.2)], clock=clock, sleep=clock.sleep
    )
    with src:
        got = []
        for _ in range(120):
            got += src.drain()
            clock.advance(0.01)
        assert src.drain() == []
    times = [round(s.timestamp, 6) for s in got]
    assert times == sorted(set(times)) and len(times) == 101 - 10
    assert SyntheticGazeSource(FixedPoints(), speed=None).open().drain() == []


def test_synthetic_gaze_defaults_are_the_stated_idealised_tracker():
    """The synthetic gaze source samples at 120 Hz without noise by default, twice the thesis's
    fastest ViewPoint rate and without its 0.25-1° error: a stated choice (the source's
    docstring, the spec list, `fovjax session --help`), pinned here so a change has to move the
    statement too; a thesis-like tracker is a keyword away."""
    import inspect

    from fovjax.cli import build_parser
    from fovjax.devices import SyntheticGazeSource, _specs, _synthetic, source_from_spec

    for spec in ("synthetic:scanpath", "synthetic:pursuit", "synthetic:fixed"):
        source = source_from_spec(spec, duration=0.1)
        assert (source.rate, source.noise_sd) == (120.0, 0.0) == (_synthetic.DEFAULT_GAZE_RATE, 0.0)
    assert source_from_spec("synthetic:scanpath", rate=60.0, duration=0.1).rate == 60.0
    defaults = inspect.signature(SyntheticGazeSource).parameters
    assert (defaults["rate"].default, defaults["noise_sd"].default) == (120.0, 0.0)
    stated = "the thesis's ViewPoint tracker ran at 60 or 30 Hz (selectable) with 0.25°-1.0° accuracy"
    assert stated in " ".join(SyntheticGazeSource.__doc__.split())
    assert "the thesis's ran at 60/30 Hz, 0.25-1° accuracy" in " ".join(_specs.__doc__.split())
    session = build_parser()._subparsers._group_actions[0].choices["session"]
    assert "idealised tracker; the thesis's ran at 60/30 Hz" in session.description
