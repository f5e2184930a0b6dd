"""`acuity_models`: acuity models at an equal ray budget (`equal_budget_foveations`), under the
"either" and the "strict" sampling rule; error per ring."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._stability import FullRenders
from ._common import (
    FailureCase,
    _Bench,
    _case,
    _frame_metrics,
    _mean,
    _metric,
    _ring_rows,
    _scene_rig,
    _side,
)

# ---- equal ray budget across acuity models ----------------------------------------------------


class AcuityTerms(eqx.Module):
    """gain · (exp_a·exp(−ω/exp_b) + const + mar_a / (1 + (ω/mar_e2)^mar_p) + ramp(ω)), where
    ramp falls linearly from ramp_top at ramp_start to ramp_floor at ramp_end degrees.

    Every acuity family of the project is one setting of these terms (`AcuityTerms.of`): the
    thesis's exponential, linear and power MAR, `LinearFalloff`, `Constant`. With one class for
    all of them, foveations that differ only in their curve share one compiled program, and the
    gain scales a curve to a ray budget without changing its shape. (Foveation.probability clips
    the result to [0, 1].)"""

    gain: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1.0)
    exp_a: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
    exp_b: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1.0)
    const: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
    mar_a: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
    mar_e2: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1.0)
    mar_p: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1.0)
    ramp_top: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
    ramp_floor: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
    ramp_start: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
    ramp_end: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1.0)

    def __call__(self, omega):
        w = jnp.asarray(omega, jnp.float32)
        f = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
        value = f(self.exp_a) * jnp.exp(-w / f(self.exp_b)) + f(self.const)
        pos = w > 0
        powered = jnp.where(
            pos, jnp.exp(f(self.mar_p) * jnp.log(jnp.where(pos, w, 1.0) / f(self.mar_e2))), 0.0
        )
        value = value + f(self.mar_a) / (1.0 + powered)
        s = jnp.clip(
            (w - f(self.ramp_start)) / jnp.maximum(f(self.ramp_end) - f(self.ramp_start), 1e-6), 0.0, 1.0
        )
        value = value + (1.0 - s) * f(self.ramp_top) + s * f(self.ramp_floor)
        return f(self.gain) * value

    @classmethod
    def of(cls, model, gain: float = 1.0) -> AcuityTerms:
        """The terms of an `fovjax.acuity` model (Exponential, LinearMAR, PowerMAR) or a
        `fovjax.foveate` LinearFalloff / Constant, times `gain`."""
        from ...acuity import Exponential, LinearMAR, PowerMAR
        from ...foveate import Constant, LinearFalloff

        v = lambda x: float(np.asarray(x))  # noqa: E731
        if isinstance(model, AcuityTerms):
            return dataclasses.replace(model, gain=v(model.gain) * gain)
        if isinstance(model, Exponential):
            return cls(gain=gain, exp_a=v(model.a), exp_b=v(model.b), const=v(model.c))
        if isinstance(model, LinearMAR):
            return cls(gain=gain, mar_a=v(model.a), mar_e2=v(model.e2))
        if isinstance(model, PowerMAR):
            return cls(gain=gain, mar_a=v(model.a), mar_e2=v(model.e2), mar_p=v(model.p))
        if isinstance(model, LinearFalloff):
            return cls(
                gain=gain,
                ramp_top=1.0,
                ramp_floor=v(model.floor),
                ramp_start=v(model.start),
                ramp_end=v(model.end),
            )
        if isinstance(model, Constant):
            return cls(gain=gain, const=v(model.p))
        raise ValueError(
            f"AcuityTerms.of: cannot express {type(model).__name__} as acuity terms; use Exponential, "
            "LinearMAR, PowerMAR, LinearFalloff or Constant"
        )


@dataclasses.dataclass(frozen=True)
class EqualBudget:
    """Foveations (by model name) whose curves are scaled (`gains`) so that the expected
    primary rays per frame over `gazes` equal the first (reference) model's, all with the same
    static `ray_budget` per eye (the largest any of them plans), so they also cost the same
    slots and share one compiled program."""

    foveations: dict
    gains: dict
    expected_rays: dict
    ray_budget: int
    reference: str


def _candidates(rig, foveation, gazes):
    """Per gaze and eye: mandatory sample count and the curve's values at the probabilistic
    candidates (the expected-count terms of plan_budget for one gaze)."""
    from ...foveate import FOVEA, eccentricity_map, regions
    from ...foveate.internal import top_left

    parts = []
    for g in gazes:
        g = np.broadcast_to(np.asarray(g, np.float32).reshape(-1, 2), (2, 2))
        for i, cam in enumerate(rig.eye_cameras()):
            ecc = eccentricity_map(cam, jnp.asarray(g[i]), foveation)
            region = regions(ecc, foveation)
            ty, tx, _ = top_left(region, foveation)
            is_tl = np.asarray(jnp.zeros(region.shape, bool).at[ty, tx].set(True))
            fovea = np.asarray(region == FOVEA)
            if foveation.rule == "either":
                mandatory = fovea | is_tl
                cand = ~mandatory
            else:
                mandatory = fovea
                cand = ~fovea & is_tl
            parts.append((int(mandatory.sum()), np.asarray(ecc)[cand]))
    return parts


def _expected(parts, curve, spp: int, n_gazes: int) -> float:
    total = 0.0
    for mandatory, omega in parts:
        p = np.clip(np.asarray(curve(jnp.asarray(omega)), np.float64), 0.0, 1.0)
        total += spp * (mandatory + float(p.sum()))
    return total / n_gazes


def equal_budget_foveations(
    rig, foveation, models: Mapping[str, object], *, gazes: Sequence = ((0.5, 0.5),), rtol: float = 1e-4
) -> EqualBudget:
    """Scale each of `models` (name -> acuity model; the first is the reference, gain 1) by the
    gain that makes the expected primary rays per frame of `foveation` with that curve, averaged
    over `gazes`, equal the reference's (bisection to `rtol`), and give all of them the same
    static ray budget per eye. The fovea and region thresholds, blocks and rule stay
    `foveation`'s: only where the probabilistic samples go differs."""
    from ...foveate.internal import plan_budget

    if not models:
        raise ValueError("equal_budget_foveations: need at least one model")
    if not (0 < rtol < 0.1):
        raise ValueError(f"equal_budget_foveations: rtol must be in (0, 0.1), got {rtol}")
    if foveation.rule not in ("either", "strict"):
        raise ValueError(
            f"equal_budget_foveations: rule {foveation.rule!r} draws no samples from the acuity curve; "
            "use 'either' or 'strict'"
        )
    gazes = list(gazes)
    if not gazes:
        raise ValueError("equal_budget_foveations: need at least one gaze")
    parts = _candidates(rig, foveation, gazes)
    names = list(models)
    curves = {name: AcuityTerms.of(models[name]) for name in names}
    target = _expected(parts, curves[names[0]], foveation.spp, len(gazes))
    gains, expected = {names[0]: 1.0}, {names[0]: target}
    for name in names[1:]:
        base = curves[name]
        rays = lambda g, base=base: _expected(parts, AcuityTerms.of(base, g), foveation.spp, len(gazes))  # noqa: E731
        lo, hi = 0.0, 1.0
        while rays(hi) < target:
            hi *= 2.0
            if hi > 1e9:
                raise ValueError(
                    f"equal_budget_foveations: model {name!r} cannot reach the reference's "
                    f"{target:.0f} expected rays at any gain (its curve is zero beyond the fovea?)"
                )
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if rays(mid) < target:
                lo = mid
            else:
                hi = mid
            if abs(rays(hi) - target) <= rtol * target:
                break
        gains[name], expected[name] = hi, rays(hi)
    arms = {
        n: dataclasses.replace(foveation, acuity=AcuityTerms.of(curves[n], gains[n]), ray_budget=None)
        for n in names
    }
    budget = max(plan_budget(cam, f) for f in arms.values() for cam in rig.eye_cameras())
    arms = {n: dataclasses.replace(f, ray_budget=int(budget)) for n, f in arms.items()}
    return EqualBudget(arms, gains, expected, int(budget), names[0])


