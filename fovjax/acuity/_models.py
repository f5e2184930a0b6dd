"""Acuity models V(ω): visual acuity as a function of retinal eccentricity ω in degrees.

Each family is a small `eqx.Module` whose fields are its parameters, so a model is a pytree: it can
be passed into `jax.jit`, `jax.vmap` or `jax.grad` like any array container. Parameters are stored
as host float64 NumPy scalars when a model is built from numbers; `__call__` casts them to the
floating dtype of ω, so a float32 renderer gets a float32 curve and a float64 fit a float64 one.

Class-level metadata says how to fit a family:

- `param_names`, `units`: the parameters in order;
- `bounds`: hard bounds per parameter. The fitter optimises an unconstrained vector and maps it
  through the transform the bounds imply: (lo, inf) -> lo + exp(u) (so b > 0 always),
  (-inf, inf) -> u;
- `priors`: the proper priors `sample_posterior` uses, each ("uniform" | "log_uniform", lo, hi).
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

# A parameter as stored: a host float64 scalar, or a JAX array inside jit/vmap/grad.
ParamScalar = Float[Array | np.ndarray, ""]


def _param(x: ArrayLike) -> Array | np.ndarray:
    # Tracers and device arrays pass through (models are rebuilt inside jit/vmap); plain numbers
    # become float64 host scalars so no precision is lost before a fit decides its dtype.
    if isinstance(x, jax.Array):
        return x
    return np.asarray(x, dtype=np.float64)


def _float_dtype(omega: Array):
    return jnp.result_type(omega.dtype, jnp.float32)


class AcuityModel(eqx.Module):
    """Base class of the acuity families. Subclasses define their parameters as fields."""

    name: ClassVar[str]
    formula: ClassVar[str]
    param_names: ClassVar[tuple[str, ...]]
    units: ClassVar[tuple[str, ...]]
    bounds: ClassVar[tuple[tuple[float, float], ...]]
    priors: ClassVar[tuple[tuple[str, float, float], ...]]

    def __call__(self, omega: ArrayLike) -> Float[Array, "*batch"]:
        raise NotImplementedError

    def inverse(self, acuity: ArrayLike) -> Float[Array, "*batch"]:
        """Eccentricity (degrees, >= 0) at which the model reaches `acuity`; NaN where it never does."""
        raise NotImplementedError(f"{self.name}: no closed-form inverse")

    # -- parameter access -------------------------------------------------------------------
    def vector(self) -> Float[Array, " P"]:
        """The parameters stacked in `param_names` order."""
        return jnp.stack([jnp.asarray(getattr(self, k)) for k in self.param_names])

    @classmethod
    def from_vector(cls, p: ArrayLike) -> AcuityModel:
        if not isinstance(p, jax.Array | np.ndarray):
            p = np.asarray(p, dtype=np.float64)
        return cls(*[p[i] for i in range(len(cls.param_names))])

    def params(self) -> dict[str, float]:
        """Host floats, for printing and JSON."""
        return {k: float(np.asarray(getattr(self, k))) for k in self.param_names}

    @classmethod
    def from_params(cls, params: dict[str, float]) -> AcuityModel:
        missing = [k for k in cls.param_names if k not in params]
        if missing:
            raise ValueError(f"{cls.name}: parameters {missing} missing from {sorted(params)}")
        extra = sorted(set(params) - set(cls.param_names))
        if extra:
            raise ValueError(f"{cls.name}: unknown parameters {extra}; expected {list(cls.param_names)}")
        return cls(**{k: float(params[k]) for k in cls.param_names})

    @classmethod
    def initial_guess(
        cls, omega: np.ndarray, acuity: np.ndarray, fixed: dict[str, float] | None = None
    ) -> AcuityModel:
        """Starting values computed from the data (host NumPy), respecting `fixed` values."""
        raise NotImplementedError

    def __repr__(self) -> str:
        inner = ", ".join(f"{k}={v:.6g}" for k, v in self.params().items())
        return f"{type(self).__name__}({inner})"


def _linear_regression(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least-squares intercept and slope (slope 0 when x has no spread)."""
    xm, ym = x.mean(), y.mean()
    sxx = float(((x - xm) ** 2).sum())
    slope = float(((x - xm) * (y - ym)).sum() / sxx) if sxx > 0 else 0.0
    return float(ym - slope * xm), slope


