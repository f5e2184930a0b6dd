"""The user study emulated on video (`fovjax.eval.video_study`, `fovjax study --video`): the full
render judged against itself scores 10 JOD, a heavier foveation is not judged better than a
lighter one on the same sequence, the metric's fixation follows the gaze per frame, the sequence
compiles once, the verdict follows the JODs by the decision rule, the display model keeps the
SX111's field of view at any resolution, and bad arguments are refused before any rendering.

Rendered on the Cornell box at 2 x 32x32, 4 frames (one module-scoped sequence)."""

import dataclasses
import math
import re

import _extras
import numpy as np
import pytest

import fovjax
import fovjax.eval as fe
import fovjax.render
from fovjax.cli import main

TINY = {"eye_width": 32, "eye_height": 32, "frames": 4, "fps": 60.0, "gaze": "fixed", "seed": 3}
ANIMATION = fe.StudyAnimation(**TINY)
LIGHT, HEAVY = (15.0, 30.0), (5.0, 10.0)


class Rendered(BaseException):
    """Raised by the trapped renderer: a bad argument reached the rendering."""


def _trap(*args, **kwargs):
    raise Rendered("rendering started before the arguments were refused")


@pytest.fixture(scope="module")
def scene():
    return fovjax.scenes.cornell_box()


@pytest.fixture(scope="module")
def sequence(scene):
    fovjax.render.clear_compile_cache()
    return fe.study_sequence(scene, ANIMATION)


@pytest.fixture(scope="module")
def study(scene, sequence):
    _extras.require("pyfvvdp")
    return fe.video_study(scene, sequence=sequence)


def test_sequence_compiles_once_for_the_full_and_once_for_the_foveated_frames(sequence):
    # 4 frames x (1 full + 5 levels) with a new head pose, head position, key and thresholds each.
    assert sequence.traces == {"stereo": 1, "foveated": 1}
    assert sequence.reference.shape == (4, 32, 64, 3)
    assert set(sequence.foveated) == set(fe.APPENDIX_LEVELS)
    assert all(v.shape == sequence.reference.shape for v in sequence.foveated.values())
    # The head moved and turned: no two frames from the same place.
    assert len({tuple(p) for p in sequence.positions.tolist()}) == 4
    assert np.ptp(sequence.head_poses[:, 0]) > 0
    # A smaller fovea traces fewer primary rays than a larger one, both fewer than the full render.
    rays = [sequence.primary_rays[level] for level in fe.APPENDIX_LEVELS]
    assert rays == sorted(rays) and rays[-1] < sequence.primary_rays[None]


def test_a_temporal_method_carries_its_history_through_the_sequence(scene, sequence):
    """Weier et al.'s method in the study: each level's renderer keeps its history from frame
    to frame (pixels shown from it after the first frame, which has none), the rows say which
    method made them, and the thesis's sequence reused nothing."""
    animation = fe.StudyAnimation(**{**TINY, "levels": [HEAVY], "method": "weier2016"})
    weier = fe.study_sequence(scene, animation)
    assert weier.method == "weier2016" and sequence.method == "thesis"
    frames = weier.frames
    # Mean over the frames of pixels shown from the history: none in the first frame, so at most
    # (frames - 1) / frames of the screen; some in the others (a slow walk, a fixed gaze).
    screen = 2 * TINY["eye_width"] * TINY["eye_height"]
    assert 0 < weier.reused_pixels[HEAVY] <= screen * (frames - 1) / frames
    assert all(v == 0 for v in sequence.reused_pixels.values())
    assert weier.primary_rays[HEAVY] < weier.primary_rays[None]


def test_scanpath_gaze_moves_and_fixed_gaze_stays_at_the_centre(scene, sequence):
    assert np.all(sequence.gaze == 0.5)
    animation = fe.StudyAnimation(**{**TINY, "levels": [HEAVY], "gaze": "scanpath", "frames": 30, "seed": 0})
    path = fe.study_sequence(scene, animation)
    g = path.gaze
    assert g.shape == (30, 2, 2) and np.all((g >= 0) & (g <= 1))
    assert np.array_equal(g[:, 0], g[:, 1])  # both eyes at the same point
    assert np.ptp(g[:, 0, 0]) > 0.01  # seed 0: a saccade at 0.21-0.32 s
    assert path.traces == {"stereo": 0, "foveated": 0}  # same configuration: nothing recompiled


