"""compare_thresholds end to end on a tiny rig: the record fields and their arithmetic, the
intervals, the choice checked by hand against the records, the CSV and charts, the CLI."""

from __future__ import annotations

import math
import re

import _extras
import imageio.v3 as iio
import numpy as np
import pytest

import fovjax
from fovjax.eval import Comparison, ThresholdSweep, compare_thresholds, read_csv
from fovjax.render import RenderConfig, StereoRig

EYE_W, EYE_H = 32, 24
THRESHOLDS = [(5, 10), (15, 30)]
GAZES = [(0.5, 0.5), (0.3, 0.4)]
KEYS = [0, 1]
CONFIG = RenderConfig(max_depth=0)  # no reflections: the shortest compile
# What `fovjax compare` records depends on the metrics installed; in CI (every extra) both are.
HAS_FLIP = _extras.have("flip_evaluator")
HAS_FVVDP = _extras.have("pyfvvdp")

FIELDS = {
    "config",
    "fovea_deg",
    "periphery_deg",
    "spp",
    "model",
    "regions",
    "rays_per_frame",
    "ms_per_frame",
    "speedup",
    "ray_reduction",
    "full_ms_per_frame",
    "full_rays_per_frame",
    "n",
    "timing",
    "pareto",
    *(f"{m}{suffix}" for m in ("psnr", "ssim") for suffix in ("", "_lo", "_hi")),
}


@pytest.fixture(scope="module")
def scene_rig():
    scene = fovjax.scenes.cornell_box()
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=EYE_W, eye_height=EYE_H)
    return scene, rig


def _compare(scene_rig, criterion) -> Comparison:
    scene, rig = scene_rig
    return compare_thresholds(
        fovjax.FoveatedRenderer(scene, rig, config=CONFIG),
        sweep=ThresholdSweep(thresholds=THRESHOLDS, spp=[1], gazes=GAZES, keys=KEYS),
        criterion=criterion,
        perceptual=False,
        progress=False,
    )


@pytest.fixture(scope="module")
def everything_passes(scene_rig):
    # PSNR above 0 dB: every configuration meets it.
    return _compare(scene_rig, ("psnr", 0.0))


def _by_hand(records, metric, threshold, higher_is_better):
    """The cheapest (ms per frame) record whose whole interval is on the right side."""
    bound = f"{metric}_lo" if higher_is_better else f"{metric}_hi"
    ok = [r for r in records if (r[bound] > threshold if higher_is_better else r[bound] < threshold)]
    return min(ok, key=lambda r: r["ms_per_frame"])["config"] if ok else None


def test_records_fields_and_arithmetic(everything_passes):
    result = everything_passes
    assert [r["config"] for r in result.records] == ["5/10 spp1", "15/30 spp1"]
    full = result.full[1]
    # Full stereo frame at SPP 1: one primary ray per pixel of both eyes, plus shadow rays.
    assert full["rays_per_frame"] >= 2 * EYE_W * EYE_H
    for r in result.records:
        assert FIELDS <= set(r), FIELDS - set(r)
        assert ("flip" in r) == HAS_FLIP
        assert r["n"] == len(GAZES) * len(KEYS)
        assert r["timing"] == "median of frames"
        assert r["full_ms_per_frame"] == full["ms_per_frame"]
        assert r["full_rays_per_frame"] == full["rays_per_frame"]
        assert math.isclose(r["speedup"], r["full_ms_per_frame"] / r["ms_per_frame"], rel_tol=1e-12)
        assert math.isclose(
            r["ray_reduction"], 1 - r["rays_per_frame"] / r["full_rays_per_frame"], rel_tol=1e-12
        )
        assert 0 < r["rays_per_frame"] < full["rays_per_frame"]
        for m in ("psnr", "ssim", "flip"):
            if m in r:
                assert r[f"{m}_lo"] <= r[m] <= r[f"{m}_hi"], (m, r)
                assert r[f"{m}_lo"] < r[f"{m}_hi"]  # four different frames: a real interval
    small, large = result.records
    # A larger fovea traces more rays and is closer to the full render.
    assert small["rays_per_frame"] < large["rays_per_frame"]
    assert small["psnr"] < large["psnr"]
    # Rings: per configuration, error and rays per 5° ring of the widest frame's rings.
    for label in ("5/10 spp1", "15/30 spp1"):
        ring = result.rings[label]
        assert len(ring.mean_error) == len(ring.lower_deg) == len(result.ring_rays[label])
        assert np.nansum(result.ring_rays[label]) > 0


