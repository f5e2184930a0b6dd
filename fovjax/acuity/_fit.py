"""Least-squares fitting of acuity models with optimistix.

Precision: fits run in float64 inside `jax.enable_x64(True)`, a thread-local context that is
restored on exit, so the rest of the package (the renderer) stays float32. Why float64: on the
thesis's curve samples float32 still finds the parameters to ~1e-7–1e-6 relative, but its rounding
(~1e-8 in the residuals) swamps the data's own 1e-11, so covariances and posteriors of
near-exact data come out ~1000× too wide, and Gauss–Newton in float32 did not meet rtol 1e-6
within 500 steps.

The solver works on an unconstrained vector u: each parameter is mapped through the transform its
bounds imply (b = exp(u_b) > 0). The covariance is reported for the natural parameters, from the
Jacobian of the (weighted) residuals at the optimum.

Every fit is checked before numbers are returned. The checks, in order, and the error each raises:

Outcomes are read from optimistix by name (`optx.RESULTS.successful`, `.nonlinear_max_steps_reached`,
lineax's `.singular`, ...), never by their integer codes, which differ between releases.

- optimistix stopped at `max_steps`                                -> `StepLimitError`
  (unless the Gauss–Newton step still to take from the last iterate is below the tolerance:
  optimistix tests convergence only on accepted steps, and once the remaining step is below
  floating-point resolution no step can be accepted, so a converged solve can run on to the
  limit. Such a fit is returned, with `extras["termination"]` saying so.)
- optimistix reported divergence, a non-finite iterate, or a
  singular linear solve (Gauss–Newton's normal equations)           -> `DivergenceError`
- the solution has non-finite parameters or residuals              -> `DivergenceError`
- the fit "converged" (steps became small) but the gradient is not
  ~0 — typical of a parameter running off to infinity               -> `StalledError`
- a parameter no longer moves the predictions (e.g. b once a -> 0),
  or the column-equilibrated Jacobian is numerically rank-deficient:
  some parameter combination is not constrained by the data         -> `IdentifiabilityError`
- fewer data points than free parameters + 1                       -> `TooFewPointsError`

Which parameters an `IdentifiabilityError` names is decided from the Jacobian at the point where
the solver stopped, never from the path it took: the parameters whose columns are ~0, else every
parameter with a large share in the near-null right singular vector of the equilibrated Jacobian.
Data with several equally good solutions (flat data: a = 0 with any b, or b -> 0 with any a) can
end at either, and the error names what is unconstrained at that point. Every error carries the
solver (`.solver`), the point (`.params`), the parameters it names (`.unconstrained`) and what to
try (`.remedy`, also in the message).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from ._data import AcuityData, AcuityDataError, from_arrays
from ._models import AcuityModel, model_family

SOLVERS: dict[str, type] = {
    "levenberg_marquardt": optx.LevenbergMarquardt,
    "gauss_newton": optx.GaussNewton,
    "dogleg": optx.Dogleg,
    "bfgs": optx.BFGS,
}
_SOLVER_ALIASES = {"lm": "levenberg_marquardt", "gn": "gauss_newton"}

# Thresholds of the post-fit checks (see the module docstring).
GRADIENT_COSINE_TOL = 1e-4  # max |J_jᵀr| / (‖J_j‖·‖r‖) at an accepted optimum
CONDITION_LIMIT = 1e7  # condition number of the column-equilibrated Jacobian
SENSITIVITY_LIMIT = 1e-7  # |∂r/∂log p| relative to |data|: below it a parameter moves nothing

# optimistix/lineax results, by name -> outcome kinds. Looked up by name at trace time (a release
# that lacks a name skips it); any result not listed is a divergence.
RESULT_KINDS = {
    "successful": "ok",
    "nonlinear_max_steps_reached": "step_limit",
    "nonlinear_divergence": "diverged",
    "nonfinite": "diverged",
    "nonfinite_input": "diverged",
    "singular": "singular_step",  # lineax: the Gauss–Newton normal equations lost rank
    "max_steps_reached": "diverged",  # an iterative linear solve ran out of steps
    "breakdown": "diverged",
    "stagnation": "diverged",
    "conlim": "diverged",
}
# Share of the near-null right singular vector (unit length) above which a parameter is named as
# part of an unconstrained combination.
NULL_SHARE = 0.25
OUTCOMES = ("ok", "step_limit", "diverged", "singular_step", "stalled", "unidentifiable", "too_few_points")


class FitError(ValueError):
    """A fit that did not produce trustworthy numbers. Subclasses say why.

    `solver`: the solver that ran; `params`: the point where it stopped (natural parameters);
    `unconstrained`: the parameters the data leave free there (IdentifiabilityError); `remedy`:
    what to try (also in the message)."""

    def __init__(
        self,
        message: str,
        *,
        solver: str | None = None,
        params: dict[str, float] | None = None,
        unconstrained: tuple[str, ...] = (),
        remedy: str = "",
    ):
        super().__init__(message)
        self.solver = solver
        self.params = dict(params or {})
        self.unconstrained = tuple(unconstrained)
        self.remedy = remedy


class StepLimitError(FitError):
    """The solver stopped at its step limit before converging."""


class DivergenceError(FitError):
    """The solver diverged: non-finite iterates or a singular linear solve."""


class StalledError(FitError):
    """The solver stopped moving where the gradient is not zero (usually a parameter → ∞)."""


class IdentifiabilityError(FitError):
    """The data do not constrain some combination of the parameters."""


class TooFewPointsError(FitError):
    """Not enough data points for the number of free parameters."""


_ERRORS = {
    "step_limit": StepLimitError,
    "diverged": DivergenceError,
    "singular_step": DivergenceError,
    "stalled": StalledError,
    "unidentifiable": IdentifiabilityError,
}


def solver_name(solver: str) -> str:
    name = _SOLVER_ALIASES.get(solver, solver)
    if name not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; choose one of {sorted(SOLVERS)} (or lm, gn)")
    return name


# -- parameter transforms ----------------------------------------------------------------------


def _to_natural(bounds, u):
    out = []
    for i, (lo, hi) in enumerate(bounds):
        if math.isinf(lo) and math.isinf(hi):
            out.append(u[..., i])
        elif math.isinf(hi):
            out.append(lo + jnp.exp(u[..., i]))
        elif math.isinf(lo):
            out.append(hi - jnp.exp(u[..., i]))
        else:
            out.append(lo + (hi - lo) * jax.nn.sigmoid(u[..., i]))
    return jnp.stack(out, axis=-1)


def _to_unconstrained(bounds, p: np.ndarray) -> np.ndarray:
    p = np.asarray(p, np.float64)
    out = np.empty_like(p)
    for i, (lo, hi) in enumerate(bounds):
        x = p[..., i]
        if math.isinf(lo) and math.isinf(hi):
            out[..., i] = x
        elif math.isinf(hi):
            out[..., i] = np.log(np.maximum(x - lo, 1e-300))
        elif math.isinf(lo):
            out[..., i] = np.log(np.maximum(hi - x, 1e-300))
        else:
            t = np.clip((x - lo) / (hi - lo), 1e-12, 1 - 1e-12)
            out[..., i] = np.log(t / (1 - t))
    return out


# -- the jitted core ------------------------------------------------------------------------------


@functools.lru_cache(maxsize=64)
def _core(
    family: type[AcuityModel], free: tuple[int, ...], solver: str, rtol: float, atol: float, max_steps: int
):
    """A jitted, vmapped solve: (u0, fixed_p, omega, acuity, weight) with a leading batch axis."""
    bounds = tuple(family.bounds[i] for i in free)
    opt = SOLVERS[solver](rtol=rtol, atol=atol)
    free_idx = jnp.asarray(free)
    names, members = _result_members()

    def residual_natural(q, fixed_p, omega, acuity, weight):
        p = fixed_p.at[free_idx].set(q)
        return (family.from_vector(p)(omega) - acuity) * weight

    def one(u0, fixed_p, omega, acuity, weight):
        def residual(u, _):
            return residual_natural(_to_natural(bounds, u), fixed_p, omega, acuity, weight)

        sol = optx.least_squares(residual, opt, u0, max_steps=max_steps, throw=False)
        # The result's index in `names` (-1: none of them), compared by name.
        result = jnp.int32(-1)
        for j, member in enumerate(members):
            result = jnp.where(sol.result == member, j, result)
        q = _to_natural(bounds, sol.value)
        jac = jax.jacfwd(residual_natural)(q, fixed_p, omega, acuity, weight)
        r = residual_natural(q, fixed_p, omega, acuity, weight)
        return {
            "p": fixed_p.at[free_idx].set(q),
            "result": result,
            "steps": sol.stats["num_steps"],
            "jac": jac,
            "r": r,
        }

    # XLA's backend optimisation roughly doubles compile time for solves that run in ~1 ms.
    return names, jax.jit(jax.vmap(one), compiler_options={"xla_backend_optimization_level": 0})


def _result_members() -> tuple[tuple[str, ...], list]:
    """The optimistix results this release has, by name (lineax's singular promoted)."""
    names, members = [], []
    for name in RESULT_KINDS:
        if name == "singular" and hasattr(lx.RESULTS, "singular"):
            member = optx.RESULTS.promote(lx.RESULTS.singular)
        elif hasattr(optx.RESULTS, name):
            member = getattr(optx.RESULTS, name)
        else:
            continue
        names.append(name)
        members.append(member)
    return tuple(names), members


def _bucket(n: int, smallest: int = 8) -> int:
    return max(smallest, 1 << (n - 1).bit_length())


@dataclass(frozen=True)
class BatchFit:
    """Raw outcome of a batch of fits (host NumPy), before any error is raised."""

    p: np.ndarray  # [B, P] natural parameters
    kind: np.ndarray  # [B] outcome (see OUTCOMES)
    steps: np.ndarray  # [B]
    jac: np.ndarray  # [B, N, k] Jacobian of the weighted residuals w.r.t. the free parameters
    r: np.ndarray  # [B, N] weighted residuals
    condition: np.ndarray  # [B] condition number of the equilibrated Jacobian
    gradient_cosine: np.ndarray  # [B]
    result: np.ndarray  # [B] optimistix result, by name ("successful", "singular", ...)
    culprit: np.ndarray  # [B] index (into all parameters) of the unconstrained one, or -1
    unconstrained: np.ndarray  # [B] tuple of indices (into all parameters) the data leave free
    converged_at_limit: np.ndarray  # [B] hit max_steps, but the remaining step was below tolerance


@dataclass(frozen=True)
class SolverOptions:
    """The least-squares solver of a fit and when it stops: `solver` (a name of `SOLVERS`, or
    the aliases "lm", "gn"; kept as the full name), its step limit `max_steps` and its relative
    and absolute tolerances `rtol`, `atol`.

    Raises:
        ValueError: an unknown solver, a step limit below 1 or a tolerance that is not a finite
            number > 0.
    """

    solver: str = "levenberg_marquardt"
    max_steps: int = 500
    rtol: float = 1e-8
    atol: float = 1e-10

    def __post_init__(self):
        object.__setattr__(self, "solver", solver_name(self.solver))
        steps = self.max_steps
        if isinstance(steps, bool) or not isinstance(steps, int | np.integer) or steps < 1:
            raise ValueError(f"SolverOptions: max_steps must be a whole number >= 1, got {steps!r}")
        for name in ("rtol", "atol"):
            value = getattr(self, name)
            ok = isinstance(value, int | float) and not isinstance(value, bool)
            if not (ok and math.isfinite(value) and value > 0):
                raise ValueError(f"SolverOptions: {name} must be a finite number > 0, got {value!r}")


def batch_fit(
    family: type[AcuityModel],
    omega: np.ndarray,
    acuity: np.ndarray,
    weight: np.ndarray,
    start: np.ndarray,
    fixed_p: np.ndarray | None = None,
    free: tuple[int, ...] | None = None,
    options: SolverOptions | None = None,
) -> BatchFit:
    """Fit B problems at once (arrays [B, N]; weight 0 drops a point; start [B, P] natural)
    with the solver and tolerances of `options` (default `SolverOptions()`).

    Used by `fit` (B = 1), leave-one-out, the bootstrap and the stability sweep. Classifies each
    outcome but raises nothing.
    """
    options = SolverOptions() if options is None else options
    solver, max_steps, rtol, atol = options.solver, options.max_steps, options.rtol, options.atol
    omega, acuity, weight = (np.atleast_2d(np.asarray(x, np.float64)) for x in (omega, acuity, weight))
    start = np.atleast_2d(np.asarray(start, np.float64))
    nb, n = omega.shape
    npar = len(family.param_names)
    free = tuple(range(npar)) if free is None else tuple(free)
    fixed_p = (
        start.copy() if fixed_p is None else np.broadcast_to(np.asarray(fixed_p, np.float64), (nb, npar))
    )
    bounds = tuple(family.bounds[i] for i in free)
    u0 = _to_unconstrained(bounds, start[:, list(free)])
    # Pad both axes to a few bucket sizes so that fits, leave-one-out and bootstrap batches of
    # similar size share compiled code (compiling an optimistix solve takes seconds).
    pad = _bucket(n, 16) - n
    if pad:
        omega, acuity = (np.pad(x, ((0, 0), (0, pad)), mode="edge") for x in (omega, acuity))
        weight = np.pad(weight, ((0, 0), (0, pad)))
    rows = _bucket(nb, 16) - nb
    if rows:
        u0, fixed_p, omega, acuity, weight = (
            np.pad(x, ((0, rows), (0, 0)), mode="edge") for x in (u0, fixed_p, omega, acuity, weight)
        )
    with jax.enable_x64(True):
        names, core = _core(family, free, solver, float(rtol), float(atol), int(max_steps))
        out = core(
            jnp.asarray(u0),
            jnp.asarray(fixed_p),
            jnp.asarray(omega),
            jnp.asarray(acuity),
            jnp.asarray(weight),
        )
        out = jax.tree.map(lambda x: np.asarray(x)[:nb], out)
    acuity, weight = acuity[:nb], weight[:nb]
    jac, r = out["jac"][:, :n], out["r"][:, :n]
    # Residual change per relative change of a positive parameter, or per unit of acuity for a
    # location parameter: a parameter whose change moves no prediction is not constrained.
    data_scale = np.abs(acuity[:, :n]).max(axis=1, keepdims=True)
    scale = np.stack(
        [out["p"][:, i] if math.isfinite(family.bounds[i][0]) else data_scale[:, 0] for i in free], axis=1
    )
    signal = np.linalg.norm(acuity[:, :n] * weight[:, :n], axis=1)
    result = np.array([names[i] if i >= 0 else "unknown" for i in out["result"]], dtype=object)
    kind, cond, gcos, culprit, at_limit, loose = _classify(
        result, out["p"], jac, r, np.abs(scale), signal, free, rtol, atol
    )
    culprit = np.array([free[c] if c >= 0 else -1 for c in culprit])
    unconstrained = np.empty(nb, dtype=object)
    unconstrained[:] = [tuple(free[j] for j in idx) for idx in loose]
    return BatchFit(
        out["p"],
        kind,
        out["steps"].astype(int),
        jac,
        r,
        cond,
        gcos,
        result,
        culprit,
        unconstrained,
        at_limit,
    )


def _classify(result, p, jac, r, scale, signal, free, rtol, atol):
    """Outcome of each fit (from the optimistix result's name, then the checks), the equilibrated
    condition number, the gradient cosine, the free parameter (index) most to blame for an
    unidentifiable fit (-1 otherwise), whether a fit that hit the step limit had in fact converged
    (see `batch_fit`), and the free parameters (indices) the data leave unconstrained.

    What is unconstrained is read from the Jacobian at the final point alone: the parameters
    whose columns move no prediction, else those with a share >= NULL_SHARE in the right
    singular vector of the smallest singular value of the column-equilibrated Jacobian."""
    nb = len(result)
    kind = np.array([RESULT_KINDS.get(str(c), "diverged") for c in result], dtype=object)
    loose: list[tuple[int, ...]] = [()] * nb
    at_limit = np.zeros(nb, bool)
    for i in np.flatnonzero(kind == "step_limit"):
        if not (np.all(np.isfinite(p[i])) and np.all(np.isfinite(r[i])) and np.all(np.isfinite(jac[i]))):
            continue
        # The Gauss–Newton step still to take from the final iterate. If it is below the
        # tolerance, the solve had converged: its termination test only runs on accepted steps,
        # and a step below floating-point resolution cannot be accepted (f does not change).
        step = np.linalg.lstsq(jac[i], -r[i], rcond=None)[0]
        if np.all(np.isfinite(step)) and np.all(np.abs(step) <= rtol * np.abs(p[i, list(free)]) + atol):
            kind[i] = "ok"
            at_limit[i] = True
    cond = np.full(nb, np.inf)
    gcos = np.full(nb, np.nan)
    culprit = np.full(nb, -1)
    for i in range(nb):
        if kind[i] != "ok":
            continue
        if not (np.all(np.isfinite(p[i])) and np.all(np.isfinite(r[i])) and np.all(np.isfinite(jac[i]))):
            kind[i] = "diverged"
            continue
        col = np.linalg.norm(jac[i], axis=0)
        sensitivity = col * scale[i]
        dead = sensitivity <= SENSITIVITY_LIMIT * signal[i]
        if np.any(dead):
            kind[i] = "unidentifiable"
            culprit[i] = int(np.argmin(sensitivity))
            loose[i] = tuple(int(j) for j in np.flatnonzero(dead))
            continue
        rnorm = np.linalg.norm(r[i])
        gcos[i] = float(np.max(np.abs(jac[i].T @ r[i]) / (col * rnorm))) if rnorm > 0 else 0.0
        _, sv, vt = np.linalg.svd(jac[i] / col, full_matrices=False)
        cond[i] = sv[0] / sv[-1] if sv[-1] > 0 else np.inf
        # A zero-residual fit (data on the curve) has an undefined gradient cosine: skip the test.
        if rnorm > 1e-9 * max(1.0, np.abs(jac[i]).max()) and gcos[i] > GRADIENT_COSINE_TOL:
            kind[i] = "stalled"
        elif cond[i] > CONDITION_LIMIT:
            kind[i] = "unidentifiable"
            share = np.abs(vt[-1])
            culprit[i] = int(np.argmax(share))
            loose[i] = tuple(int(j) for j in np.flatnonzero(share >= NULL_SHARE))
    return kind, cond, gcos, culprit, at_limit, loose


# -- the public fit -------------------------------------------------------------------------------


def _as_data(data) -> AcuityData:
    if isinstance(data, AcuityData):
        return data
    if isinstance(data, tuple) and len(data) in (2, 3):
        return from_arrays(*data)
    raise ValueError(
        f"fit: expected AcuityData or (eccentricity, acuity[, sd]) arrays, got {type(data).__name__}"
    )


def _single_condition(data: AcuityData, condition: str | None) -> AcuityData:
    if condition is not None:
        return data.select(condition)
    if len(data.conditions) > 1:
        raise AcuityDataError(
            f"{data.where}: {len(data.conditions)} conditions {list(data.conditions)}; fit one at a time "
            "(pass condition=... or data.select(...))"
        )
    return data


def _check_fixed(family, fixed) -> dict[str, float]:
    fixed = dict(fixed or {})
    for k, v in fixed.items():
        if k not in family.param_names:
            raise ValueError(
                f"{family.name}: cannot fix unknown parameter {k!r}; parameters are {family.param_names}"
            )
        lo, hi = family.bounds[family.param_names.index(k)]
        if not (lo < float(v) < hi):
            raise ValueError(f"{family.name}: fixed {k} = {v} is outside its bounds ({lo}, {hi})")
    if len(fixed) == len(family.param_names):
        raise ValueError(f"{family.name}: every parameter is fixed; nothing to fit")
    return {k: float(v) for k, v in fixed.items()}


def _start_vector(family, data: AcuityData, init, fixed) -> np.ndarray:
    if init is None:
        start = family.initial_guess(data.eccentricity_deg, data.acuity, fixed)
    elif isinstance(init, AcuityModel):
        if type(init) is not family:
            raise ValueError(f"init is a {type(init).__name__}, the model is {family.name}")
        start = init
    else:
        start = family.from_params({**dict(init), **fixed})
    p = np.array([start.params()[k] for k in family.param_names])
    for i, k in enumerate(family.param_names):
        if k in fixed:
            p[i] = fixed[k]
        lo, hi = family.bounds[i]
        if not (lo < p[i] < hi):
            # Nudge a start on or beyond a bound inside it; the transform cannot represent the bound.
            span = (hi - lo) if math.isfinite(hi - lo) else max(1.0, abs(p[i]))
            p[i] = min(max(p[i], lo + 1e-6 * span), hi - 1e-6 * span)
    return p


def gaussian_loglik(chi2: float, n: int, se: np.ndarray | None) -> tuple[float, int]:
    """Maximised Gaussian log-likelihood and the count of variance parameters it estimated.

    With known standard errors: −½χ² − Σ log(se·√2π). Without: σ² is estimated as RSS/n, adding a
    parameter: −(n/2)(log(2π·RSS/n) + 1).
    """
    if se is not None:
        return float(-0.5 * chi2 - np.sum(np.log(se * math.sqrt(2 * math.pi)))), 0
    rss = max(chi2, 1e-300)
    return float(-0.5 * n * (math.log(2 * math.pi * rss / n) + 1.0)), 1


@dataclass(frozen=True, eq=False)
class FitResult:
    """A converged, checked fit. `covariance` is over all parameters (zeros for fixed ones)."""

    model: AcuityModel
    data: AcuityData
    solver: str
    fixed: dict[str, float]
    covariance: np.ndarray
    residuals: np.ndarray  # acuity − model, in acuity units
    weighted_residuals: np.ndarray  # residuals / se (or = residuals when unweighted)
    metrics: dict[str, float]
    iterations: int
    result: str
    start: dict[str, float]
    level: float = 0.95
    jacobian_condition: float = float("nan")
    extras: dict = field(default_factory=dict)

    @property
    def family(self) -> type[AcuityModel]:
        return type(self.model)

    @property
    def params(self) -> dict[str, float]:
        return self.model.params()

    @property
    def free(self) -> tuple[str, ...]:
        return tuple(k for k in self.family.param_names if k not in self.fixed)

    @property
    def stderr(self) -> dict[str, float]:
        return {
            k: float(math.sqrt(max(self.covariance[i, i], 0.0)))
            for i, k in enumerate(self.family.param_names)
        }

    def quantile(self, level: float | None = None) -> float:
        """Two-sided critical value: Student-t on the residual dof when σ was estimated, else normal."""
        from scipy import stats  # imported here: scipy.stats costs ~1 s at `fovjax` start-up

        level = self.level if level is None else level
        tail = 0.5 + 0.5 * level
        if self.data.weighted:
            return float(stats.norm.ppf(tail))
        return float(stats.t.ppf(tail, self.metrics["dof"]))

    def intervals(self, level: float | None = None, space: str = "natural") -> dict[str, tuple[float, float]]:
        """Wald (Laplace) intervals: estimate ± z·stderr in natural parameters (`space="natural"`),
        or, for parameters bounded below by 0, exp(log p ± z·stderr/p) (`space="log"`), which stays
        positive when the uncertainty is large."""
        z = self.quantile(level)
        out = {}
        for i, (k, v) in enumerate(self.params.items()):
            se = self.stderr[k]
            if space == "log" and self.family.bounds[i][0] == 0.0 and v > 0:
                out[k] = (v * math.exp(-z * se / v), v * math.exp(z * se / v))
            elif space in ("natural", "log"):
                out[k] = (v - z * se, v + z * se)
            else:
                raise ValueError(f"space must be 'natural' or 'log', not {space!r}")
        return out

    def predict(self, omega) -> np.ndarray:
        with jax.enable_x64(True):
            return np.asarray(self.model(jnp.asarray(omega, jnp.float64)))

    def band(self, omega, level: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Delta-method band for V(ω): (estimate, lower, upper)."""
        family = self.family
        with jax.enable_x64(True):
            w = jnp.asarray(omega, jnp.float64)
            p0 = jnp.asarray([self.params[k] for k in family.param_names])
            grad = jax.jacfwd(lambda p: family.from_vector(p)(w))(p0)
            centre = np.asarray(family.from_vector(p0)(w))
            var = np.einsum("ni,ij,nj->n", np.asarray(grad), self.covariance, np.asarray(grad))
        half = self.quantile(level) * np.sqrt(np.maximum(var, 0.0))
        return centre, centre - half, centre + half

    def summary(self) -> str:
        lo_hi = self.intervals()
        lines = [f"{self.family.name}: {self.family.formula}  ({self.solver}, {self.iterations} iterations)"]
        for k in self.family.param_names:
            if k in self.fixed:
                lines.append(f"  {k:>3} = {self.params[k]:.6g} (fixed)")
            else:
                lo, hi = lo_hi[k]
                line = (
                    f"  {k:>3} = {self.params[k]:.6g} ± {self.stderr[k]:.3g}   "
                    f"{100 * self.level:.0f}% [{lo:.6g}, {hi:.6g}]"
                )
                bound = self.family.bounds[self.family.param_names.index(k)][0]
                if lo <= bound:  # the symmetric interval crosses the bound: show the log-space one
                    llo, lhi = self.intervals(space="log")[k]
                    line += f" (log-space [{llo:.6g}, {lhi:.6g}])"
                lines.append(line)
        m = self.metrics
        lines.append(
            f"  n={m['n']} k={m['k']} R²={m['r2']:.6f} RMSE={m['rmse']:.4g} "
            f"AIC={m['aic']:.3f} BIC={m['bic']:.3f}"
        )
        return "\n".join(lines)


def _remedy(kind: str, solver: str) -> str:
    other = "another solver (levenberg_marquardt)" if solver != "levenberg_marquardt" else "another solver"
    return {
        "step_limit": f"try a larger max_steps, another start (init=...) or {other}, or fix a parameter "
        "(fixed=...): an optimum at a parameter's limit is never reached",
        "diverged": f"try {other} or another start (init=...)",
        "singular_step": f"try {other} (its damping keeps the step defined) or another start (init=...)",
        "stalled": f"try another start (init=...) or {other}, or fix the parameter that runs off (fixed=...)",
        "unidentifiable": "try fixing a parameter (fixed=...) or adding data over a wider eccentricity range",
    }[kind]


def _raise_for(kind: str, family, solver, data, steps, p, max_steps, cond, gcos, culprit, loose) -> None:
    params = ", ".join(f"{k}={v:.6g}" for k, v in zip(family.param_names, p, strict=True))
    where = f"fit {family.name} to {data.where} ({len(data)} points) with {solver}"
    remedy = _remedy(kind, solver)
    names: tuple[str, ...] = ()
    if kind == "step_limit":
        msg = f"{where}: stopped at the step limit max_steps={max_steps} without converging"
    elif kind == "diverged":
        msg = f"{where}: diverged after {steps} steps (non-finite values)"
    elif kind == "singular_step":
        msg = (
            f"{where}: the linear solve for a step was singular after {steps} steps (the Gauss–Newton "
            "normal equations lost rank)"
        )
    elif kind == "stalled":
        msg = (
            f"{where}: stopped after {steps} steps with a non-zero gradient (cosine {gcos:.2g} > "
            f"{GRADIENT_COSINE_TOL:g}); a parameter is probably running off to a bound"
        )
    else:
        names = tuple(family.param_names[j] for j in (loose or (culprit,)))
        listed = " and ".join(names)
        why = (
            f"changing {listed} no longer changes the predictions"
            if not math.isfinite(cond)
            else f"{'they are' if len(names) > 1 else f'{listed} is'} confounded "
            f"{'' if len(names) > 1 else 'with the others '}"
            f"(equilibrated Jacobian condition {cond:.3g} > {CONDITION_LIMIT:g})"
        )
        msg = f"{where}: the data do not constrain {listed}: {why}"
    raise _ERRORS[kind](
        f"{msg}; last iterate {params}; {remedy}",
        solver=solver,
        params=dict(zip(family.param_names, map(float, p), strict=True)),
        unconstrained=names,
        remedy=remedy,
    )


def fit(
    data,
    model: str | type[AcuityModel] | AcuityModel = "exponential",
    *,
    solver: str = "levenberg_marquardt",
    init: AcuityModel | dict | None = None,
    fixed: dict[str, float] | None = None,
    condition: str | None = None,
    max_steps: int = 500,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    level: float = 0.95,
) -> FitResult:
    """Fit an acuity model by (weighted) least squares with optimistix.

    Weighting: rows with `sd` are weighted by 1/se² (se = sd/√n) and the covariance is
    (JᵀWJ)⁻¹ (standard errors taken as known); without `sd` the fit is unweighted and the
    covariance is s²(JᵀJ)⁻¹ with s² = RSS/(n − k).

    Args:
        data: `AcuityData` (one condition, or pick one with `condition`).
        model: a family name ("exponential", "linear_mar", "power_mar"), class or instance.
        solver: "levenberg_marquardt" (default), "gauss_newton", "dogleg" or "bfgs".
        init: starting values (model or dict); by default they come from the data
            (`initial_guess`).
        fixed: parameters held at given values, e.g. ``{"c": 0.0}``.
        condition: the condition to fit when the data hold several.
        max_steps: the solver's step limit.
        rtol: the solver's relative tolerance.
        atol: the solver's absolute tolerance.
        level: the confidence level of the intervals.

    Returns:
        A converged, checked `FitResult` (model, covariance, residuals, metrics, iterations).

    Raises:
        FitError: a subclass (`StepLimitError`, `DivergenceError`, `StalledError`,
            `IdentifiabilityError`, `TooFewPointsError`) naming the solver and what to try, rather
            than an unconverged fit.

    Example:
        ```python
        data = fa.load_csv("data/ashraf2025/resolution_limit_achromatic_mean.csv")
        result = fa.fit(data, "exponential", fixed={"c": 0.0})
        result.model(10.0)                    # relative acuity at 10°, jittable
        ```
    """
    family = model_family(model)
    data = _single_condition(_as_data(data), condition)
    fixed = _check_fixed(family, fixed)
    solver = solver_name(solver)
    free = tuple(i for i, k in enumerate(family.param_names) if k not in fixed)
    k = len(free)
    n = len(data)
    if n <= k:
        raise TooFewPointsError(
            f"fit {family.name} to {data.where}: {n} points for {k} free parameters; need at least {k + 1}"
        )
    start = _start_vector(family, data, init, fixed)
    se = data.se
    weight = np.ones(n) if se is None else 1.0 / se
    out = batch_fit(
        family,
        data.eccentricity_deg[None],
        data.acuity[None],
        weight[None],
        start[None],
        free=free,
        options=SolverOptions(solver, max_steps, rtol, atol),
    )
    p, kind, steps = out.p[0], out.kind[0], int(out.steps[0])
    if kind != "ok":
        _raise_for(
            kind,
            family,
            solver,
            data,
            steps,
            p,
            max_steps,
            out.condition[0],
            out.gradient_cosine[0],
            out.culprit[0],
            out.unconstrained[0],
        )

    jac, wres = out.jac[0], out.r[0]
    chi2 = float(wres @ wres)
    dof = n - k
    jtj_inv = np.linalg.inv(jac.T @ jac)
    scale = 1.0 if se is not None else chi2 / dof
    cov = np.zeros((len(family.param_names),) * 2)
    cov[np.ix_(free, free)] = scale * jtj_inv
    cov = 0.5 * (cov + cov.T)

    fitted = family.from_vector(p)
    with jax.enable_x64(True):
        pred = np.asarray(fitted(jnp.asarray(data.eccentricity_deg)))
    resid = data.acuity - pred
    rss = float(resid @ resid)
    tss = float(((data.acuity - data.acuity.mean()) ** 2).sum())
    # AIC/BIC count every estimated parameter, including σ when the fit estimated it.
    loglik, extra = gaussian_loglik(chi2, n, se)
    kk = k + extra
    metrics = {
        "n": n,
        "k": k,
        "k_likelihood": kk,
        "dof": dof,
        "rss": rss,
        "chi2": chi2,
        "r2": 1.0 - rss / tss if tss > 0 else float("nan"),
        "rmse": math.sqrt(rss / n),
        "loglik": loglik,
        "aic": 2 * kk - 2 * loglik,
        "aicc": 2 * kk - 2 * loglik + (2 * kk * (kk + 1) / (n - kk - 1) if n - kk - 1 > 0 else float("inf")),
        "bic": kk * math.log(n) - 2 * loglik,
    }
    return FitResult(
        model=fitted,
        data=data,
        solver=solver,
        fixed=fixed,
        covariance=cov,
        residuals=resid,
        weighted_residuals=resid if se is None else resid / se,
        metrics=metrics,
        iterations=steps,
        result="successful",
        start=dict(zip(family.param_names, map(float, start), strict=True)),
        level=level,
        jacobian_condition=float(out.condition[0]),
        extras={
            "gradient_cosine": float(out.gradient_cosine[0]),
            "termination": "remaining Gauss–Newton step below tolerance at the step limit"
            if out.converged_at_limit[0]
            else "solver",
        },
    )