FITTED_MAR = Path(__file__).resolve().parents[3] / "fits" / "published_linear_mar.json"
"""The linear-MAR curve fitted to the published acuity data (`fovjax fit`), in the repository's
`fits/` folder: the second of `default_models()`."""


def default_models(fit: str | Path | None = None) -> dict[str, object]:
    """The thesis's exponential, the fitted linear-MAR curve read from `fit` (default
    `FITTED_MAR`, the repository's `fits/published_linear_mar.json`), the `LinearFalloff`
    default (1 at 5° to 0.05 at 30°) and `Constant` (uniform). A missing or unreadable fit is an
    error (FileNotFoundError / ValueError naming the file), never a silent stand-in curve."""
    from ...acuity import THESIS_MODEL, LinearMAR, load_fit
    from ...foveate import Constant, LinearFalloff

    path = FITTED_MAR if fit is None else Path(fit)
    if not path.is_file():
        raise FileNotFoundError(
            f"{path}: no such file; the acuity models need the fitted linear-MAR curve "
            "(the repository's fits/published_linear_mar.json, or another `fovjax fit` record)"
        )
    mar = load_fit(path)
    if not isinstance(mar, LinearMAR):
        raise ValueError(f"{path}: a {type(mar).__name__} fit; the acuity models need a linear-MAR fit")
    return {
        "thesis exponential": THESIS_MODEL,
        f"linear MAR fit (E2 {float(mar.e2):.2f}°)": mar,
        "linear fall-off": LinearFalloff(),
        "constant": Constant(),
    }


