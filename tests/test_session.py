"""The session runner: gaze-following fovea, the stale-gaze fallback and its recovery, outputs,
determinism, the wall clock's warm-up, the CLI, and input errors.

Every session here uses one tiny configuration (Cornell box, 48x40 per eye, one bounce, fovea
10°/20°), so the whole file compiles three programs: the base thresholds, one intermediate
widening step and the full screen (the policy below widens in two steps)."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import re
import warnings
from pathlib import Path

import _extras
import imageio.v3 as iio
import numpy as np
import pytest

import fovjax
from fovjax import FoveatedRenderer, foveate
from fovjax.devices import (
    MISSING_EYE,
    EyeGaze,
    FallbackPolicy,
    GazeSample,
    GazeTracker,
    RigGeometry,
    Source,
    load_recording,
)
from fovjax.foveate import Foveation
from fovjax.render import RenderConfig, StereoRig
from fovjax.session import SessionConfig, SessionOutput

RECORDINGS = Path(__file__).resolve().parents[1] / "data" / "recordings"
SCANPATH = RECORDINGS / "synthetic_scanpath_seed0.jsonl"
DROPOUT = RECORDINGS / "synthetic_scanpath_seed1_dropout.csv"
EYE_W, EYE_H = 48, 40
FOVEATION = Foveation(fovea_deg=10.0, periphery_deg=20.0)
CONFIG = RenderConfig(max_depth=1)
# Two widening steps: one intermediate threshold pair between the base and the full screen.
POLICY = FallbackPolicy(widen_steps=2, widen_every=0.2)


@pytest.fixture(scope="module")
def scene():
    return fovjax.scenes.BUILTIN["cornell_box"]()


@pytest.fixture(scope="module")
def rig(scene):
    return StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=EYE_W, eye_height=EYE_H)


SESSION_FIELDS = ("frames", "seconds", "fps", "clock", "fresh_key_per_frame", "warmup", "wait")


def session(scene, rig, *, out=None, video=False, debug=False, policy=None, **kwargs):
    """`run_session` on a renderer of the test's foveation and config, the session's length
    and clock, output, fallback policy and foveation given as keywords for brevity."""
    renderer = FoveatedRenderer(scene, rig, kwargs.pop("foveation", FOVEATION), CONFIG)
    config = SessionConfig(**{k: kwargs.pop(k) for k in SESSION_FIELDS if k in kwargs})
    if out is not None:
        out = SessionOutput(out, video=video, debug=debug)
    if policy is not None:
        kwargs["tracker"] = GazeTracker(policy=policy)
    kwargs.setdefault("progress", False)
    return fovjax.run_session(renderer, session=config, out=out, **kwargs)


@pytest.fixture(scope="module")
def scan(scene, rig, tmp_path_factory):
    """A scanpath replayed at 10 frames/s for 1.6 s, frames, debug views and log written; and
    the (gaze, regions) of every frame, seen through a spy on `render_foveated`."""
    out = tmp_path_factory.mktemp("scan")
    captured = []
    real = foveate.FoveatedRenderer.render

    def spy(self, gaze, **kwargs):
        frame = real(self, gaze, **kwargs)
        captured.append((np.asarray(gaze), frame.regions))
        return frame

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(foveate.FoveatedRenderer, "render", spy)
        result = session(scene, rig, gaze=f"replay:{SCANPATH}", frames=16, fps=10, out=out, debug=True)
    return result, out, captured


def recorded_gaze(path, t):
    """The recording's left-eye gaze at time t (linear between samples)."""
    samples = load_recording(path).samples
    ts = np.array([s.timestamp for s in samples])
    xy = np.array([(s.left.x, s.left.y) for s in samples])
    return np.array([np.interp(t, ts, xy[:, 0]), np.interp(t, ts, xy[:, 1])])


