"""Model choice: "model no more than the data needs".

`compare` fits each candidate, ranks by AIC, reports BIC and the leave-one-out prediction error, and
names the simplest model (fewest free parameters; ties broken by AIC) whose AIC is within 2 of the
best — the usual threshold below which the data give no real support for the richer model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ._fit import FitError, FitResult, SolverOptions, _as_data, _single_condition, batch_fit, fit
from ._models import AcuityModel, model_family

DELTA_AIC = 2.0


@dataclass(frozen=True)
class CandidateScore:
    name: str
    k: int  # free model parameters
    aic: float
    aicc: float
    bic: float
    loo_rmse: float  # leave-one-out prediction error (acuity units)
    loo_failed: int  # leave-one-out refits that failed their checks
    delta_aic: float
    delta_bic: float
    fit: FitResult | None
    error: str | None = None


@dataclass(frozen=True)
class Comparison:
    scores: tuple[CandidateScore, ...]  # sorted by AIC; failed fits last
    chosen: str  # simplest model within ΔAIC < 2 of the best
    best_aic: str

    def __getitem__(self, name: str) -> CandidateScore:
        for s in self.scores:
            if s.name == name:
                return s
        raise KeyError(name)

    def table(self) -> str:
        head = f"{'model':<12} {'k':>2} {'AIC':>10} {'ΔAIC':>8} {'BIC':>10} {'ΔBIC':>8} {'LOO RMSE':>10}"
        rows = [head]
        for s in self.scores:
            if s.fit is None:
                rows.append(f"{s.name:<12} {s.k:>2}  failed: {s.error}")
                continue
            loo = f"{s.loo_rmse:.4g}" + (f" ({s.loo_failed} failed)" if s.loo_failed else "")
            rows.append(
                f"{s.name:<12} {s.k:>2} {s.aic:>10.3f} {s.delta_aic:>8.3f} "
                f"{s.bic:>10.3f} {s.delta_bic:>8.3f} {loo:>10}"
            )
        rows.append(f"chosen: {self.chosen} (simplest within ΔAIC < {DELTA_AIC:g} of {self.best_aic})")
        return "\n".join(rows)

    def to_dict(self) -> dict:
        return {
            "chosen": self.chosen,
            "best_aic": self.best_aic,
            "rule": f"fewest free parameters among models with ΔAIC < {DELTA_AIC:g}",
            "scores": [
                {
                    "model": s.name,
                    "k": s.k,
                    "aic": s.aic,
                    "aicc": s.aicc,
                    "bic": s.bic,
                    "delta_aic": s.delta_aic,
                    "delta_bic": s.delta_bic,
                    "loo_rmse": s.loo_rmse,
                    "loo_failed": s.loo_failed,
                    "params": None if s.fit is None else s.fit.params,
                    "error": s.error,
                }
                for s in self.scores
            ],
        }


def leave_one_out(result: FitResult) -> tuple[np.ndarray, int]:
    """Prediction errors V_i − f₋ᵢ(ω_i) with each point left out in turn (NaN where the refit failed).

    All n refits run as one vmapped batch (the left-out point gets weight 0), starting from the
    full-data optimum.
    """
    data, family = result.data, result.family
    n = len(data)
    free = tuple(i for i, k in enumerate(family.param_names) if k not in result.fixed)
    base = np.ones(n) if data.se is None else 1.0 / data.se
    weight = np.tile(base, (n, 1))
    weight[np.arange(n), np.arange(n)] = 0.0
    p0 = np.array([result.params[k] for k in family.param_names])
    out = batch_fit(
        family,
        np.tile(data.eccentricity_deg, (n, 1)),
        np.tile(data.acuity, (n, 1)),
        weight,
        np.tile(p0, (n, 1)),
        free=free,
        options=SolverOptions(result.solver),
    )
    ok = out.kind == "ok"
    with jax.enable_x64(True):
        pred = np.asarray(
            jax.vmap(lambda p, w: family.from_vector(p)(w))(
                jnp.asarray(out.p), jnp.asarray(data.eccentricity_deg)
            )
        )
    err = np.where(ok, data.acuity - pred, np.nan)
    return err, int((~ok).sum())


def compare(
    data,
    models=("exponential", "linear_mar", "power_mar"),
    *,
    fixed: dict[str, dict[str, float]] | None = None,
    condition: str | None = None,
    solver: str = "levenberg_marquardt",
) -> Comparison:
    """Fit every model in `models` and rank them by AIC, with leave-one-out errors beside it.

    A model whose fit fails is listed with its error and excluded from the choice.

    Args:
        data: `AcuityData`.
        models: names, classes or instances of the families to compare.
        fixed: per model name, the parameters held fixed for it, e.g.
            ``{"linear_mar": {"a": 1.0}}``.
        condition: the condition to fit when the data hold several.
        solver: the least-squares solver of every fit (see `fit`).

    Returns:
        A `Comparison`: `scores` (a `CandidateScore` per model, sorted by AIC, failed fits last: k,
        AIC, AICc, BIC, LOO RMSE, Δ to the best, the fit or its error), `chosen` (the simplest
        model within ΔAIC < 2 of the best) and `best_aic`.

    Example:
        ```python
        cmp = fa.compare(data, ("exponential", "linear_mar"), fixed={"exponential": {"c": 0.0}})
        print(cmp.chosen)
        ```
    """
    data = _single_condition(_as_data(data), condition)
    fixed = fixed or {}
    raw = []
    for m in models:
        family: type[AcuityModel] = model_family(m)
        fx = fixed.get(family.name, {})
        k = len(family.param_names) - len(fx)
        try:
            res = fit(data, family, solver=solver, fixed=fx)
        except FitError as err:
            raw.append((family.name, k, None, str(err)))
            continue
        raw.append((family.name, k, res, None))
    good = [r for r in raw if r[2] is not None]
    if not good:
        raise FitError(
            f"compare on {data.where}: every model failed: " + "; ".join(f"{r[0]}: {r[3]}" for r in raw)
        )
    best_aic = min(r[2].metrics["aic"] for r in good)
    best_bic = min(r[2].metrics["bic"] for r in good)
    scores = []
    for name, k, res, error in raw:
        if res is None:
            nan = float("nan")
            scores.append(CandidateScore(name, k, nan, nan, nan, nan, 0, nan, nan, None, error))
            continue
        err, failed = leave_one_out(res)
        loo = float(math.sqrt(np.nanmean(err**2))) if np.isfinite(err).any() else float("nan")
        m = res.metrics
        scores.append(
            CandidateScore(
                name,
                k,
                m["aic"],
                m["aicc"],
                m["bic"],
                loo,
                failed,
                m["aic"] - best_aic,
                m["bic"] - best_bic,
                res,
            )
        )
    scores.sort(key=lambda s: (s.fit is None, s.aic if s.fit is not None else 0.0))
    within = [s for s in scores if s.fit is not None and s.delta_aic < DELTA_AIC]
    chosen = min(within, key=lambda s: (s.k, s.aic)).name
    return Comparison(tuple(scores), chosen, scores[0].name)