def test_choice_is_the_cheapest_meeting_the_criterion(everything_passes, scene_rig):
    records = everything_passes.records
    assert everything_passes.choice is not None
    assert everything_passes.choice.name == _by_hand(records, "psnr", 0.0, True)
    # A PSNR threshold between the two configurations' lower bounds: only the better one passes.
    lows = sorted(r["psnr_lo"] for r in records)
    assert lows[0] < lows[1]
    between = _compare(scene_rig, ("psnr", (lows[0] + lows[1]) / 2))
    expected = _by_hand(between.records, "psnr", between.criterion[1], True)
    assert expected == max(records, key=lambda r: r["psnr_lo"])["config"]
    assert between.choice.name == expected
    # Above every upper bound: nothing qualifies.
    beyond = _compare(scene_rig, ("psnr", max(r["psnr_hi"] for r in records) + 1.0))
    assert beyond.choice is None
    if HAS_FLIP:  # FLIP: lower is better, the upper bound must stay below
        highs = sorted(r["flip_hi"] for r in records)
        flip = _compare(scene_rig, ("flip", (highs[0] + highs[1]) / 2))
        assert flip.choice.name == _by_hand(flip.records, "flip", flip.criterion[1], False)
        assert flip.choice.name == min(records, key=lambda r: r["flip_hi"])["config"]


def test_write_csv_and_charts(everything_passes, tmp_path):
    paths = everything_passes.write(tmp_path)
    rows = read_csv(paths["csv"])
    assert [r["config"] for r in rows] == [r["config"] for r in everything_passes.records]
    for row, rec in zip(rows, everything_passes.records, strict=True):
        assert math.isclose(float(row["speedup"]), rec["speedup"], rel_tol=1e-9)
        assert math.isclose(float(row["psnr_lo"]), rec["psnr_lo"], rel_tol=1e-9)
    charts = [p for name, p in paths.items() if name != "csv"]
    assert {p.name for p in charts} == {
        "cost_accuracy_ms_spp1.png",
        "cost_accuracy_rays_spp1.png",
        "bars_spp1.png",
        "rings.png",
    }
    for p in charts:
        image = iio.imread(p)
        assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100
        assert image.std() > 0  # something is drawn