def test_fovea_follows_the_replayed_gaze(scan):
    result, _, captured = scan
    assert len(captured) == len(result.frames)
    # Frame 0 comes before the tracker has confirmed a gaze: full quality, then tracking.
    assert result.states()[0] == "lost" and set(result.states()[1:]) == {"ok"}
    checked = 0
    centroids = []
    for row, (gaze, regions) in zip(result.frames[1:], captured[1:], strict=True):
        # The gaze rendered is the recording's gaze at the frame's time.
        np.testing.assert_allclose(row.gaze_left, recorded_gaze(SCANPATH, row.time_s), atol=0.02)
        np.testing.assert_array_equal(gaze, [row.gaze_left, row.gaze_right])
        for eye in range(2):
            fovea = regions[eye] == foveate.FOVEA
            ys, xs = np.nonzero(fovea)
            assert len(xs) > 0
            touches_edge = ys.min() == 0 or xs.min() == 0 or ys.max() == EYE_H - 1 or xs.max() == EYE_W - 1
            if touches_edge:
                continue
            # Pixel centres at +0.5: the fovea's centroid is the gaze point in pixels.
            centroid = np.array([xs.mean() + 0.5, ys.mean() + 0.5])
            np.testing.assert_allclose(centroid, gaze[eye] * [EYE_W, EYE_H], atol=1.0)
            centroids.append(centroid)
            checked += 1
    assert checked >= 12
    # The gaze moved: the fovea visited places more than 10 pixels apart.
    spread = np.ptp(np.array(centroids), axis=0)
    assert spread.max() > 10


def test_fallback_holds_widens_and_recovers(scene, rig):
    # The recording is silent from 2.0 s to 3.0 s.
    result = session(scene, rig, gaze=f"replay:{DROPOUT}", frames=70, fps=20, policy=POLICY)
    frames, states = result.frames, result.states()
    full = result.summary["omega_full"]
    assert 90.0 < full <= 180.0
    runs = [s for i, s in enumerate(states) if i == 0 or s != states[i - 1]]
    assert runs == ["lost", "ok", "holding", "degraded", "lost", "ok"]
    first_silent = states.index("holding")
    recovered = len(states) - states[::-1].index("lost")
    silent = frames[first_silent:recovered]
    last_ok = frames[first_silent - 1]
    assert last_ok.time_s <= 2.0 < silent[0].time_s
    assert 3.0 <= frames[recovered].time_s <= 3.0 + 2 / 20
    # While silent: the gaze stays at the last good sample (the last ok frame's was predicted a
    # few ms ahead of it), and the fovea never narrows.
    for f in silent:
        assert f.gaze_left == silent[0].gaze_left and f.gaze_right == silent[0].gaze_right
    np.testing.assert_allclose(silent[0].gaze_left, last_ok.gaze_left, atol=1e-3)
    for a, b in zip(silent, silent[1:], strict=False):
        assert b.widening >= a.widening
        assert b.fovea_deg >= a.fovea_deg and b.periphery_deg >= a.periphery_deg
        assert b.fovea_pixels >= a.fovea_pixels
    held = [f for f in silent if f.tracking_state == "holding"]
    widened = [f for f in silent if f.tracking_state == "degraded"]
    lost = [f for f in silent if f.tracking_state == "lost"]
    assert all(f.fovea_deg == FOVEATION.fovea_deg and f.widening == 0 for f in held)
    assert all(f.gaze_age_s > POLICY.hold_for for f in widened)
    assert all(FOVEATION.fovea_deg < f.fovea_deg < full for f in widened)
    assert all(held[-1].fovea_pixels < f.fovea_pixels < 2 * EYE_W * EYE_H for f in widened)
    assert all(f.fovea_deg == full and f.fovea_pixels == 2 * EYE_W * EYE_H for f in lost)
    # Full quality costs more rays than the foveated frames before the silence.
    assert lost[0].primary_rays > 2 * last_ok.primary_rays
    # Recovery: the base thresholds again, at the new gaze.
    back = frames[recovered:]
    assert all(f.fovea_deg == FOVEATION.fovea_deg and f.widening == 0 for f in back)
    assert all(f.fovea_pixels < 0.2 * 2 * EYE_W * EYE_H for f in back)
    np.testing.assert_allclose(back[-1].gaze_left, recorded_gaze(DROPOUT, back[-1].time_s), atol=0.02)


