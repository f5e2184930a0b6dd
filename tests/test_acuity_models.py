"""Acuity models: values, inverses, transforms, dtype behaviour under jit."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fovjax.acuity as fa
from fovjax.acuity._fit import _to_natural, _to_unconstrained

FAMILIES = [fa.Exponential(), fa.LinearMAR(0.95, 2.5), fa.PowerMAR(0.9, 2.0, 1.6)]


def test_thesis_defaults_and_sign_of_the_exponent():
    m = fa.Exponential()
    assert m.params() == {"a": 0.90964, "b": 2.9661, "c": 0.00792}
    assert fa.THESIS_MODEL.params() == m.params()
    with jax.enable_x64(True):
        v = np.asarray(m(jnp.array([0.0, 2.0, 5.0, 10.0, 20.0])))
    # The values quoted in data/acuity/SOURCES.md for the sign-corrected curve.
    np.testing.assert_allclose(v, [0.918, 0.471, 0.177, 0.039, 0.009], atol=6e-4)
    assert np.all(np.diff(v) < 0), "acuity must fall with eccentricity: exp(-ω/b), not exp(+ω/b)"
    assert v[0] == pytest.approx(0.90964 + 0.00792)


@pytest.mark.parametrize("model", FAMILIES, ids=lambda m: m.name)
def test_inverse_round_trip(model):
    with jax.enable_x64(True):
        omega = jnp.linspace(0.0, 30.0, 61)
        back = model.inverse(model(omega))
        np.testing.assert_allclose(np.asarray(back), np.asarray(omega), rtol=1e-9, atol=1e-9)
        top = float(model(0.0))
        # Above the foveal value there is no eccentricity; NaN, not a negative angle.
        assert np.isnan(float(model.inverse(top * 1.01)))
        assert np.isnan(float(model.inverse(-0.1)))


@pytest.mark.parametrize("model", FAMILIES, ids=lambda m: m.name)
def test_float32_under_jit_and_finite_gradients(model):
    omega = jnp.linspace(0.0, 40.0, 9, dtype=jnp.float32)
    out = jax.jit(lambda m, w: m(w))(model, omega)
    assert out.dtype == jnp.float32
    assert jax.jit(lambda w: model(w))(omega).dtype == jnp.float32  # model closed over
    with jax.enable_x64(True):
        ref = np.asarray(model(jnp.asarray(np.linspace(0.0, 40.0, 9))))
    np.testing.assert_allclose(np.asarray(out), ref, rtol=2e-6, atol=1e-7)
    # d V / d params is finite everywhere, including ω = 0 (where 0**p has a NaN derivative).
    grads = jax.grad(lambda m: jnp.sum(m(omega)))(model)
    for k in model.param_names:
        assert np.all(np.isfinite(np.asarray(getattr(grads, k)))), k


def test_models_are_pytrees_of_their_parameters():
    m = fa.PowerMAR(1.0, 3.0, 1.2)
    leaves = jax.tree.leaves(m)
    assert len(leaves) == 3
    again = type(m).from_vector(m.vector())
    assert again.params() == pytest.approx(m.params())
    assert type(m).from_params(m.params()).params() == m.params()
    with pytest.raises(ValueError, match="missing"):
        fa.PowerMAR.from_params({"a": 1.0})
    with pytest.raises(ValueError, match="unknown parameters"):
        fa.LinearMAR.from_params({"a": 1.0, "e2": 2.0, "q": 3.0})


@pytest.mark.parametrize("family", list(fa.MODEL_FAMILIES.values()), ids=lambda f: f.name)
def test_bounds_transform_round_trip(family):
    p = np.array([[0.7, 2.5, 0.01][: len(family.param_names)]])
    u = _to_unconstrained(family.bounds, p)
    with jax.enable_x64(True):
        back = np.asarray(_to_natural(family.bounds, jnp.asarray(u)))
        # Any unconstrained vector maps inside the bounds (b > 0 always).
        wild = np.asarray(_to_natural(family.bounds, jnp.asarray([[-40.0] * len(family.param_names)])))
    np.testing.assert_allclose(back, p, rtol=1e-12)
    for value, (lo, hi) in zip(wild[0], family.bounds, strict=True):
        assert lo <= value <= hi
        if lo == 0.0:
            assert value > 0.0


@pytest.mark.parametrize("family", list(fa.MODEL_FAMILIES.values()), ids=lambda f: f.name)
def test_initial_guess_from_data_is_inside_bounds(family):
    omega = np.array([0.0, 1.0, 2.0, 5.0, 10.0, 20.0])
    for acuity in (
        np.asarray(fa.THESIS_MODEL(omega), np.float64),
        1.0 / (1.0 + omega / 3.0),
        np.full(6, 0.5),  # flat data: no decay to read off
        np.linspace(0.2, 0.9, 6),  # increasing data
    ):
        guess = family.initial_guess(omega, acuity)
        for value, (lo, hi) in zip(guess.params().values(), family.bounds, strict=True):
            assert math.isfinite(value) and lo < value < hi


def test_model_family_lookup():
    assert fa.model_family("linear_mar") is fa.LinearMAR
    assert fa.model_family(fa.PowerMAR()) is fa.PowerMAR
    assert fa.model_family(fa.Exponential) is fa.Exponential
    with pytest.raises(ValueError, match="unknown acuity model 'gauss'"):
        fa.model_family("gauss")
