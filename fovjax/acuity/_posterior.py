"""Uncertainty: an emcee posterior (with convergence checks) and a residual bootstrap.

Both return a `Samples` object: draws of the free parameters, their medians and central credible
(or percentile) intervals, and a band for V(ω).

Priors (`sample_posterior`): independent and proper, from each family's `priors`:
"uniform" on (lo, hi) for location-like parameters (a, c) and "log_uniform" on (lo, hi) — flat in
log p — for scale-like ones (b, E2, p). The boxes are broad (a ∈ (0, 10), b and E2 ∈ (0.01°, 1000°),
p ∈ (0.1, 10), c ∈ (−1, 1)), so they matter only where the data do not constrain a parameter, and
then the posterior visibly piles against a box edge.

Likelihood: Gaussian. With per-row `sd` the standard errors sd/√n are taken as known. Without, the
noise level σ is a nuisance parameter with the Jeffreys prior 1/σ, integrated out analytically:
log L = −(n/2)·log RSS (up to a constant).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from ._data import AcuityData
from ._fit import FitResult, SolverOptions, _as_data, _single_condition, batch_fit, fit
from ._models import AcuityModel, model_family


class PosteriorConvergenceError(RuntimeError):
    """The MCMC chain is too short for its autocorrelation time, or its acceptance is off."""


class PosteriorConvergenceWarning(UserWarning):
    """Same as `PosteriorConvergenceError`, when `on_fail="warn"`."""


# emcee's guidance: trust τ only when the chain is at least ~50 τ long.
MIN_TAU_MULTIPLE = 50
# The stretch move accepts ~0.8 of proposals in one dimension and less in more; below 0.15
# walkers are stuck.
ACCEPTANCE_RANGE = (0.15, 0.9)


@dataclass(frozen=True, eq=False)
class Samples:
    """Draws of the free parameters (natural units) with fixed ones alongside."""

    family: type[AcuityModel]
    names: tuple[str, ...]  # free parameter names, the columns of `draws`
    draws: np.ndarray  # [S, k]
    fixed: dict[str, float]
    method: str  # "emcee" or "bootstrap"
    level: float = 0.95
    diagnostics: dict = field(default_factory=dict)

    def full(self) -> np.ndarray:
        """Draws of all parameters [S, P], fixed ones repeated."""
        cols = []
        for k in self.family.param_names:
            if k in self.fixed:
                cols.append(np.full(self.draws.shape[0], self.fixed[k]))
            else:
                cols.append(self.draws[:, self.names.index(k)])
        return np.stack(cols, axis=1)

    @property
    def median(self) -> dict[str, float]:
        return {k: float(np.median(self.draws[:, i])) for i, k in enumerate(self.names)}

    def intervals(self, level: float | None = None) -> dict[str, tuple[float, float]]:
        """Central intervals holding `level` of the draws."""
        level = self.level if level is None else level
        q = 100 * np.array([0.5 - level / 2, 0.5 + level / 2])
        bounds = {k: np.percentile(self.draws[:, i], q) for i, k in enumerate(self.names)}
        return {k: (float(b[0]), float(b[1])) for k, b in bounds.items()}

    def median_model(self) -> AcuityModel:
        return self.family.from_params({**self.fixed, **self.median})

    def band(self, omega, level: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pointwise median and central `level` band of V(ω) over the draws."""
        level = self.level if level is None else level
        with jax.enable_x64(True):
            curves = jax.vmap(lambda p: self.family.from_vector(p)(jnp.asarray(omega, jnp.float64)))(
                jnp.asarray(self.full())
            )
            curves = np.asarray(curves)
        lo, mid, hi = np.percentile(curves, [50 * (1 - level), 50, 50 * (1 + level)], axis=0)
        return mid, lo, hi


def _log_prob_fn(family, free, fixed_p, data: AcuityData):
    """Vectorised log posterior over x = sampling coordinates (log p for log-uniform priors)."""
    priors = [family.priors[i] for i in free]
    is_log = np.array([kind == "log_uniform" for kind, _, _ in priors])
    lo = np.array([math.log(a) if log else a for (_, a, _), log in zip(priors, is_log, strict=True)])
    hi = np.array([math.log(b) if log else b for (_, _, b), log in zip(priors, is_log, strict=True)])
    omega = jnp.asarray(data.eccentricity_deg, jnp.float64)
    acuity = jnp.asarray(data.acuity, jnp.float64)
    se = data.se
    n = len(data)
    free_idx = jnp.asarray(free)

    def log_prob(x):
        q = jnp.where(is_log, jnp.exp(x), x)
        p = jnp.asarray(fixed_p).at[free_idx].set(q)
        r = family.from_vector(p)(omega) - acuity
        if se is None:
            ll = -0.5 * n * jnp.log(jnp.sum(r**2))
        else:
            ll = -0.5 * jnp.sum((r / jnp.asarray(se)) ** 2)
        inside = jnp.all((x > lo) & (x < hi))
        return jnp.where(inside & jnp.isfinite(ll), ll, -jnp.inf)

    return jax.jit(jax.vmap(log_prob)), is_log, lo, hi