class ListSource(Source):
    """Gaze samples given up front, each received once its timestamp is due on `clock`."""

    kind = "gaze"

    def __init__(self, samples):
        super().__init__()
        self.samples = list(samples)
        self._given = 0

    def _open(self):
        pass

    def _close(self):
        pass

    def drain(self):
        out = []
        now = self.clock()
        while self._given < len(self.samples) and self.samples[self._given].timestamp <= now:
            out.append(self.samples[self._given])
            self._given += 1
        return out

    def latest(self):
        return self.samples[self._given - 1] if self._given else None


def gaze_samples(start, end, xy, rate=120.0):
    eye = EyeGaze(*xy)
    return [GazeSample(start + i / rate, eye, eye) for i in range(int(round((end - start) * rate)))]


def test_nan_samples_are_never_rendered(scene, rig, monkeypatch):
    nan_eye = EyeGaze(math.nan, 0.5)
    bad = [GazeSample(0.3 + i / 120, nan_eye, nan_eye) for i in range(72)]  # 0.3 s .. 0.9 s
    source = ListSource(gaze_samples(0.0, 0.3, (0.3, 0.4)) + bad + gaze_samples(0.9, 1.2, (0.7, 0.6)))
    rendered = []
    real = foveate.FoveatedRenderer.render

    def spy(self, gaze, **kwargs):
        rendered.append(np.asarray(gaze, np.float64))
        return real(self, gaze, **kwargs)

    monkeypatch.setattr(foveate.FoveatedRenderer, "render", spy)
    result = session(scene, rig, gaze=source, frames=24, fps=20, policy=POLICY)
    assert len(rendered) == 24
    assert all(np.isfinite(g).all() for g in rendered)
    states = result.states()
    during = [f for f in result.frames if 0.3 < f.time_s < 0.9]
    # NaN samples count as silence: held at the last good gaze, then widened.
    assert all(f.gaze_left == (pytest.approx(0.3), pytest.approx(0.4)) for f in during)
    assert {"holding", "degraded"} <= {f.tracking_state for f in during}
    assert result.frames[-1].rejected_samples == len(bad) * 2  # both eyes of every NaN sample
    assert states[-1] == "ok"
    assert result.frames[-1].gaze_left == (pytest.approx(0.7), pytest.approx(0.6))


def test_a_bad_eye_keeps_its_own_gaze_on_the_toed_out_rig(scene, rig):
    """The rig turns each eye 13° outwards: a far point ahead is at x = 0.615 in the left eye and
    0.385 in the right. When the right eye's samples fail, its fovea stays on its own last gaze
    (the thesis's rule), not on the left eye's display position 26° from where it looks; with
    ``single_eye="map"`` it follows the left eye through the session's rig."""
    geometry = RigGeometry.from_rig(rig)
    left, right = (tuple(float(v) for v in eye) for eye in geometry.fixation((0.5, 0.5)))
    assert left[0] == pytest.approx(0.615, abs=2e-3) and right[0] == pytest.approx(0.385, abs=2e-3)
    both = [GazeSample(i / 120, EyeGaze(*left), EyeGaze(*right)) for i in range(36)]  # 0 .. 0.3 s
    moved = (left[0] + 0.05, left[1])
    one_eye = [GazeSample(0.3 + i / 120, EyeGaze(*moved), MISSING_EYE) for i in range(36)]
    result = session(scene, rig, gaze=ListSource(both + one_eye), frames=6, fps=10)
    late = [f for f in result.frames if f.time_s > 0.35]
    assert late and all(f.tracking_state == "ok" for f in late)
    for f in late:
        assert f.gaze_left == (pytest.approx(moved[0], abs=1e-6), pytest.approx(0.5, abs=1e-6))
        assert f.gaze_right == (pytest.approx(right[0], abs=1e-6), pytest.approx(0.5, abs=1e-6))

    mapped = session(
        scene,
        rig,
        gaze=ListSource(both + one_eye),
        frames=6,
        fps=10,
        tracker=GazeTracker(FallbackPolicy(single_eye="map"), predictor=None),
    )
    expected = geometry.transfer(moved, "left")  # the session gave the tracker its rig
    for f in (f for f in mapped.frames if f.time_s > 0.35):
        assert f.gaze_right == (pytest.approx(expected[0], abs=1e-6), pytest.approx(expected[1], abs=1e-6))
    elsewhere = GazeTracker(FallbackPolicy(single_eye="map"), geometry=RigGeometry(toe_out_deg=0.0))
    with pytest.raises(ValueError, match="not the renderer's rig"):
        session(scene, rig, gaze=ListSource(both), frames=2, fps=10, tracker=elsewhere)


