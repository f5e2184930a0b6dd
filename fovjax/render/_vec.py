"""Small-vector arithmetic on (..., 3) arrays, written component by component.

XLA:CPU routes reductions over short trailing axes (`jnp.sum(a * b, -1)` of a 3-vector, the sum
over a triangle's three corners) to a library kernel that is an order of magnitude slower than
the fused elementwise loop the same arithmetic becomes when written out. The integrator does all
its per-ray vector work through these helpers.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def dot(a, b):
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def cross(a, b):
    return jnp.stack(
        [
            a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
            a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
        ],
        axis=-1,
    )


def norm(v):
    """|v|, with a zero (not NaN) gradient at v = 0."""
    n2 = dot(v, v)
    ok = n2 > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, n2, 1.0)), 0.0)


def normalize(v):
    """v / |v|, and 0 (with a zero, not NaN, gradient) where v = 0."""
    n2 = dot(v, v)[..., None]
    ok = n2 > 0
    return v * jnp.where(ok, jax.lax.rsqrt(jnp.where(ok, n2, 1.0)), 0.0)


def interpolate(weights, corners):
    """Σ_k weights[..., k] · corners[..., k, :] over the three corners of a triangle."""
    return (
        weights[..., 0, None] * corners[..., 0, :]
        + weights[..., 1, None] * corners[..., 1, :]
        + weights[..., 2, None] * corners[..., 2, :]
    )


def all3(x):
    return x[..., 0] & x[..., 1] & x[..., 2]


def any3(x):
    return x[..., 0] | x[..., 1] | x[..., 2]


def matvec(m, v):
    """m @ v for a (3, 3) matrix and vectors v (..., 3)."""
    return jnp.stack([dot(v, m[i]) for i in range(3)], axis=-1)