def test_cli_compare(scene_rig, tmp_path, capsys):
    from fovjax.cli import main

    out = tmp_path / "cmp"
    # The same tiny configuration as the fixtures, so the compiled programs are reused.
    argv = ["compare", "--scene", "cornell_box", "--thresholds", "5,10", "15,30", "--spp", "1"]
    argv += ["--width", str(EYE_W), "--height", str(EYE_H), "--gazes", "0.5,0.5", "0.3,0.4"]
    argv += ["--keys", "0", "1", "--criterion", "psnr", "--threshold", "0", "--max-depth", "0"]
    argv += ["--no-perceptual", "-o", str(out)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "5/10 spp1" in text and "15/30 spp1" in text
    assert "cheapest with psnr > 0 (whole 95% interval):" in text
    assert len(read_csv(out / "comparison.csv")) == 2
    assert (out / "rings.png").is_file()


@_extras.needs("flip_evaluator")  # --fidelity auto plans by FLIP
def test_cli_compare_fidelity_auto(scene_rig, tmp_path, capsys):
    """A planned configuration beside plain foveation: its own record (planned, with the plan),
    the plan printed, both on the charts. A loose per-ring threshold: the plan drops every
    region's shadow rays (max_depth 0 leaves them as the only option), fewer rays."""
    from fovjax.cli import main

    out = tmp_path / "cmp"
    argv = ["compare", "--scene", "cornell_box", "--thresholds", "15,30", "--spp", "1"]
    argv += ["--width", str(EYE_W), "--height", str(EYE_H), "--gazes", "0.5,0.5", "0.3,0.4"]
    argv += ["--keys", "0", "1", "--max-depth", "0", "--no-perceptual", "-o", str(out)]
    # A frame tolerance no plan can exceed (FLIP lies in [0, 1]): the same plan, the bound said.
    argv += ["--fidelity", "auto", "--fidelity-threshold", "1", "--fidelity-frame-tolerance", "1"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "15/30 spp1 planned:" in text and "fovea shadows='none'" in text and "speed:" in text
    assert "added per 5° ring <= 1 and per frame <= 1," in text
    rows = read_csv(out / "comparison.csv")
    assert [(r["config"], r["planned"]) for r in rows] == [
        ("15/30 spp1", False),
        ("15/30 spp1 planned", True),
    ]
    plain, planned = rows
    assert plain["fidelity"] == "full"
    assert planned["fidelity"] == "fovea shadows='none', periphery shadows='none', outside shadows='none'"
    assert planned["rays_per_frame"] < plain["rays_per_frame"]
    assert planned["fovea_deg"] == plain["fovea_deg"] and planned["spp"] == plain["spp"]
    assert (out / "cost_accuracy_ms_spp1.png").is_file()


def test_compare_rejects_a_bad_plan_before_rendering(scene_rig):
    scene, rig = scene_rig
    with pytest.raises(ValueError, match="metric 'psnr'"):
        compare_thresholds(scene, rig, plan=("psnr", 0.1), progress=False)
    with pytest.raises(ValueError, match="threshold 3"):
        compare_thresholds(scene, rig, plan=("flip", 3), progress=False)


@pytest.mark.no_typecheck  # the package's own check of a string or a bool, not the annotation's
def test_compare_rejects_a_bad_plan_shape_or_frame_tolerance_before_rendering(scene_rig):
    scene, rig = scene_rig
    for bad in (-0.001, math.nan, math.inf, "0.005", True):
        message = re.escape(f"compare_thresholds: plan's frame tolerance {bad!r}: expected None or a finite")
        with pytest.raises(ValueError, match=message):
            compare_thresholds(scene, rig, plan=("flip", 0.01, bad), progress=False)
    for bad in (("flip",), ("flip", 0.01, 0.005, 1), "flip"):
        message = re.escape(f"compare_thresholds: plan {bad!r}: expected (metric, threshold) or (metric,")
        with pytest.raises(ValueError, match=message):
            compare_thresholds(scene, rig, plan=bad, progress=False)


@pytest.mark.no_typecheck
@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"thresholds": [(10, 5)]}, "thresholds[0] (10, 5): expected (fovea, periphery) degrees"),
        ({"thresholds": []}, "thresholds []: expected a non-empty sequence"),
        ({"spp": [1, 3]}, "spp[1] 3: expected a positive square"),
        ({"gazes": [(0.5, 1.5)]}, "gazes[0] (0.5, 1.5): expected (x, y)"),
        ({"keys": [0, -1]}, "keys[1] -1: expected an integer seed >= 0"),
        ({"rule": "sometimes"}, "rule 'sometimes': expected one of"),
        ({"regions": "square"}, "regions 'square': expected one of"),
    ],
)
def test_a_sweep_checks_its_fields(fields, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        ThresholdSweep(**fields)


def test_the_documented_keywords_still_work_with_a_deprecation(scene_rig, everything_passes):
    """The README's and the tutorials' earlier call (thresholds=, spp=, gazes=, keys=, config=)
    measures what the sweep does, and names the replacements."""
    scene, rig = scene_rig
    with pytest.warns(DeprecationWarning) as caught:
        old = compare_thresholds(
            scene, rig, thresholds=THRESHOLDS, spp=[1], gazes=GAZES, keys=KEYS, config=CONFIG,
            criterion=("psnr", 0.0), perceptual=False, progress=False,
        )  # fmt: skip
    said = " ".join(str(w.message) for w in caught)
    assert "ThresholdSweep(" in said and "FoveatedRenderer(" in said
    for a, b in zip(old.records, everything_passes.records, strict=True):
        assert a["config"] == b["config"] and a["rays_per_frame"] == b["rays_per_frame"]
        assert a["psnr"] == pytest.approx(b["psnr"], rel=1e-6)
    with pytest.raises(TypeError, match="unexpected keyword argument 'threshold'"):
        compare_thresholds(scene, rig, threshold=[(5, 10)])


def test_cli_rejects_a_bad_distributed_spec(capsys):
    from fovjax.cli import main

    with pytest.raises(SystemExit):
        main(["compare", "--distributed", "localhost:1234,2,2"])
    assert "PROCESS_ID < NUM_PROCESSES" in capsys.readouterr().err


def test_documented_defaults_and_one_frame_has_no_interval(scene_rig):
    # Every keyword but the loops' sizes at its default (config, criterion, perceptual, rule,
    # models, bvh, shard): the defaults once let config=None reach render_stereo. One gaze × one
    # key: a single frame per configuration gives no interval, so no criterion can be met.
    scene, rig = scene_rig
    one = compare_thresholds(
        scene,
        rig,
        ThresholdSweep(thresholds=[(15, 30)], spp=[1], gazes=[(0.5, 0.5)], keys=[0]),
        progress=False,
    )
    (record,) = one.records
    assert record["n"] == 1
    metrics = ["psnr", "ssim"] + ["flip"] * HAS_FLIP + ["jod"] * HAS_FVVDP
    for m in metrics:
        assert math.isfinite(record[m]) and record[f"{m}_n"] == 1, (m, record)
        assert math.isnan(record[f"{m}_lo"]) and math.isnan(record[f"{m}_hi"]), (m, record)
    assert one.criterion == ("flip", 0.05)
    assert one.choice is None
    # PSNR > 0 dB holds for any frame, yet one frame cannot pass it either.
    psnr = compare_thresholds(
        scene,
        rig,
        ThresholdSweep(thresholds=[(15, 30)], spp=[1], gazes=[(0.5, 0.5)], keys=[0]),
        criterion=("psnr", 0.0),
        perceptual=False,
        progress=False,
    )
    assert psnr.choice is None


def test_metric_summary_needs_two_finite_samples():
    from fovjax.eval._compare import _summarise

    two = _summarise("psnr", [30.0, 32.0])
    assert two["psnr"] == 31.0 and two["psnr_lo"] < 31.0 < two["psnr_hi"] and two["psnr_n"] == 2
    # One finite sample among infinite ones (identical frames but one): no interval.
    mixed = _summarise("psnr", [math.inf, 30.0, math.inf])
    assert mixed["psnr"] == 30.0 and math.isnan(mixed["psnr_lo"]) and mixed["psnr_n"] == 1
    # Every frame identical to the reference: the degenerate interval at +inf, which passes.
    same = _summarise("psnr", [math.inf, math.inf])
    assert same["psnr"] == same["psnr_lo"] == same["psnr_hi"] == math.inf
    single = _summarise("flip", [0.01])
    assert single["flip"] == 0.01 and math.isnan(single["flip_lo"]) and math.isnan(single["flip_hi"])


def test_methods_side_by_side_in_one_table_and_chart(scene_rig, tmp_path, capsys):
    """`ThresholdSweep(methods=)`: every method × threshold pair in one table (the method per
    row, new rays and reused pixels per frame) and one chart of new rays across methods; the temporal method
    measured after a frame of history reuses pixels and traces fewer new rays than the full
    frame; the CLI's --methods is the same sweep."""
    from fovjax.cli import main

    scene, rig = scene_rig
    methods = ["thesis", "guenter2012", "weier2016"]
    result = compare_thresholds(
        fovjax.FoveatedRenderer(scene, rig, config=CONFIG),
        sweep=ThresholdSweep(thresholds=[(5, 10)], spp=[1], gazes=GAZES, keys=KEYS, methods=methods),
        criterion=("psnr", 0.0),
        perceptual=False,
        progress=False,
    )
    assert [r["method"] for r in result.records] == methods
    assert [r["config"] for r in result.records] == [f"{m} 5/10 spp1" for m in methods]
    full_primary = 2 * EYE_W * EYE_H
    by_method = {r["method"]: r for r in result.records}
    for r in result.records:
        assert FIELDS <= set(r) and r["n"] == len(GAZES) * len(KEYS)
        assert 0 < r["new_rays_per_frame"] < full_primary
    assert by_method["thesis"]["reused_pixels_per_frame"] == 0
    assert by_method["guenter2012"]["reused_pixels_per_frame"] == 0
    assert by_method["weier2016"]["reused_pixels_per_frame"] > 0
    paths = result.write(tmp_path / "api")
    assert paths["cost_accuracy_new_rays_spp1"].is_file()
    assert [r["method"] for r in read_csv(paths["csv"])] == methods
    with pytest.raises(ValueError, match="method must be one of"):
        compare_thresholds(scene, rig, ThresholdSweep(methods=["nope"]), progress=False, perceptual=False)
    with pytest.raises(ValueError, match="take neither shard"):
        compare_thresholds(
            scene, rig, ThresholdSweep(methods=["weier2016"]), shard=True, progress=False, perceptual=False
        )

    out = tmp_path / "cli"
    argv = ["compare", "--scene", "cornell_box", "--thresholds", "5,10", "--spp", "1"]
    argv += ["--width", str(EYE_W), "--height", str(EYE_H), "--gazes", "0.5,0.5", "0.3,0.4"]
    argv += ["--keys", "0", "1", "--criterion", "psnr", "--threshold", "0", "--max-depth", "0"]
    argv += ["--no-perceptual", "--methods", *methods, "-o", str(out)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert all(f"{m} 5/10 spp1" in text for m in methods)
    assert [r["method"] for r in read_csv(out / "comparison.csv")] == methods
    assert (out / "cost_accuracy_new_rays_spp1.png").is_file()
    assert main([*argv[:-2], "--methods", "nope", "-o", str(out)]) != 0