def test_reference_against_itself_is_at_the_top_of_the_scale(study):
    assert float(study.reference_jod) == pytest.approx(10.0, abs=1e-3)
    assert all(float(j) < 10.0 + 1e-3 for j in study.jods.values())


def test_heavier_foveation_is_not_judged_better(study):
    jods = [float(study.jods[level]) for level in fe.APPENDIX_LEVELS]
    assert float(study.jods[HEAVY]) <= float(study.jods[LIGHT])
    assert jods[0] < 10.0 - 0.01  # 5/10 on a 2-pixels-per-degree display is visibly different


def test_the_metrics_fixation_is_the_gaze_per_frame(study, sequence):
    # The same frames judged with the fixation moved to a corner: a different JOD for the
    # heavily foveated level (the metric is fixation-dependent, frame by frame).
    corner = dataclasses.replace(sequence, gaze=np.full_like(sequence.gaze, 0.05))
    moved = fe.judge_sequence(corner)[HEAVY]
    assert abs(float(moved) - float(study.jods[HEAVY])) > 1e-3
    # Without foveated sensitivity the gaze does not matter.
    plain = fe.judge_sequence(sequence, foveated=False)[HEAVY]
    plain_corner = fe.judge_sequence(corner, foveated=False)[HEAVY]
    assert float(plain) == pytest.approx(float(plain_corner), abs=1e-6)


def test_verdict_follows_the_jods_by_the_decision_rule(study):
    seen = {level: 10.0 - float(jod) > fe.JND_JOD for level, jod in study.jods.items()}
    first_same = next((level[0] for level in fe.APPENDIX_LEVELS if not seen[level]), None)
    assert study.majorities["pair"] == first_same
    assert study.majorities["ramp up"] == first_same
    assert study.majorities["slider"] == (fe.APPENDIX_LEVELS[-1][0] if first_same is None else first_same)
    rows = study.records()
    assert [r["seen"] for r in rows] == [seen[level] for level in fe.APPENDIX_LEVELS]
    assert all(r["d"] == pytest.approx(10.0 - r["jod"]) for r in rows)


def test_sx111_display_keeps_the_field_of_view_at_any_resolution():
    full = fe.sx111_display()
    assert full.vfov_deg == pytest.approx(64.0)
    assert full.hfov_deg == pytest.approx(2 * math.degrees(math.atan(math.tan(math.radians(32)) * 1.25)))
    eighth = fe.sx111_display(160, 128)
    assert eighth.vfov_deg == pytest.approx(64.0) and eighth.hfov_deg == pytest.approx(full.hfov_deg)
    assert eighth.ppd == pytest.approx(full.ppd / 8)