class Exponential(AcuityModel):
    """The thesis's curve, V(ω) = a·exp(−ω/b) + c.

    Defaults are the thesis's coefficients (a = 0.90964, b = 2.9661°, c = 0.00792), fitted there
    to Mandelbaum & Sloan (1947). The thesis prints exp(+ω/b), which grows without bound; its own
    text ("as eccentricity increase the visual acuity fall") and its Figure 44 need exp(−ω/b), so
    the minus sign was lost in typesetting.
    """

    a: ParamScalar = eqx.field(converter=_param, default=0.90964)
    b: ParamScalar = eqx.field(converter=_param, default=2.9661)
    c: ParamScalar = eqx.field(converter=_param, default=0.00792)

    name: ClassVar[str] = "exponential"
    formula: ClassVar[str] = "V = a*exp(-omega/b) + c"
    param_names: ClassVar[tuple[str, ...]] = ("a", "b", "c")
    units: ClassVar[tuple[str, ...]] = ("acuity", "deg", "acuity")
    # c may go slightly negative: an unbiased estimate of a floor near 0 needs both signs.
    bounds: ClassVar[tuple[tuple[float, float], ...]] = (
        (0.0, math.inf),
        (0.0, math.inf),
        (-math.inf, math.inf),
    )
    priors: ClassVar[tuple[tuple[str, float, float], ...]] = (
        ("uniform", 0.0, 10.0),
        ("log_uniform", 1e-2, 1e3),
        ("uniform", -1.0, 1.0),
    )

    def __call__(self, omega: ArrayLike) -> Float[Array, "*batch"]:
        omega = jnp.asarray(omega)
        dt = _float_dtype(omega)
        a, b, c = (jnp.asarray(getattr(self, k), dt) for k in self.param_names)
        return a * jnp.exp(-omega.astype(dt) / b) + c

    def inverse(self, acuity: ArrayLike) -> Float[Array, "*batch"]:
        """ω = −b·ln((V − c)/a), defined for c < V ≤ a + c."""
        acuity = jnp.asarray(acuity)
        dt = _float_dtype(acuity)
        a, b, c = (jnp.asarray(getattr(self, k), dt) for k in self.param_names)
        v = acuity.astype(dt)
        ok = (v > c) & (v <= a + c)
        ratio = jnp.where(ok, (v - c) / a, 1.0)
        return jnp.where(ok, -b * jnp.log(ratio), jnp.nan)

    @classmethod
    def initial_guess(cls, omega, acuity, fixed=None):
        fixed = dict(fixed or {})
        omega, acuity = np.asarray(omega, np.float64), np.asarray(acuity, np.float64)
        # Floor: half the lowest acuity seen (the data may not reach the asymptote). Decay length
        # and amplitude: a log-linear regression of V − c on ω over the points clearly above the
        # floor (points on the floor flatten the slope and would overstate b).
        c0 = fixed.get("c", 0.5 * float(acuity.min()))
        lifted = np.clip(acuity - c0, 1e-12, None)
        above = lifted >= 0.05 * lifted.max()
        if above.sum() < 2:
            above = np.ones_like(above)
        intercept, slope = _linear_regression(omega[above], np.log(lifted[above]))
        span = float(omega.max() - omega.min()) or 1.0
        b0 = -1.0 / slope if slope < -1e-12 else span
        b0 = fixed.get("b", float(np.clip(b0, 1e-2 * span, 1e2 * span)))
        a0 = fixed.get("a", float(np.exp(intercept)) if slope < -1e-12 else float(lifted.max()))
        return cls(a0, b0, c0)


