"""Model choice, the `fovjax fit` command, fit records, the committed fits, the stability sweep."""

import csv
import hashlib
import json
import shlex
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fovjax.acuity as fa
from fovjax.cli import build_parser, main

REPO = Path(__file__).resolve().parents[1]
CURVE = REPO / "data" / "mandelbaum" / "curve_samples.csv"
PUBLISHED = REPO / "data" / "published" / "linear_mar_e2.csv"
COMMITTED = {"curve_samples.json": CURVE, "published_linear_mar.json": PUBLISHED}


def test_compare_picks_the_exponential_for_the_thesis_curve():
    cmp = fa.compare(fa.load_csv(CURVE))
    assert cmp.chosen == "exponential" and cmp.best_aic == "exponential"
    assert cmp["exponential"].loo_rmse < 1e-8
    assert cmp["linear_mar"].loo_rmse > 0.1 and cmp["linear_mar"].delta_aic > 100
    assert "chosen: exponential" in cmp.table()


def test_compare_prefers_the_simpler_nested_model_within_two_aic():
    rng = np.random.default_rng(0)
    omega = np.array([0, 1, 2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 25, 30, 40], float)
    clean = 1.0 / (1.0 + omega / 3.0)
    data = fa.from_arrays(omega, clean * (1 + 0.05 * rng.standard_normal(omega.size)), 0.05 * clean)
    cmp = fa.compare(data)
    # power_mar nests linear_mar (p = 1) and fits at least as well; with ΔAIC < 2 the simpler wins.
    # (For data truly from linear MAR, power_mar beats it by ΔAIC > 2 about 4.5% of the time.)
    assert cmp.chosen == "linear_mar"
    assert cmp["power_mar"].fit.metrics["chi2"] <= cmp["linear_mar"].fit.metrics["chi2"]
    assert cmp["linear_mar"].delta_aic < 2.0
    assert cmp["exponential"].delta_aic > 10
    d = cmp.to_dict()
    assert d["chosen"] == "linear_mar" and len(d["scores"]) == 3


def test_compare_lists_a_model_that_fails_and_chooses_among_the_rest():
    data = fa.from_arrays([0.0, 0.5, 1.0, 1.5, 2.0], [1.0, 0.95, 0.9, 0.85, 0.8])
    cmp = fa.compare(data)
    failed = cmp["exponential"]
    assert failed.fit is None and "step limit" in failed.error
    assert cmp.scores[-1].name == "exponential"
    assert cmp.chosen in ("linear_mar", "power_mar")


def test_leave_one_out_on_exact_data():
    omega = np.linspace(0.0, 20.0, 8)
    data = fa.from_arrays(omega, 0.9 / (1.0 + omega / 2.5))
    err, failed = fa.leave_one_out(fa.fit(data, "linear_mar"))
    assert failed == 0 and np.max(np.abs(err)) < 1e-7


def _file_hash(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def test_fit_command_writes_a_record_that_loads_into_a_jittable_model(tmp_path, capsys):
    stem = tmp_path / "fits" / "thesis"
    assert main(["fit", str(CURVE), "-o", str(stem)]) == 0
    out = capsys.readouterr().out
    assert "exponential" in out and "wrote" in out
    record = json.loads(stem.with_suffix(".json").read_text())
    assert record["schema"] == "fovjax.acuity.fit/1"
    assert record["data"]["sha256"] == _file_hash(CURVE)
    assert record["command"].startswith("fovjax fit ") and "--model exponential" in record["command"]
    assert record["versions"]["jax"] == jax.__version__
    assert set(record["metrics"]) >= {"r2", "rmse", "aic", "bic", "n", "k"}
    assert stem.with_suffix(".png").stat().st_size > 10_000

    model = fa.load_fit(stem.with_suffix(".json"))
    assert isinstance(model, fa.Exponential)
    omega = jnp.linspace(0.0, 40.0, 17, dtype=jnp.float32)
    v = jax.jit(lambda m, w: m(w))(model, omega)
    assert v.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(v), np.asarray(fa.THESIS_MODEL(omega)), rtol=1e-6)


def test_fit_command_with_bootstrap_and_a_fixed_parameter(tmp_path):
    stem = tmp_path / "pub"
    argv = ["fit", str(PUBLISHED), "--model", "linear_mar", "--fix", "a=1", "--posterior", "bootstrap"]
    assert main([*argv, "--n-boot", "16", "--plot-max", "20", "-o", str(stem)]) == 0
    record = fa.read_fit(stem.with_suffix(".json"))
    assert record["fixed"] == {"a": 1.0} and record["posterior"]["method"] == "bootstrap"
    assert "--fix a=1" in record["command"] and "--plot-max 20" in record["command"]
    model = fa.load_fit(stem.with_suffix(".json"), estimate="posterior_median")
    assert model.params()["a"] == 1.0
    assert not (tmp_path / "pub_corner.png").exists()  # one free parameter: no corner plot