def test_write_and_cli_print_the_verdict_beside_the_thesis(tmp_path, capsys, study):
    paths = study.write(tmp_path / "api")
    for name in ("video_study.csv", "majority.csv", "responses.csv", "fig66_pair_test.png"):
        assert (tmp_path / "api" / name).is_file()
    assert len(fe.read_csv(paths["video_study"])) == 5
    out = tmp_path / "cli"
    argv = ["study", "--video", "--scene", "cornell", "--width", "32", "--height", "32", "--frames", "4"]
    assert main([*argv, "--gaze", "fixed", "--seed", "3", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "full render against itself: 10.000 JOD" in text
    # Each test's line: the majority the observers gave (the API's, same sequence and observers)
    # beside the thesis's; the thesis column alone is the same whatever the study found.
    levels = dict(fe.APPENDIX_LEVELS)
    for test, fovea in study.majorities.items():
        accepts = "none (no level has a majority)" if fovea is None else f"{fovea:g}°/{levels[fovea]:g}°"
        row = re.search(rf"^\s*{test}  (.+?)\s+12\.5°/25°$", text, re.M)
        assert row is not None and row.group(1) == accepts, (test, accepts, text)
    written = fe.read_csv(out / "video_study.csv")
    # The command renders the same sequence as the API: the same JODs.
    assert [r["jod"] for r in written] == pytest.approx([float(study.jods[lv]) for lv in fe.APPENDIX_LEVELS])


BAD = [
    ({"frames": 1}, "frames must be a whole number >= 2, got 1"),
    ({"eye_width": 0}, "eye_width must be a whole number >= 8, got 0"),
    ({"fps": 0.0}, "fps must be a finite number > 0, got 0.0"),
    ({"fps": math.nan}, "fps must be a finite number > 0, got nan"),
    ({"spp": 3}, "spp must be a perfect square"),
    ({"gaze": "wander"}, "gaze must be one of ('scanpath', 'fixed'), got 'wander'"),
    ({"rule": "sometimes"}, "rule must be one of"),
    ({"keys": "random"}, "keys must be one of ('fresh', 'fixed'), got 'random'"),
    ({"method": "weier"}, "method must be one of ('thesis', 'guenter2012', 'patney2016', 'weier2016'), got"),
    ({"walk_speed": -1.0}, "walk_speed must be a finite number >= 0 (m/s), got -1.0"),
    ({"seed": -2}, "seed must be a whole number >= 0, got -2"),
    ({"levels": [(10.0, 5.0)]}, "0 <= fovea <= periphery"),
    ({"peak_luminance": 0.0}, "peak_luminance must be a number > 0 (cd/m²), got 0.0"),
    ({"observers": 0}, "n (observers) must be a whole number >= 1, got 0"),
    ({"noise_sd": -0.1}, "noise_sd must be a finite number >= 0, got -0.1"),
    ({"threshold": math.inf}, "threshold must be None or a finite number >= 0, got inf"),
]


@pytest.mark.parametrize(("kwargs", "message"), BAD)
def test_bad_arguments_are_refused_before_rendering(monkeypatch, scene, kwargs, message):
    monkeypatch.setattr(fovjax.render, "render_stereo", _trap)
    with pytest.raises(ValueError, match=re.escape(message)):
        options = {**TINY, **kwargs}
        panel = {k: options.pop(k) for k in ("observers", "noise_sd", "threshold") if k in options}
        if "observers" in panel:
            panel["n"] = panel.pop("observers")
        peak = {"peak_luminance": options.pop("peak_luminance")} if "peak_luminance" in options else {}
        fe.video_study(scene, fe.StudyAnimation(**options), observers=fe.ObserverPanel(**panel), **peak)


CLI_BAD = [
    ("--video --frames 1", "--frames 1: expected a whole number >= 2"),
    ("--video --width 4", "--width 4: expected a whole number >= 8"),
    ("--video --fps 0", "--fps 0"),
    ("--video --fps nan", "--fps nan"),
    ("--video --peak-luminance -3", "--peak-luminance -3"),
    ("--video --walk-speed inf", "--walk-speed inf"),
    ("--video --spp 3", "--spp 3: expected a perfect square"),
    ("--video --scene nowhere", "'nowhere'"),
    ("--video --metric flip", "--metric: not with --video"),
    ("--video --seed -1", "--seed -1"),
    ("--video --method weier", "--method 'weier': expected one of thesis, guenter2012, patney2016"),
    ("--responses r.csv --method weier2016", "--method: only with --video"),
    ("--responses r.csv --frames 9", "--frames: only with --video"),
]


@pytest.mark.parametrize(("args", "message"), CLI_BAD)
def test_cli_bad_arguments_exit_2_before_rendering(monkeypatch, tmp_path, capsys, args, message):
    monkeypatch.setattr(fovjax.render, "render_stereo", _trap)
    monkeypatch.setattr(fovjax.eval, "video_study", _trap)
    assert main(["study", *args.split(), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fovjax study: error: ") and message in err, err
    assert "Traceback" not in err