def test_outputs_written(scan):
    result, out, _ = scan
    n = len(result.frames)
    with open(out / "session.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == n == 16
    assert [int(r["frame"]) for r in rows] == list(range(n))
    assert [r["tracking_state"] for r in rows] == result.states()
    assert json.loads(rows[5]["gaze_left"]) == list(result.frames[5].gaze_left)
    log = json.loads((out / "session.json").read_text())
    assert len(log["frames"]) == n
    summary = log["summary"]
    assert summary["frames"] == n and summary["clock"] == "virtual" and summary["eye_size"] == [EYE_W, EYE_H]
    assert summary["tracking_states"] == {"lost": 1, "ok": n - 1}
    assert summary["rays_total"] == sum(f.rays for f in result.frames) > 0
    assert log["frames"][0]["gaze_age_s"] is None  # inf in Python, null in JSON
    for k in range(n):
        image = iio.imread(out / f"frame_{k:05d}.png")
        debug = iio.imread(out / f"debug_{k:05d}.png")
        assert image.shape == debug.shape == (EYE_H, 2 * EYE_W, 3)
        assert result.frames[k].path == str(out / f"frame_{k:05d}.png")
    assert not (out / "session.mp4").exists()


def test_sources_status_is_logged_per_frame_and_in_the_summary(scan):
    result, out, _ = scan
    frames = result.frames
    # A replay is "connected" while open; its sample count grows with the timeline.
    assert all(f.gaze_connected and f.gaze_reconnects == 0 and f.gaze_errors == 0 for f in frames)
    counts = [f.gaze_samples for f in frames]
    assert counts == sorted(counts) and counts[-1] > counts[0] > 0
    assert all(0 <= f.gaze_sample_age_s < 0.1 for f in frames)  # the recording is 120 Hz
    assert all(f.head_connected is None and f.head_samples is None for f in frames)  # no head source
    with open(out / "session.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["gaze_samples"]) for r in rows] == counts and rows[0]["head_samples"] == ""
    gaze = json.loads((out / "session.json").read_text())["summary"]["sources"]["gaze"]
    assert gaze["spec"] == f"replay:{SCANPATH}" and gaze["device"] == f"recording {SCANPATH}"
    assert gaze["samples"] >= counts[-1] and gaze["errors"] == 0 and gaze["last_sample_age_s"] >= 0
    assert result.summary["warnings"] == []


def test_silent_device_is_named_in_a_warning(scene, rig, tmp_path, capsys):
    # pyserial's loop:// connects at once and never delivers a line: every frame falls back.
    result = session(scene, rig, gaze="serial:loop://", frames=3, fps=10, clock="virtual", out=tmp_path)
    assert result.states() == ["lost"] * 3
    assert all(f.gaze_connected and f.gaze_samples == 0 for f in result.frames)
    assert all(math.isinf(f.gaze_sample_age_s) for f in result.frames)
    (warning,) = result.summary["warnings"]
    assert "serial:loop:// (serial port loop://) never delivered a sample in 3 frame(s)" in warning
    assert result.summary["sources"]["gaze"]["last_sample_age_s"] is None
    # The command line says so on stderr and ends with status 1.
    from fovjax.cli import main

    args = ["session", "--gaze", "serial:loop://", "--frames", "2", "--clock", "virtual", "--scene"]
    args += ["cornell", "--width", str(EYE_W), "--height", str(EYE_H), "--fovea", "10", "--periphery"]
    args += ["20", "--max-depth", "1", "--no-progress", "-o", str(tmp_path / "cli")]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "fovjax session: warning: the gaze source serial:loop:// (serial port loop://)" in err


def test_unreachable_device_fails_before_compiling(scene, rig, monkeypatch):
    monkeypatch.setattr(foveate, "render_foveated", lambda *a, **k: pytest.fail("rendered"))
    with pytest.raises(fovjax.devices.DeviceError, match=r"serial:/dev/ttyNOPE .*within 0\.3 s"):
        session(scene, rig, gaze="serial:/dev/ttyNOPE", frames=2, wait=0.3)


def test_video(scene, rig, tmp_path):
    _extras.require("imageio_ffmpeg")
    result = session(scene, rig, gaze=f"replay:{SCANPATH}", frames=3, out=tmp_path, video=True)
    assert result.video == tmp_path / "session.mp4"
    with warnings.catch_warnings():  # reading runs ffmpeg too (fork + exec)
        warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
        video = iio.imread(result.video)
    assert video.shape == (3, EYE_H, 2 * EYE_W, 3)


def test_virtual_clock_is_deterministic(scan, scene, rig, tmp_path):
    _, first, _ = scan
    # Same inputs, a shorter run: the same first frames, pixel for pixel.
    session(scene, rig, gaze=f"replay:{SCANPATH}", frames=9, fps=10, out=tmp_path / "a")
    for k in range(9):
        np.testing.assert_array_equal(
            iio.imread(tmp_path / "a" / f"frame_{k:05d}.png"), iio.imread(first / f"frame_{k:05d}.png")
        )
    # Another key samples differently.
    import jax

    session(
        scene, rig, gaze=f"replay:{SCANPATH}", frames=2, fps=10, out=tmp_path / "b", key=jax.random.key(7)
    )
    assert not np.array_equal(
        iio.imread(tmp_path / "b" / "frame_00001.png"), iio.imread(first / "frame_00001.png")
    )


class TickingClock:
    """A wall clock that moves 10 ms every time it is read (rendering 'takes time')."""

    def __init__(self):
        self.t = 100.0

    def __call__(self):
        self.t += 0.01
        return self.t


def test_wall_clock_warms_up_every_widening_level(scene, rig, monkeypatch):
    clock = TickingClock()
    source = ListSource(gaze_samples(100.0, 100.3, (0.4, 0.5)))
    source.clock = clock
    calls = []
    real = foveate.FoveatedRenderer.render

    def spy(self, gaze=((0.5, 0.5), (0.5, 0.5)), **kwargs):
        calls.append(tuple(kwargs["thresholds"]))
        return real(self, gaze, **kwargs)

    monkeypatch.setattr(foveate.FoveatedRenderer, "render", spy)
    result = session(scene, rig, gaze=source, frames=24, clock="wall", policy=POLICY)
    assert result.summary["clock"] == "wall"
    levels = POLICY.widen_steps + 1
    warm, frames = calls[:levels], calls[levels:]
    assert len(frames) == 24 and len(set(warm)) == levels
    # The source went silent after 0.3 s: the session widened, with thresholds compiled up front.
    states = result.states()
    assert [s for i, s in enumerate(states) if i == 0 or s != states[i - 1]] == [
        "ok",
        "holding",
        "degraded",
        "lost",
    ]
    assert set(frames) <= set(warm)
    assert all(f.compile_s == 0 for f in result.frames)
    # Latency on the wall clock runs to the end of the frame's rendering.
    ok = [f for f in result.frames if f.tracking_state == "ok"]
    assert ok and all(f.latency_s > f.gaze_age_s for f in ok)


def test_cli_session(tmp_path, capsys):
    from fovjax.cli import main

    out = tmp_path / "cli"
    args = ["session", "--gaze", f"replay:{SCANPATH}", "--frames", "3", "--scene", "cornell"]
    args += ["--width", str(EYE_W), "--height", str(EYE_H), "--fovea", "10", "--periphery", "20"]
    args += ["--max-depth", "1", "--show-samples", "--no-progress", "-o", str(out)]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "3 frames (virtual clock)" in printed and "lost 1, ok 2" in printed
    assert sorted(p.name for p in out.glob("*.png")) == [
        f"{kind}_{k:05d}.png" for kind in ("debug", "frame") for k in range(3)
    ]
    with open(out / "session.csv", newline="") as fh:
        assert len(list(csv.DictReader(fh))) == 3


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--frames", "0"], "--frames 0: expected a whole number >= 1"),
        (["--frames", "2", "--gaze", "bogus:thing"], "unknown scheme 'bogus'"),
        (["--frames", "2", "--gaze", "replay:/no/such/file.csv"], "/no/such/file.csv"),
        (["--frames", "2", "--width", "0"], "--width 0: expected a whole number >= 1"),
    ],
)
def test_cli_errors(tmp_path, capsys, extra, message):
    from fovjax.cli import main

    args = [
        "session",
        "--gaze",
        f"replay:{SCANPATH}",
        "--scene",
        "cornell",
        "--no-progress",
        "-o",
        str(tmp_path),
    ]
    assert main(args + extra) == 2
    err = capsys.readouterr().err
    assert err.startswith("fovjax session: error:") and message in err


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"frames": 0}, "need at least one frame"),
        ({"frames": -3}, "need at least one frame"),
        ({"frames": 2.5}, "frames must be an integer"),
        ({"seconds": 0.01}, "need at least one frame"),
        ({"seconds": math.nan}, "seconds must be a finite number"),
        ({}, "give frames= or seconds="),
        ({"frames": 2, "wait": -1.0}, "wait must be a finite number of seconds >= 0, got -1.0"),
        ({"frames": 2, "seconds": 1.0}, "not both"),
        ({"frames": 2, "fps": 0}, "fps must be a positive number"),
        ({"frames": 2, "gaze": "bogus:thing"}, "unknown scheme 'bogus'"),
        ({"frames": 2, "gaze": "synthetic:spiral"}, "unknown synthetic gaze model 'spiral'"),
        ({"frames": 2, "gaze": None}, "gaze must be a source spec"),
        ({"frames": 2, "gaze": (0.5, 0.5)}, "gaze must be a source spec"),
        ({"frames": 2, "head": f"replay:{SCANPATH}"}, "is a gaze recording, not head"),
        ({"frames": 2, "clock": "sundial"}, "clock must be one of"),
    ],
)
@pytest.mark.no_typecheck
def test_bad_input_is_a_clear_value_error(scene, rig, kwargs, message):
    kwargs.setdefault("gaze", f"replay:{SCANPATH}")
    with pytest.raises(ValueError, match=re.escape(message)):
        session(scene, rig, **kwargs)


