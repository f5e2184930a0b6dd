"""The stage builder's derivative rule (`fovjax.native.internal.on_platforms`, `jvp_of`): an
operand that does not depend on what is differentiated adds no tangent arithmetic.

The probe is `x * sqrt(y)` at y = 0: its derivative in y is infinite there, so a zero tangent
for y that were multiplied through would turn the derivative in x into NaN (0 · inf)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from fovjax.native.internal import jvp_of, on_platforms


def probe(x, y):
    return x * jnp.sqrt(y), jnp.sum(y > 0)


def test_jvp_of_holds_symbolic_zeros_constant_and_matches_jvp_elsewhere():
    x, y = jnp.float32(2.0), jnp.float32(0.0)
    (value, count), (tangent, _) = jvp_of(probe, (x, y), (jnp.float32(1.0), SymbolicZero(jax.typeof(y))))
    assert float(value) == 0.0 and int(count) == 0
    assert float(tangent) == 0.0  # sqrt(0): multiplying a zero tangent through gives NaN
    _, (plain, _) = jax.jvp(probe, (x, y), (jnp.float32(1.0), jnp.float32(0.0)))
    assert np.isnan(float(plain))  # what the rule avoids
    y = jnp.float32(4.0)
    ours = jvp_of(probe, (x, y), (jnp.float32(0.5), jnp.float32(0.25)))
    theirs = jax.jvp(probe, (x, y), (jnp.float32(0.5), jnp.float32(0.25)))
    assert float(ours[1][0]) == float(theirs[1][0]) == 0.5 * 2.0 + 2.0 * 0.25 / (2 * 2.0)


def test_a_stage_differentiates_only_the_operands_that_move():
    def native(x, y):  # stands in for a native handler: same value, no derivative of its own
        return jax.lax.stop_gradient(probe(x, y)[0]), probe(x, y)[1]

    def native_jvp(primals, tangents):
        return native(*primals), jvp_of(probe, primals, tangents)[1]

    def check(stage):
        # Forward mode (reverse mode drops a constant tangent term before it is computed).
        tangent = jax.jit(lambda x: jax.jvp(lambda x: stage(x, jnp.float32(0.0))[0], (x,), (1.0,))[1])
        assert float(tangent(jnp.float32(2.0))) == 0.0
        grad_y = jax.jit(jax.grad(lambda y: stage(jnp.float32(2.0), y)[0]))(jnp.float32(4.0))
        assert float(grad_y) == 2.0 / (2 * 2.0)

    for cpu_only in (False, True):
        check(on_platforms(probe, cpu=native, cpu_jvp=native_jvp, cpu_only=cpu_only))
    reference_only = on_platforms(probe, cpu=native)
    tangent = jax.jvp(lambda x: reference_only(x, jnp.float32(0.0))[0], (jnp.float32(2.0),), (1.0,))[1]
    assert float(tangent) == 0.0