ON_FAIL = ("raise", "warn")


@dataclass(frozen=True)
class EmceeOptions:
    """How `sample_posterior` runs emcee: `nwalkers` walkers for `nsteps` steps, and what an
    unconverged chain does: `on_fail="raise"` a `PosteriorConvergenceError`, "warn" a
    `PosteriorConvergenceWarning`.

    Raises:
        ValueError: fewer than 2 walkers or 1 step, or an `on_fail` not in `ON_FAIL`.
    """

    nwalkers: int = 32
    nsteps: int = 5000
    on_fail: str = "raise"

    def __post_init__(self):
        for name, least in (("nwalkers", 2), ("nsteps", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < least:
                raise ValueError(f"EmceeOptions: {name} must be a whole number >= {least}, got {value!r}")
        if self.on_fail not in ON_FAIL:
            raise ValueError(f"EmceeOptions: on_fail must be 'raise' or 'warn', not {self.on_fail!r}")


def sample_posterior(
    data,
    model: str | type[AcuityModel] | AcuityModel = "exponential",
    *,
    fixed: dict[str, float] | None = None,
    condition: str | None = None,
    solver: str = "levenberg_marquardt",
    start: FitResult | None = None,
    sampler: EmceeOptions | None = None,
    seed: int = 0,
    level: float = 0.95,
) -> Samples:
    """Sample the posterior of a model's free parameters with emcee (`sampler`, default
    `EmceeOptions()`: 32 walkers, 5000 steps).

    Walkers start as draws from the Laplace approximation around the least-squares fit (`start`,
    or a fresh `fit`). After the run: the integrated autocorrelation time τ of every parameter must satisfy
    nsteps ≥ 50·τ, and the mean acceptance fraction must lie in [0.15, 0.9]; otherwise
    `PosteriorConvergenceError` is raised (`sampler.on_fail="raise"`) or a
    `PosteriorConvergenceWarning` issued (`on_fail="warn"`). Burn-in of 3·max τ steps is
    discarded and chains are thinned by τ/2.
    """
    sampler = EmceeOptions() if sampler is None else sampler
    if not isinstance(sampler, EmceeOptions):
        raise TypeError(f"sample_posterior: sampler must be an EmceeOptions, got {type(sampler).__name__}")
    nwalkers, nsteps, on_fail = sampler.nwalkers, sampler.nsteps, sampler.on_fail
    import emcee  # imported on use: it pulls in scipy.stats (~1.5 s)

    family = model_family(model)
    data = _single_condition(_as_data(data), condition)
    best = start if start is not None else fit(data, family, solver=solver, fixed=fixed, level=level)
    fixed = dict(best.fixed)
    free = tuple(i for i, k in enumerate(family.param_names) if k not in fixed)
    names = tuple(family.param_names[i] for i in free)
    p_best = np.array([best.params[k] for k in family.param_names])
    with jax.enable_x64(True):  # the data arrays inside must be float64
        log_prob, is_log, lo, hi = _log_prob_fn(family, free, p_best, data)

    # Start the walkers on the Laplace approximation (the least-squares covariance mapped to the
    # sampling coordinates), so burn-in is short when that approximation is reasonable.
    cols = list(free)
    x_best = np.where(is_log, np.log(p_best[cols]), p_best[cols])
    if not np.all((x_best > lo) & (x_best < hi)):
        raise ValueError(
            f"{family.name}: the least-squares optimum "
            f"{dict(zip(names, p_best[cols], strict=True))} lies outside the prior box"
        )
    jac = np.where(is_log, 1.0 / p_best[cols], 1.0)
    cov_x = best.covariance[np.ix_(cols, cols)] * np.outer(jac, jac)
    rng = np.random.default_rng(seed)
    try:
        x0 = rng.multivariate_normal(x_best, cov_x, size=nwalkers, method="eigh")
    except np.linalg.LinAlgError:
        x0 = x_best + 1e-3 * rng.standard_normal((nwalkers, len(free)))
    x0 = np.clip(x0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))

    with jax.enable_x64(True):

        def host_log_prob(x):
            return np.asarray(log_prob(jnp.asarray(x)))

        ensemble = emcee.EnsembleSampler(nwalkers, len(free), host_log_prob, vectorize=True)
        ensemble.random_state = np.random.RandomState(seed).get_state()
        ensemble.run_mcmc(x0, nsteps, progress=False)

    tau = ensemble.get_autocorr_time(tol=0, quiet=True)
    acceptance = float(np.mean(ensemble.acceptance_fraction))
    problems = []
    if not np.all(np.isfinite(tau)) or nsteps < MIN_TAU_MULTIPLE * np.max(tau):
        problems.append(
            f"chain of {nsteps} steps is shorter than {MIN_TAU_MULTIPLE}× the autocorrelation time "
            f"(τ = {dict(zip(names, np.round(tau, 1), strict=True))}); "
            f"run at least {int(MIN_TAU_MULTIPLE * np.nanmax(tau)) + 1} steps"
        )
    if not ACCEPTANCE_RANGE[0] <= acceptance <= ACCEPTANCE_RANGE[1]:
        problems.append(f"mean acceptance fraction {acceptance:.3f} is outside {list(ACCEPTANCE_RANGE)}")
    if problems:
        msg = f"sample_posterior {family.name} on {data.where}: " + "; ".join(problems)
        if on_fail == "raise":
            raise PosteriorConvergenceError(msg)
        warnings.warn(msg, PosteriorConvergenceWarning, stacklevel=2)

    tau_max = float(np.nanmax(tau)) if np.any(np.isfinite(tau)) else nsteps / 10
    burn = min(int(3 * tau_max), nsteps // 2)
    thin = max(1, int(tau_max / 2))
    x = np.asarray(ensemble.get_chain(discard=burn, thin=thin, flat=True))
    draws = np.where(is_log, np.exp(x), x)
    return Samples(
        family=family,
        names=names,
        draws=draws,
        fixed=fixed,
        method="emcee",
        level=level,
        diagnostics={
            "nwalkers": nwalkers,
            "nsteps": nsteps,
            "burn": burn,
            "thin": thin,
            "tau": dict(zip(names, map(float, tau), strict=True)),
            "acceptance_fraction": acceptance,
            "n_draws": int(draws.shape[0]),
            "seed": seed,
            "converged": not problems,
            "problems": problems,
        },
    )


def bootstrap(
    data,
    model: str | type[AcuityModel] | AcuityModel = "exponential",
    *,
    fixed: dict[str, float] | None = None,
    condition: str | None = None,
    solver: str = "levenberg_marquardt",
    start: FitResult | None = None,
    n_boot: int = 1000,
    seed: int = 0,
    level: float = 0.95,
    max_failed_fraction: float = 0.05,
) -> Samples:
    """Residual bootstrap: refit the model to fitted curve + resampled residuals, `n_boot` times.

    Residuals are resampled with replacement — standardised (r/se, then × se) when `sd` is given,
    raw and inflated by √(n/(n−k)) otherwise — and the refits run as one vmapped batch starting at
    the least-squares optimum. Refits that fail any check are dropped and counted; if more than
    `max_failed_fraction` fail, a warning says so (the percentiles then describe only the
    successful resamples).
    """
    family = model_family(model)
    data = _single_condition(_as_data(data), condition)
    best = start if start is not None else fit(data, family, solver=solver, fixed=fixed, level=level)
    fixed = dict(best.fixed)
    free = tuple(i for i, k in enumerate(family.param_names) if k not in fixed)
    names = tuple(family.param_names[i] for i in free)
    n = len(data)
    fitted = best.predict(data.eccentricity_deg)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, n, (n_boot, n))
    if data.se is not None:
        z = best.residuals / data.se
        y = fitted + z[idx] * data.se
        weight = np.broadcast_to(1.0 / data.se, (n_boot, n))
    else:
        r = best.residuals * math.sqrt(n / (n - len(free)))
        y = fitted + r[idx]
        weight = np.ones((n_boot, n))
    p_best = np.array([best.params[k] for k in family.param_names])
    out = batch_fit(
        family,
        np.broadcast_to(data.eccentricity_deg, (n_boot, n)),
        y,
        weight,
        np.broadcast_to(p_best, (n_boot, p_best.size)),
        free=free,
        options=SolverOptions(best.solver),
    )
    ok = out.kind == "ok"
    failed = int((~ok).sum())
    if failed > max_failed_fraction * n_boot:
        warnings.warn(
            f"bootstrap {family.name} on {data.where}: {failed}/{n_boot} refits failed "
            f"({dict(zip(*np.unique(out.kind[~ok], return_counts=True), strict=True))})",
            stacklevel=2,
        )
    if not ok.any():
        raise RuntimeError(f"bootstrap {family.name} on {data.where}: every refit failed")
    return Samples(
        family=family,
        names=names,
        draws=out.p[ok][:, list(free)],
        fixed=fixed,
        method="bootstrap",
        level=level,
        diagnostics={"n_boot": n_boot, "failed": failed, "seed": seed},
    )
