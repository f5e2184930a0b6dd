"""Uncertainty: emcee against the Laplace approximation, convergence checks, the bootstrap, plots."""

import jax
import numpy as np
import pytest
from PIL import Image

import fovjax.acuity as fa


@pytest.fixture(scope="module")
def well_posed():
    """15 points of the thesis curve over 0–40° with 5% Gaussian noise and known sd."""
    rng = np.random.default_rng(7)
    omega = np.array([0, 1, 2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 25, 30, 40], float)
    with jax.enable_x64(True):
        clean = np.asarray(fa.THESIS_MODEL(omega))
    sd = 0.05 * clean
    data = fa.from_arrays(omega, clean + sd * rng.standard_normal(omega.size), sd)
    return data, fa.fit(data)


@pytest.fixture(scope="module")
def posterior(well_posed):
    data, result = well_posed
    sampler = fa.EmceeOptions(nwalkers=32, nsteps=2500)
    return fa.sample_posterior(data, "exponential", start=result, sampler=sampler, seed=1)


def test_emcee_agrees_with_the_laplace_approximation(well_posed, posterior):
    _, result = well_posed
    d = posterior.diagnostics
    assert d["converged"] and d["nsteps"] >= 50 * max(d["tau"].values())
    assert 0.15 <= d["acceptance_fraction"] <= 0.9
    for i, k in enumerate(posterior.names):
        mu, se = result.params[k], result.stderr[k]
        draws = posterior.draws[:, i]
        # Flat priors and a nearly linear model near the optimum: the posterior is close to the
        # Gaussian N(optimum, covariance). Tolerances are in units of the Laplace standard error.
        assert abs(np.median(draws) - mu) < 0.15 * se, k
        assert draws.std() == pytest.approx(se, rel=0.12), k
        lo, hi = posterior.intervals()[k]
        llo, lhi = result.intervals()[k]
        assert abs(lo - llo) < 0.25 * se and abs(hi - lhi) < 0.25 * se, k
    corr_post = np.corrcoef(posterior.draws.T)
    cov = result.covariance
    corr_lap = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    np.testing.assert_allclose(corr_post, corr_lap, atol=0.08)


def test_credible_band_brackets_the_fit(well_posed, posterior):
    _, result = well_posed
    omega = np.linspace(0, 40, 41)
    mid, lo, hi = posterior.band(omega)
    fitted = result.predict(omega)
    assert np.all(lo <= mid) and np.all(mid <= hi) and np.all(hi - lo > 0)
    assert np.all((lo <= fitted) & (fitted <= hi))
    # The delta-method band has about the same width.
    _, llo, lhi = result.band(omega)
    np.testing.assert_allclose(hi - lo, lhi - llo, rtol=0.25)


def test_short_chain_fails_the_autocorrelation_check(well_posed):
    data, result = well_posed
    with pytest.raises(
        fa.PosteriorConvergenceError, match=r"chain of 200 steps is shorter than 50× the autocorrelation"
    ):
        fa.sample_posterior(data, start=result, sampler=fa.EmceeOptions(nsteps=200))
    with pytest.warns(fa.PosteriorConvergenceWarning, match="autocorrelation"):
        s = fa.sample_posterior(data, start=result, sampler=fa.EmceeOptions(nsteps=200, on_fail="warn"))
    assert not s.diagnostics["converged"]
    with pytest.raises(ValueError, match="on_fail"):
        fa.EmceeOptions(on_fail="ignore")


def test_bootstrap_intervals(well_posed):
    data, result = well_posed
    boot = fa.bootstrap(data, "exponential", start=result, n_boot=256, seed=2)
    assert boot.method == "bootstrap" and boot.diagnostics["failed"] <= 0.05 * 256
    for i, k in enumerate(boot.names):
        lo, hi = boot.intervals()[k]
        assert lo < result.params[k] < hi
        # Resampled residuals carry the observed scatter, which for this draw is within a factor
        # of two of the stated sd.
        assert 0.5 < boot.draws[:, i].std() / result.stderr[k] < 2.0, k
    assert boot.median_model().params()["b"] == pytest.approx(result.params["b"], rel=0.05)


def test_fixed_parameters_are_not_sampled():
    data = fa.from_arrays([0.5, 1.75, 2.72, 3.0, 5.27], [0.5] * 5)
    res = fa.fit(data, "linear_mar", fixed={"a": 1.0})
    s = fa.sample_posterior(data, "linear_mar", start=res, sampler=fa.EmceeOptions(nsteps=2000))
    assert s.names == ("e2",) and s.full().shape[1] == 2
    assert np.all(s.full()[:, 0] == 1.0)
    lo, hi = s.intervals()["e2"]
    assert 0 < lo < res.params["e2"] < hi


def test_plots_are_written(tmp_path, well_posed, posterior):
    _, result = well_posed
    fit_png = fa.plot_fit(result, tmp_path / "fit.png", samples=posterior)
    corner_png = fa.plot_corner(posterior, tmp_path / "corner.png", laplace=result)
    # (The Laplace-band variant of plot_fit is drawn by the CLI tests.)
    for path in (fit_png, corner_png):
        with Image.open(path) as im:
            assert im.size[0] > 500 and im.size[1] > 500
            # Not a blank canvas.
            assert len(np.unique(np.asarray(im.convert("L")))) > 20


def test_public_defaults_run(tmp_path):
    # bootstrap, sample_posterior and plot_fit with every keyword at its documented default
    # (1000 resamples; 32 walkers × 5000 steps; the thesis's curve as the reference).
    from pathlib import Path

    data = fa.load_csv(Path(__file__).resolve().parents[1] / "data" / "mandelbaum" / "curve_samples.csv")
    result = fa.fit(data)
    for samples, method in ((fa.bootstrap(data), "bootstrap"), (fa.sample_posterior(data), "emcee")):
        assert samples.method == method and samples.names == ("a", "b", "c")
        assert samples.draws.shape[1] == 3 and np.isfinite(samples.draws).all()
        for k, (lo, hi) in samples.intervals().items():
            assert lo <= result.params[k] <= hi, (method, k, lo, hi)
    path = fa.plot_fit(result, tmp_path / "fit.png")
    assert Image.open(path).size[0] > 100
