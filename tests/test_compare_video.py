"""compare_methods_on_recording and `fovjax compare --video` on a tiny rig along the dropout
recording: the records' fields, a fovea covering the screen equal to the full render (JOD at the
metric's maximum), Weier's reuse while tracking is ok and its reset where tracking is lost, the
CSV and the chart, and bad arguments refused before anything is rendered."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import _extras
import pytest

import fovjax
from fovjax.eval import (
    VIDEO_RECORD_FIELDS,
    ThresholdSweep,
    VideoComparison,
    compare_methods_on_recording,
    read_csv,
)
from fovjax.render import RenderConfig, StereoRig

RECORDING = Path(__file__).resolve().parents[1] / "data/recordings/synthetic_scanpath_seed1_dropout.csv"
EYE = 32
CONFIG = RenderConfig(max_depth=0)  # no reflections: the shortest compile
METHODS = ["thesis", "guenter2012", "patney2016", "weier2016"]
# 8 frames at 10 fps from 1.9 s: ok until the tracker falls silent at 2.0 s, lost from ~2.45 s.
FRAMES, FPS, START = 8, 10.0, 1.9


@pytest.fixture(scope="module")
def renderer():
    scene = fovjax.scenes.cornell_box()
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=EYE, eye_height=EYE)
    return fovjax.FoveatedRenderer(scene, rig, config=CONFIG)


@pytest.fixture(scope="module")
def comparison(renderer) -> VideoComparison:
    _extras.require("pyfvvdp")
    screen = fovjax.full_eccentricity(renderer.rig, renderer.foveation)
    sweep = ThresholdSweep(thresholds=[(5, 10), (screen, screen)], spp=[1], methods=METHODS)
    return compare_methods_on_recording(
        renderer, RECORDING, sweep, frames=FRAMES, fps=FPS, start_s=START, blocks=2, progress=False
    )


def test_records_have_every_field(comparison):
    assert len(comparison.records) == 2 * len(METHODS)
    assert [r["method"] for r in comparison.records[: len(METHODS)]] == METHODS
    full_primary = 2 * EYE * EYE
    for r in comparison.records:
        assert set(VIDEO_RECORD_FIELDS) <= set(r), set(VIDEO_RECORD_FIELDS) - set(r)
        for name in ("jod", "jod_lo", "jod_hi", "jod_left", "jod_right"):
            assert math.isfinite(r[name]), (r["config"], name)
        assert r["jod_lo"] <= r["jod"] <= r["jod_hi"] <= 10.0
        assert r["jod_n"] == 2 and r["frames"] == FRAMES
        assert 0 < r["new_rays_per_frame"] <= full_primary and r["ms_per_frame"] > 0
        assert r["resets"] >= 2 and r["lost_frames"] >= 1  # the first frame and the loss
    # the tracking: ok first, lost later, the histories reset on the first frame and at the loss
    states = [f["state"] for f in comparison.frames]
    assert states[0] == "ok" and "lost" in states
    first_lost = states.index("lost")
    resets = [k for k, f in enumerate(comparison.frames) if f["reset"]]
    assert resets == [0, first_lost]


def test_a_fovea_covering_the_screen_is_the_full_render(comparison, renderer):
    screen = fovjax.full_eccentricity(renderer.rig, renderer.foveation)
    for method in ("thesis", "guenter2012"):
        r = comparison.record(method, (screen, screen))
        assert r["jod"] == pytest.approx(10.0, abs=1e-3), method
        assert r["psnr"] > 100, method  # the full render up to float rounding
        assert r["new_rays_per_frame"] == r["full_primary_rays_per_frame"]


def test_weier_reuses_while_tracking_is_ok_and_not_after_a_loss(comparison):
    states = [f["state"] for f in comparison.frames]
    reused = comparison.series["weier2016 5/10 spp1"]["reused"]
    first_lost = states.index("lost")
    assert reused[0] == 0  # no history yet
    # Its default `widened_fovea="reproject"`: the fallback's widening does not force tracing,
    # so every frame with a history reuses it, the degraded and lost ones too.
    later = [k for k in range(1, len(states)) if k != first_lost]
    assert first_lost + 1 in later and "degraded" in states
    assert all(reused[k] > 0 for k in later), (states, reused)
    assert reused[first_lost] == 0, (states, reused)  # the reset at the loss
    assert all(x == 0 for x in comparison.series["thesis 5/10 spp1"]["reused"])
    m = comparison.measure("weier2016", "thesis", (5, 10))
    assert m["new_rays_ratio"] > 0 and isinstance(m["at_most_half"], bool)
    assert m["jod_no_lower"] in (True, False)


def test_write_csv_and_chart(comparison, tmp_path):
    paths = comparison.write(tmp_path / "out")
    assert set(paths) == {"csv", "chart"}
    rows = read_csv(paths["csv"])
    assert [r["config"] for r in rows] == [r["config"] for r in comparison.records]
    assert paths["chart"].stat().st_size > 0


def test_cli_writes_the_table_and_chart(renderer, tmp_path, capsys):
    _extras.require("pyfvvdp")
    from fovjax.cli import main

    out = tmp_path / "cli"
    argv = ["compare", "--scene", "cornell_box", "--thresholds", "5,10", "--spp", "1"]
    argv += ["--width", str(EYE), "--height", str(EYE), "--max-depth", "0"]
    argv += ["--methods", "thesis", "weier2016", "--video", str(RECORDING), "--frames", "4"]
    argv += ["--fps", str(FPS), "--start", str(START), "--blocks", "2", "-o", str(out)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "weier2016 5/10 spp1" in text and "new rays, weier2016 / thesis" in text
    assert [r["method"] for r in read_csv(out / "video_comparison.csv")] == ["thesis", "weier2016"]
    assert (out / "video_comparison.png").is_file()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"recording": "nope.csv"}, "recording 'nope.csv'"),
        ({"frames": 1}, "frames 1: expected a whole number >= 2"),
        ({"fps": 0}, "fps 0: expected a finite number > 0"),
        ({"start_s": -1.0}, "start_s -1.0"),
        ({"start_s": 4.99, "frames": 10}, "expected frame times within the recording"),
        ({"blocks": 1}, "blocks 1: expected 0"),
        ({"blocks": 5, "frames": 8}, "blocks 5"),
        ({"sweep": "thesis"}, "sweep 'thesis'"),
        ({"sweep": ThresholdSweep(methods=["nope"])}, "method must be one of"),
        ({"tracker": 3}, "tracker 3"),
        ({"renderer": None}, "renderer None"),
    ],
)
def test_bad_arguments_fail_before_rendering(renderer, kwargs, message, monkeypatch):
    def no_render(*args, **kw):
        raise AssertionError("rendered before checking the arguments")

    monkeypatch.setattr(fovjax.FoveatedRenderer, "render", no_render)
    monkeypatch.setattr(fovjax.FoveatedRenderer, "render_full", no_render)
    args = {"renderer": renderer, "recording": RECORDING, "frames": 8, "perceptual": False, "progress": False}
    args.update(kwargs)
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(".", r"\.")):
        compare_methods_on_recording(args.pop("renderer"), args.pop("recording"), **args)


def test_cli_rejects_bad_video_arguments(tmp_path, capsys):
    from fovjax.cli import main

    for extra, message in (
        (["--video", str(tmp_path / "missing.csv")], "--video"),
        (["--video", str(RECORDING), "--frames", "1"], "--frames 1"),
        (["--frames", "4"], "--frames needs --video"),
    ):
        assert main(["compare", *extra, "-o", str(tmp_path / "c")]) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err, err
    assert not (tmp_path / "c").exists()


def test_without_pyfvvdp_it_says_which_extra(renderer, monkeypatch):
    from fovjax.eval import MissingExtraError

    monkeypatch.setitem(sys.modules, "pyfvvdp", None)  # import now raises ImportError
    with pytest.raises(MissingExtraError, match=r"fovjax\[fvvdp\]"):
        compare_methods_on_recording(renderer, RECORDING, frames=8, progress=False)