class LinearMAR(AcuityModel):
    """The linear minimum-angle-of-resolution family, V(ω) = a / (1 + ω/E2).

    If MAR grows linearly with eccentricity, MAR(ω) = MAR0·(1 + ω/E2) (Weymouth 1958; Levi's E2,
    the eccentricity at which MAR doubles), then acuity ∝ 1/MAR is a/(1 + ω/E2) with a the foveal
    acuity. With a fixed at 1 it is relative acuity; Song, Levi & Pelli (2014) Eq. 13 is this form
    with E2 = 2.72°.
    """

    a: ParamScalar = eqx.field(converter=_param, default=1.0)
    e2: ParamScalar = eqx.field(converter=_param, default=2.72)

    name: ClassVar[str] = "linear_mar"
    formula: ClassVar[str] = "V = a / (1 + omega/e2)"
    param_names: ClassVar[tuple[str, ...]] = ("a", "e2")
    units: ClassVar[tuple[str, ...]] = ("acuity", "deg")
    bounds: ClassVar[tuple[tuple[float, float], ...]] = ((0.0, math.inf), (0.0, math.inf))
    priors: ClassVar[tuple[tuple[str, float, float], ...]] = (
        ("uniform", 0.0, 10.0),
        ("log_uniform", 1e-2, 1e3),
    )

    def __call__(self, omega: ArrayLike) -> Float[Array, "*batch"]:
        omega = jnp.asarray(omega)
        dt = _float_dtype(omega)
        a, e2 = (jnp.asarray(getattr(self, k), dt) for k in self.param_names)
        return a / (1.0 + omega.astype(dt) / e2)

    def inverse(self, acuity: ArrayLike) -> Float[Array, "*batch"]:
        """ω = E2·(a/V − 1), defined for 0 < V ≤ a."""
        acuity = jnp.asarray(acuity)
        dt = _float_dtype(acuity)
        a, e2 = (jnp.asarray(getattr(self, k), dt) for k in self.param_names)
        v = acuity.astype(dt)
        ok = (v > 0) & (v <= a)
        return jnp.where(ok, e2 * (a / jnp.where(ok, v, 1.0) - 1.0), jnp.nan)

    @classmethod
    def initial_guess(cls, omega, acuity, fixed=None):
        fixed = dict(fixed or {})
        omega, acuity = np.asarray(omega, np.float64), np.asarray(acuity, np.float64)
        if "a" in fixed:
            # Each point below the fixed foveal value gives its own E2 = ω / (a/V − 1).
            a0 = float(fixed["a"])
            use = (acuity < a0) & (omega > 0)
            e2 = omega[use] / (a0 / acuity[use] - 1.0)
            e20 = (
                float(np.median(e2))
                if e2.size
                else float(np.median(omega[omega > 0]) if (omega > 0).any() else 1.0)
            )
        else:
            # 1/V = 1/a + ω/(a·E2) is linear in ω.
            intercept, slope = _linear_regression(omega, 1.0 / acuity)
            if intercept > 0 and slope > 0:
                a0, e20 = 1.0 / intercept, intercept / slope
            else:
                a0, e20 = float(acuity.max()), float(np.median(omega)) or 1.0
        return cls(a0, fixed.get("e2", e20))