def test_cli_choices_match_the_package():
    from fovjax.cli import _fit as _cli

    assert set(_cli.MODEL_NAMES) == set(fa.MODEL_FAMILIES)
    assert set(_cli.SOLVER_NAMES) == set(fa.SOLVERS)


def test_fit_command_reports_bad_data(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("eccentricity_deg,acuity,sd,n,condition,source\n0,1,,,c,s\n2,0,,,c,s\n")
    assert main(["fit", str(bad), "-o", str(tmp_path / "x")]) == 2  # a bad input file
    assert "bad.csv:3: acuity = 0 must be > 0" in capsys.readouterr().err
    assert not (tmp_path / "x.json").exists()


def test_load_fit_errors(tmp_path):
    with pytest.raises(ValueError, match="cannot read fit record"):
        fa.load_fit(tmp_path / "none.json")
    (tmp_path / "w.json").write_text(json.dumps({"schema": "other"}))
    with pytest.raises(ValueError, match="schema is 'other'"):
        fa.load_fit(tmp_path / "w.json")
    (tmp_path / "p.json").write_text(
        json.dumps({"schema": "fovjax.acuity.fit/1", "model": "linear_mar", "params": {"a": 1}})
    )
    with pytest.raises(ValueError, match=r"p\.json: linear_mar: parameters \['e2'\] missing"):
        fa.load_fit(tmp_path / "p.json")
    with pytest.raises(ValueError, match="no posterior"):
        fa.load_fit(tmp_path / "p.json", estimate="posterior_median")


@pytest.mark.parametrize("name", list(COMMITTED))
def test_committed_fit_is_reproduced_by_its_recorded_command(name):
    path = REPO / "fits" / name
    record = fa.read_fit(path)
    data_path = REPO / record["data"]["path"]
    assert data_path.resolve() == COMMITTED[name].resolve()
    assert record["data"]["sha256"] == _file_hash(data_path), "data changed since the fit was committed"
    argv = shlex.split(record["command"])
    assert argv[:2] == ["fovjax", "fit"]
    args = build_parser().parse_args(argv[1:])
    assert (REPO / args.output).with_suffix(".json").resolve() == path.resolve()
    assert (REPO / args.output).with_suffix(".png").exists()
    # Re-run the least-squares part of the recorded command (the posterior is seeded, but slow).
    res = fa.fit(fa.load_csv(data_path), args.model, solver=args.solver, fixed=dict(args.fix))
    for k, v in record["params"].items():
        assert res.params[k] == pytest.approx(v, rel=1e-8), k
    assert fa.load_fit(path).params() == pytest.approx(record["params"], rel=1e-12)


def test_stability_sweep_small(tmp_path):
    cfg = fa.SweepConfig(
        solvers=("levenberg_marquardt", "gauss_newton"),
        sizes=(3, 6),
        ranges=(40.0, 3.0),
        noises=(0.0,),
        seeds=1,
        start_a=(0.9,),
        start_b=(0.3, 3.0),
        start_c=(0.0,),
    )
    out = fa.write_sweep(tmp_path, cfg, write_runs=True)
    assert out["runs"] == 2 * 4 * 3
    runs = list(csv.DictReader(open(tmp_path / "runs.csv")))
    assert {r["outcome"] for r in runs if r["n"] == "3"} == {"too_few_points"}
    ok = [r for r in runs if r["outcome"] == "ok" and r["n"] == "6" and r["wmax"] == "40"]
    assert ok and all(abs(float(r["b"]) / 2.9661 - 1) < 1e-6 for r in ok)
    # Which way a solver fails from a poor start (Gauss–Newton from b = 0.3 loses rank here) is the
    # path of a chaotic iteration and differs between machines: pin only that every run has a
    # known outcome and that no run reported "ok" with numbers away from the truth (above).
    assert {r["outcome"] for r in runs} <= set(fa._stability.OUTCOME_ORDER)
    assert all(r["outcome"] != "ok" or abs(float(r["b"]) / 2.9661 - 1) < 1e-4 for r in runs if r["n"] == "6")
    summary = list(csv.DictReader(open(tmp_path / "summary.csv")))
    assert len(summary) == 2 * 2 * 2 and {"success_rate", "step_limit", "median_err_b"} <= set(summary[0])
    assert (tmp_path / "stability.png").stat().st_size > 10_000