def test_temporal_method_carries_its_history_and_resets_on_tracking_loss(scene, rig):
    """Weier et al. 2016 in a session: the history runs from frame to frame (pixels reused
    while tracking is good, fewer new rays than the full frame), is reset exactly where
    tracking becomes lost (seen through a spy on the renderer), and one program serves it.
    Its default `widened_fovea="reproject"`: the fallback's widening leaves its thresholds as
    configured, so after the reset at the loss the lost frames reuse the history too."""
    calls, thresholds = [], []
    real = foveate.FoveatedRenderer.render

    def spy(self, *args, **kwargs):
        calls.append(bool(kwargs.get("reset", False)))
        thresholds.append(kwargs.get("thresholds"))
        return real(self, *args, **kwargs)

    fov = Foveation(fovea_deg=10.0, periphery_deg=20.0, method="weier2016")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(foveate.FoveatedRenderer, "render", spy)
        result = session(
            scene, rig, gaze=f"replay:{DROPOUT}", frames=34, fps=10, policy=POLICY, foveation=fov
        )
    states = result.states()
    assert "ok" in states and states.count("lost") >= 2 and "degraded" in states
    entered_lost = [s == "lost" and (i == 0 or states[i - 1] != "lost") for i, s in enumerate(states)]
    assert calls == entered_lost
    assert set(thresholds) == {(10.0, 20.0)}  # never widened
    every = 2 * EYE_W * EYE_H
    for i, f in enumerate(result.frames):
        if entered_lost[i]:  # the reset: no history, every pixel traced
            assert f.reused_pixels == 0 and f.primary_rays == every
        elif i > 0 and states[i - 1] in ("ok", "lost"):
            assert f.reused_pixels > 0 and f.primary_rays < every, (i, states[i])
    assert sum(f.compile_s > 0 for f in result.frames) == 1