def acuity_models(
    full: FullRenders,
    foveation=None,
    *,
    models: Mapping[str, object] | None = None,
    gazes: Sequence = ((0.5, 0.5), (0.3, 0.4)),
    keys: Sequence[int] = (0,),
    rules: Sequence[str] = ("either", "strict"),
    ring_deg: float = 5.0,
    budgets: Mapping[str, EqualBudget] | None = None,
    progress=None,
) -> FailureCase:
    """Acuity models at the same ray budget (`equal_budget_foveations`), under each sampling
    rule of `rules` (under "either" the block top-lefts are traced whatever the curve, under
    "strict" every sample beyond the fovea is the curve's draw); `budgets` (rule -> EqualBudget)
    reuses ones already made. Per rule, model, gaze and key the primary rays (and their
    difference from the rule's reference model's), frame error and FLIP ("frame" rows), and
    error and primary rays per ring ("ring" rows); `arm` names rule and model."""
    scene, rig = _scene_rig(full, "acuity_models")
    from ...foveate import SAMPLING_RULES, Foveation, check_gaze

    t0 = time.perf_counter()
    foveation = foveation or Foveation.thesis(2)
    gazes = [
        check_gaze(np.broadcast_to(np.asarray(g, np.float64).reshape(-1, 2), (2, 2)), "acuity_models gaze")
        for g in gazes
    ]
    if not gazes or not keys:
        raise ValueError("acuity_models: need at least one gaze and one key")
    drawn = tuple(r for r in SAMPLING_RULES if r != "thesis-measured")  # rules that use the curve
    if not rules or any(r not in drawn for r in rules):
        raise ValueError(f"acuity_models: rules must be among {drawn}, got {rules!r}")
    budgets = dict(budgets or {})
    models = models or default_models()
    for rule in rules:
        if rule not in budgets:
            budgets[rule] = equal_budget_foveations(
                rig, dataclasses.replace(foveation, rule=rule), models, gazes=gazes
            )
    bench = _Bench.make(full, progress)
    records, rays_ref = [], {}
    for rule in rules:
        budget = budgets[rule]
        for name, fov in budget.foveations.items():
            for gi, g in enumerate(gazes):
                for k in keys:
                    frame = bench.foveated(g, fov, k)
                    ref = bench.reference(k)
                    maps = bench.maps(frame.image, ref)
                    ecc = _side(frame.eccentricity)
                    assert frame.sample_mask is not None  # the bench asks for it
                    traced = _side(frame.sample_mask.sum(axis=1))
                    primary = frame.stats.primary_rays
                    rays_ref.setdefault((rule, gi, k), primary)
                    common = {
                        "arm": f"{rule}: {name}",
                        "rule": rule,
                        "model": name,
                        "gaze_x": float(g[0, 0]),
                        "gaze_y": float(g[0, 1]),
                        "key": int(k),
                        "gain": budget.gains[name],
                        "expected_primary_rays": budget.expected_rays[name],
                        "ray_budget_per_eye": budget.ray_budget,
                    }
                    records.append(
                        {
                            "kind": "frame",
                            **common,
                            "primary_rays": primary,
                            "rays": frame.stats.rays,
                            "primary_rays_vs_reference": primary / rays_ref[rule, gi, k] - 1.0,
                            "dropped": frame.foveation.dropped,
                            "ms": 1000 * frame.stats.render_seconds,
                            **_frame_metrics(maps, frame.image, ref),
                        }
                    )
                    for row in _ring_rows(maps, frame.image, ref, ecc, ring_deg):
                        inside = (ecc >= row["ring_lower_deg"]) & (ecc < row["ring_upper_deg"])
                        records.append(
                            {"kind": "ring", **common, **row, "ring_primary_rays": int(traced[inside].sum())}
                        )
    frames = [r for r in records if r["kind"] == "frame"]
    m = _metric(frames, "frame_flip")
    parts = []
    for rule in rules:
        budget = budgets[rule]
        rows = [r for r in frames if r["rule"] == rule]
        spread = max(abs(r["primary_rays_vs_reference"]) for r in rows)
        models_text = ", ".join(
            f"{name} {_mean(rows, m, model=name):.4f} (gain {budget.gains[name]:.3g})"
            for name in budget.foveations
        )
        parts.append(
            f"{rule}: {m} at {budget.expected_rays[budget.reference]:.0f} expected primary rays "
            f"(realised within {100 * spread:.1f}%): {models_text}"
        )
    finding = "; ".join(parts)
    params = {
        "models": tuple(models),
        "rules": tuple(rules),
        "gazes": tuple(tuple(map(float, g[0])) for g in gazes),
        "keys": tuple(keys),
        "ray_budget_per_eye": {r: budgets[r].ray_budget for r in rules},
        "fovea_deg": foveation.fovea_deg,
        "periphery_deg": foveation.periphery_deg,
    }
    return _case("acuity_models", "acuity models at an equal ray budget", records, finding, params, t0)