class PowerMAR(AcuityModel):
    """A flexible generalisation of the linear-MAR family, V(ω) = a / (1 + (ω/E2)^p).

    Why this family: it nests the linear-MAR model (p = 1), so `compare` can ask whether the data
    need anything beyond linear MAR growth with one extra parameter; p > 1 gives the steeper
    mid-periphery fall-off of the thesis's exponential (and of letter acuity), p < 1 a shallower
    one; E2 keeps its meaning (V(E2) = a/2) and the inverse stays closed-form.
    """

    a: ParamScalar = eqx.field(converter=_param, default=1.0)
    e2: ParamScalar = eqx.field(converter=_param, default=2.72)
    p: ParamScalar = eqx.field(converter=_param, default=1.0)

    name: ClassVar[str] = "power_mar"
    formula: ClassVar[str] = "V = a / (1 + (omega/e2)**p)"
    param_names: ClassVar[tuple[str, ...]] = ("a", "e2", "p")
    units: ClassVar[tuple[str, ...]] = ("acuity", "deg", "1")
    bounds: ClassVar[tuple[tuple[float, float], ...]] = ((0.0, math.inf), (0.0, math.inf), (0.0, math.inf))
    priors: ClassVar[tuple[tuple[str, float, float], ...]] = (
        ("uniform", 0.0, 10.0),
        ("log_uniform", 1e-2, 1e3),
        ("log_uniform", 0.1, 10.0),
    )

    def __call__(self, omega: ArrayLike) -> Float[Array, "*batch"]:
        omega = jnp.asarray(omega)
        dt = _float_dtype(omega)
        a, e2, p = (jnp.asarray(getattr(self, k), dt) for k in self.param_names)
        w = omega.astype(dt)
        pos = w > 0
        # exp(p·log x) with a safe log: 0**p has a NaN derivative in p at ω = 0.
        powered = jnp.where(pos, jnp.exp(p * jnp.log(jnp.where(pos, w, 1.0) / e2)), 0.0)
        return a / (1.0 + powered)

    def inverse(self, acuity: ArrayLike) -> Float[Array, "*batch"]:
        """ω = E2·(a/V − 1)^(1/p), defined for 0 < V ≤ a."""
        acuity = jnp.asarray(acuity)
        dt = _float_dtype(acuity)
        a, e2, p = (jnp.asarray(getattr(self, k), dt) for k in self.param_names)
        v = acuity.astype(dt)
        ok = (v > 0) & (v < a)
        x = jnp.where(ok, a / jnp.where(ok, v, 1.0) - 1.0, 1.0)
        out = jnp.where(ok, e2 * jnp.exp(jnp.log(x) / p), jnp.nan)
        return jnp.where(v == a, jnp.zeros_like(out), out)

    @classmethod
    def initial_guess(cls, omega, acuity, fixed=None):
        fixed = dict(fixed or {})
        lin = LinearMAR.initial_guess(omega, acuity, {k: v for k, v in fixed.items() if k in ("a", "e2")})
        a0, e20 = float(lin.a), float(lin.e2)
        omega, acuity = np.asarray(omega, np.float64), np.asarray(acuity, np.float64)
        # log(a/V − 1) = p·log ω − p·log E2 on points strictly inside (0, a).
        use = (omega > 0) & (acuity < a0)
        p0 = 1.0
        if use.sum() >= 2:
            _, slope = _linear_regression(np.log(omega[use]), np.log(a0 / acuity[use] - 1.0))
            if 0.1 < slope < 10:
                p0 = slope
        return cls(a0, e20, fixed.get("p", p0))


MODEL_FAMILIES: dict[str, type[AcuityModel]] = {m.name: m for m in (Exponential, LinearMAR, PowerMAR)}

# The thesis's published fit to Mandelbaum & Sloan (1947), sign of the exponent corrected.
THESIS_MODEL = Exponential(0.90964, 2.9661, 0.00792)


def model_family(model: str | type[AcuityModel] | AcuityModel) -> type[AcuityModel]:
    """The family of a model given by name, class or instance."""
    if isinstance(model, str):
        try:
            return MODEL_FAMILIES[model]
        except KeyError:
            raise ValueError(
                f"unknown acuity model {model!r}; choose one of {sorted(MODEL_FAMILIES)}"
            ) from None
    if isinstance(model, AcuityModel):
        return type(model)
    if isinstance(model, type) and issubclass(model, AcuityModel):
        return model
    raise ValueError(f"not an acuity model: {model!r}")