@pytest.mark.parametrize(
    ("method", "widens"),
    [("thesis", True), ("guenter2012", True), ("patney2016", True), ("weier2016", False)],
)
def test_which_methods_take_the_fallbacks_widened_fovea(method, widens):
    """Only Weier's default covers a degraded tracker's widening with its history; with
    `widened_fovea="trace"` it traces the widened fovea as the other methods do."""
    assert Foveation(method=method).method.widens_fovea is widens
    assert foveate.Weier2016(widened_fovea="trace").widens_fovea is True
    with pytest.raises(ValueError, match="widened_fovea.*'reproject', 'trace'.*'blur'"):
        foveate.Weier2016(widened_fovea="blur")


def test_the_old_keywords_still_work_with_a_deprecation(scene, rig, tmp_path):
    """The tutorials' earlier call (scene, rig, foveation=, config=, policy=, frames=, fps=,
    out=, debug=) renders what the new one does, and says what replaces each keyword."""
    gaze = f"replay:{SCANPATH}"
    with pytest.warns(DeprecationWarning) as caught:
        old = fovjax.run_session(
            scene, rig, gaze=gaze, foveation=FOVEATION, config=CONFIG, policy=POLICY,
            frames=2, fps=10, out=tmp_path / "old", debug=True, progress=False,
        )  # fmt: skip
    said = " ".join(str(w.message) for w in caught)
    for replacement in ("SessionConfig(", "SessionOutput(", "GazeTracker(policy=", "FoveatedRenderer("):
        assert replacement in said
    new = session(scene, rig, gaze=gaze, frames=2, fps=10, out=tmp_path / "new", debug=True, policy=POLICY)

    def untimed(rows):  # the frames' paths and measured times differ between the runs
        return [dataclasses.replace(f, path="", render_s=0.0, compile_s=0.0) for f in rows]

    assert untimed(old.frames) == untimed(new.frames)
    for name in ("frame_00001.png", "debug_00001.png"):
        old_image, new_image = (iio.imread(tmp_path / run / name) for run in ("old", "new"))
        np.testing.assert_array_equal(old_image, new_image)


@pytest.mark.no_typecheck
def test_a_keyword_that_never_existed_is_a_type_error(scene, rig):
    with pytest.raises(TypeError, match="unexpected keyword argument 'frame'"):
        fovjax.run_session(scene, rig, gaze=f"replay:{SCANPATH}", frame=2)


@pytest.mark.no_typecheck
@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: SessionOutput(None), "directory must be a path (str or pathlib.Path), got None"),
        (lambda: SessionOutput("out", video="yes"), "video must be True or False, got 'yes'"),
        (lambda: SessionConfig(frames=3, clock="sundial"), "clock must be one of"),
    ],
)
def test_options_check_their_values(make, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        make()


@pytest.mark.no_typecheck
def test_a_renderer_brings_its_own_rig(scene, rig):
    renderer = FoveatedRenderer(scene, rig, FOVEATION, CONFIG)
    with pytest.raises(ValueError, match="the renderer has its own rig"):
        fovjax.run_session(renderer, rig, gaze=f"replay:{SCANPATH}", session=SessionConfig(frames=1))
    with pytest.raises(TypeError, match="session must be a SessionConfig, got dict"):
        fovjax.run_session(renderer, gaze=f"replay:{SCANPATH}", session={"frames": 1})
