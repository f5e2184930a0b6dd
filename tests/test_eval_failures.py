"""Failure cases: corner gaze, tracker error, after a saccade, acuity models at an equal ray
budget, and their input checks, on a tiny rig (the same scene, rig, config and foveation as
tests/test_eval_stability.py, so one session compiles the two programs once)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import fovjax
from fovjax.acuity import THESIS_MODEL, LinearMAR, PowerMAR
from fovjax.eval import (
    AcuityTerms,
    FullRenders,
    PursuitFlicker,
    SaccadeTrial,
    after_saccade,
    checkerboard_scene,
    corner_gaze,
    equal_budget_foveations,
    failure_cases,
    high_spp,
    offset_gaze,
    tracking_error,
)
from fovjax.foveate import Constant, Foveation, LinearFalloff, eccentricity_angle
from fovjax.render import RenderConfig, StereoRig

CONFIG = RenderConfig(max_depth=0)
# The equal-budget arms of these models share one ray budget; their reference ("thesis") arm is
# the foveation of every test, so every foveated frame here reuses one compiled program.
MODELS = {
    "thesis": THESIS_MODEL,
    "linear MAR": LinearMAR(1.0, 2.35),
    "fall-off": LinearFalloff(),
    "constant": Constant(),
}


@pytest.fixture(scope="module")
def tiny():
    scene = fovjax.scenes.spheres(subdivisions=1, ground_cells=2)
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=64, eye_height=48)
    budget = equal_budget_foveations(rig, Foveation(10.0, 20.0), MODELS, gazes=((0.5, 0.5),))
    return scene, rig, budget.foveations["thesis"], FullRenders(scene, rig, CONFIG)


def test_acuity_terms_reproduce_each_family():
    omega = np.linspace(0.0, 90.0, 721, dtype=np.float32)
    assert np.array_equal(np.asarray(AcuityTerms.of(THESIS_MODEL)(omega)), np.asarray(THESIS_MODEL(omega)))
    for model in (
        LinearMAR(1.0, 2.35),
        PowerMAR(0.9, 3.0, 1.7),
        LinearFalloff(5.0, 30.0, 0.05),
        Constant(0.3),
    ):
        np.testing.assert_allclose(AcuityTerms.of(model)(omega), model(omega), rtol=2e-6, atol=1e-7)
    np.testing.assert_allclose(AcuityTerms.of(Constant(0.3), 2.0)(omega), 0.6, rtol=1e-6)
    with pytest.raises(ValueError, match="cannot express"):
        AcuityTerms.of(lambda w: w)


def test_offset_gaze_is_the_stated_angle_away(tiny):
    _, rig, _, _ = tiny
    cam = rig.eye_cameras()[0]
    for angle, direction in ((4.0, 0.0), (10.0, 90.0), (7.0, 225.0)):
        shown = offset_gaze(rig, (0.5, 0.5), angle, direction)
        px = shown[0] * np.array([cam.width, cam.height], np.float32)
        measured = float(eccentricity_angle(cam, np.array([0.5, 0.5], np.float32), px[None])[0])
        assert measured == pytest.approx(angle, abs=0.01)
    assert shown[0, 0] < 0.5 and shown[0, 1] < 0.5  # 225°: left and up
    with pytest.raises(ValueError, match="leaves the screen"):
        offset_gaze(rig, (0.95, 0.5), 20.0, 0.0)
    with pytest.raises(ValueError, match="angle_deg"):
        offset_gaze(rig, (0.5, 0.5), -1.0)


def test_corner_gaze_gives_a_valid_frame_and_ring_records(tiny, tmp_path):
    scene, rig, fov, full = tiny
    case = corner_gaze(full, fov, keys=(0,))
    assert {r["gaze"] for r in case.records} == {"centre", "corner"}
    corner = [r for r in case.records if r["gaze"] == "corner"]
    centre = [r for r in case.records if r["gaze"] == "centre"]
    # The corner sees eccentricities the centre never does.
    assert max(r["ring_upper_deg"] for r in corner) > max(r["ring_upper_deg"] for r in centre)
    assert corner[0]["fovea_rays"] > 0 and centre[0]["fovea_rays"] > 0
    assert all(r["dropped"] == 0 and math.isfinite(r["frame_psnr"]) for r in case.records)
    populated = [r for r in corner if r["ring_pixels"] > 0]
    assert populated and all(math.isfinite(r["abs_error"]) for r in populated)
    assert (
        populated[0]["ring_lower_deg"] == 0 and populated[0]["abs_error"] < 1e-5
    )  # the fovea is the full render
    assert "corner" in case.finding
    paths = case.write(tmp_path)
    assert paths["csv"].exists() and paths["chart"].stat().st_size > 0


def test_tracker_error_raises_the_error_at_the_true_gaze(tiny):
    scene, rig, fov, full = tiny
    case = tracking_error(full, [fov], errors_deg=(0.0, 8.0), directions_deg=(0.0,))
    perfect, off = case.records
    assert perfect["tracker_error_deg"] == 0 and off["measured_error_deg"] == pytest.approx(8.0, abs=0.05)
    # Perfect tracking: the true fovea is the full render (to float32 rounding).
    assert perfect["abs_true_fovea"] < 1e-5 and perfect["true_fovea_covered"] == 1.0
    assert off["abs_true_fovea"] > 1e-3 + perfect["abs_true_fovea"]
    assert off["true_fovea_covered"] < 1.0


def test_after_saccade_latest_gaze_lags_and_perfect_does_not(tiny):
    scene, rig, fov, full = tiny
    case = after_saccade(full, fov, saccade=SaccadeTrial(latencies_s=(0.025,), after_s=0.05))
    rows = {(r["display"], r["frame"]): r for r in case.records}
    perfect = [r for r in case.records if r["policy"] == "perfect"]
    assert all(r["gaze_error_deg"] < 1e-3 and r["abs_true_fovea"] < 1e-5 for r in perfect)
    landing = min(r["frame"] for r in perfect if r["phase"] == "after")
    lagging = rows["latest, 25 ms", landing]
    assert lagging["gaze_error_deg"] > 1.0 and lagging["abs_true_fovea"] > 1e-3
    assert {"before", "saccade", "after"} <= {r["phase"] for r in case.records}


def test_equal_budget_models_match_rays(tiny):
    scene, rig, fov, full = tiny
    models = MODELS
    budget = equal_budget_foveations(rig, Foveation(10.0, 20.0), models, gazes=((0.5, 0.5),))
    assert budget.foveations["thesis"] == fov
    target = budget.expected_rays["thesis"]
    assert all(e == pytest.approx(target, rel=1e-4) for e in budget.expected_rays.values())
    assert budget.gains["thesis"] == 1.0 and all(0 < g < 1 for n, g in budget.gains.items() if n != "thesis")
    assert {f.ray_budget for f in budget.foveations.values()} == {budget.ray_budget}
    from fovjax.eval import acuity_models

    case = acuity_models(full, gazes=((0.5, 0.5),), rules=("either",), budgets={"either": budget})
    frames = [r for r in case.records if r["kind"] == "frame"]
    assert len(frames) == 4 and all(r["dropped"] == 0 for r in frames)
    assert all(abs(r["primary_rays_vs_reference"]) < 0.05 for r in frames)
    rings = [r for r in case.records if r["kind"] == "ring"]
    assert sum(r["ring_primary_rays"] for r in rings if r["model"] == "thesis") == frames[0]["primary_rays"]
    # Under the strict rule every sample beyond the fovea is the curve's draw: gains still match.
    strict = equal_budget_foveations(rig, Foveation(10.0, 20.0, rule="strict"), models)
    target = strict.expected_rays["thesis"]
    assert all(e == pytest.approx(target, rel=1e-4) for e in strict.expected_rays.values())
    assert strict.gains != budget.gains


def test_high_spp_compares_the_foveated_frame_with_the_full_one(tiny):
    scene, rig, fov, _ = tiny
    case = high_spp(
        scene, rig, (float(fov.fovea_deg), float(fov.periphery_deg)), spp=(1,), keys=(0,), config=CONFIG
    )
    (row,) = case.records
    assert row["spp"] == 1 and row["key"] == 0
    assert 0 < row["foveated_primary_rays"] < row["full_primary_rays"]
    assert row["ray_reduction"] > 0
    # One key: the "converged" image is the full frame itself.
    assert row["abs_full_vs_converged"] == 0.0
    assert row["abs_foveated_vs_full"] == row["abs_foveated_vs_converged"] > 0
    assert case.parameters["resolution"] == (rig.eye_width, rig.eye_height)


def test_checkerboard_scene_is_a_textured_wall_and_its_smooth_twin_shares_shapes():
    scene, pose = checkerboard_scene(check_size=0.05)
    smooth, _ = checkerboard_scene(check_size=0.05, smooth=True)
    tex, flat = scene.textures[0], smooth.textures[0]
    assert tex.shape == flat.shape and set(np.unique(tex)) == {np.float32(0.03), np.float32(0.9)}
    assert np.allclose(flat, tex.mean())
    assert np.shape(scene.uvs) == np.shape(smooth.uvs) and pose.position[2] > 0
    for kwargs in ({"check_size": 0.0}, {"distance": -1.0}, {"light": 2.0}):
        with pytest.raises(ValueError, match="checkerboard_scene"):
            checkerboard_scene(**kwargs)


def test_bad_inputs_raise_clear_errors(tiny):
    scene, rig, fov, full = tiny
    with pytest.raises(ValueError, match="unknown cases"):
        failure_cases(scene, rig, cases=("nope",), progress=False)
    with pytest.raises(ValueError, match="options for unknown"):
        failure_cases(scene, rig, options={"nope": {}}, progress=False)
    with pytest.raises(ValueError, match="policies"):
        after_saccade(full, fov, policies=("psychic",))
    with pytest.raises(ValueError, match="latencies_s"):
        SaccadeTrial(latencies_s=(-0.01,))
    with pytest.raises(ValueError, match="PursuitFlicker: frames must be a whole number >= 2, got 1"):
        PursuitFlicker(frames=1)
    with pytest.raises(ValueError, match="rules"):
        from fovjax.eval import acuity_models

        acuity_models(full, fov, rules=("loose",))
    with pytest.raises(ValueError, match="positive squares"):
        high_spp(scene, rig, spp=(1, 3))
    with pytest.raises(ValueError, match="errors >= 0"):
        tracking_error(full, [fov], errors_deg=(-1.0,))
    with pytest.raises(ValueError, match="off-screen"):
        corner_gaze(full, fov, corner=(1.2, 0.5))
    with pytest.raises(ValueError, match="at least one model"):
        equal_budget_foveations(rig, fov, {})
    with pytest.raises(ValueError, match="cannot reach"):
        equal_budget_foveations(rig, Foveation(10.0, 20.0), {"thesis": THESIS_MODEL, "zero": Constant(0.0)})


def test_default_models_load_the_fitted_linear_mar_curve():
    """The second default model is the repository's fit (E2 2.35°), not Song et al.'s 2.72°."""
    from fovjax.acuity import read_fit
    from fovjax.eval import FITTED_MAR, default_models

    assert FITTED_MAR.is_file(), FITTED_MAR
    fitted = read_fit(FITTED_MAR)["params"]["e2"]
    models = default_models()
    mars = {name: m for name, m in models.items() if isinstance(m, LinearMAR)}
    assert list(mars) == [f"linear MAR fit (E2 {fitted:.2f}°)"] == ["linear MAR fit (E2 2.35°)"]
    (mar,) = mars.values()
    assert float(mar.e2) == pytest.approx(fitted, rel=1e-6) and float(mar.a) == 1.0
    assert list(models)[0] == "thesis exponential" and models["thesis exponential"] is THESIS_MODEL


def test_a_missing_or_wrong_fit_is_an_error(tmp_path, capsys):
    from fovjax.cli import main
    from fovjax.eval import default_models

    missing = tmp_path / "no_fit.json"
    with pytest.raises(FileNotFoundError, match="no_fit.json: no such file"):
        default_models(missing)
    exponential = fovjax.eval.FITTED_MAR.parent / "yavuz2009_exponential.json"
    with pytest.raises(ValueError, match="Exponential fit; the acuity models need a linear-MAR fit"):
        default_models(exponential)
    # The command refuses before rendering anything: one line, exit 2.
    assert main(["failures", "--acuity-fit", str(missing), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"fovjax failures: error: --acuity-fit {missing}: no such file", err
    assert not (tmp_path / "out").exists()


def test_cli_registers_failures_and_stability():
    from fovjax.cli import _failures as _cli_failures
    from fovjax.cli import _stability as _cli_stability
    from fovjax.cli import build_parser

    parser = build_parser()
    args = parser.parse_args(["failures", "--cases", "corner_gaze", "--small", "64x48", "--spp", "1", "4"])
    assert args.func is _cli_failures.run_failures and args.small == (64, 48) and args.spp == [1, 4]
    args = parser.parse_args(["stability", "--gaze", "pursuit", "--frames", "4"])
    assert args.func is _cli_stability.run_stability and args.frames == 4
    with pytest.raises(SystemExit):
        parser.parse_args(["failures", "--small", "64by48"])
    with pytest.raises(SystemExit):
        parser.parse_args(["failures", "--cases", "nope"])


@pytest.mark.no_typecheck
def test_a_case_needs_full_renders_of_what_to_render(tiny):
    scene, _, fov, _ = tiny
    for case in (after_saccade, corner_gaze):
        with pytest.raises(TypeError, match="the first argument must be a fovjax.eval.FullRenders"):
            case(scene, fov)
