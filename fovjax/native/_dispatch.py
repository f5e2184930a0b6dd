"""The one place a program chooses between a stage's native implementation and its JAX one.

Every stage that has a native handler (a ray query, the Whitted integrator, the foveated
frame's selection, slots and reconstruction) is a pair: the native function and the JAX
function that is its oracle and the source of its derivatives. `plan_native` decides once per
configuration whether the native side can run (the handlers built, the configuration allows
it), and `on_platforms` builds the stage: the native function on the platforms it serves and the
JAX function elsewhere, chosen inside the program (`jax.lax.platform_dependent`), so that one
program lowers for CPU and CUDA; with derivatives from the JAX function (a custom JVP) where the
outputs are differentiable."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import jax
from jax.custom_derivatives import SymbolicZero

from .. import _environment
from ._library import status

REQUESTS = ("auto", "native", "jax")


@dataclasses.dataclass(frozen=True)
class NativePlan:
    """Where a configuration's native stages run, resolved once (`plan_native`).

    - `cpu`: the native handlers run the stages' CPU side;
    - `cpu_only`: the program is built for the CPU alone (no JAX branch: "native" asked for);
    - `reason`: what the native handlers are (where they run) or why they do not run.
    """

    cpu: bool
    cpu_only: bool
    reason: str


def plan_native(
    request: str = "auto", *, allowed: bool = True, why_not: str = "", what: str = "the configuration"
) -> NativePlan:
    """Whether a configuration's native stages run: `request` "auto" (where the handlers built and
    `allowed`), "native" (the handlers, or an error naming `what` asked for them and why they
    cannot run) or "jax" (never). `why_not` says why a configuration is not `allowed`."""
    if request not in REQUESTS:
        raise ValueError(f"the native request must be one of {REQUESTS}, got {request!r}")
    if request == "jax":
        return NativePlan(False, False, "the JAX implementation was asked for")
    if not allowed:
        if request == "native":
            raise ValueError(f"{what} needs the native handlers, but {why_not}")
        return NativePlan(False, False, why_not)
    found = status()
    if not found:
        if request == "native":
            raise RuntimeError(f"{what} needs the native handlers, which are unavailable: {found.reason}")
        return NativePlan(False, False, found.reason)
    return NativePlan(True, request == "native", found.reason)


@functools.cache
def other_platforms() -> bool:
    """Whether a stage chosen per platform also lowers its JAX side for platforms other than CPU
    and CUDA: where JAX sees a device that is neither a CPU nor an NVIDIA GPU (ROCm, TPU, ...),
    or FOVJAX_AUTO_OTHER_PLATFORMS=1 (to export such a program from a machine without one). Every
    branch is traced though only one is compiled, so a branch no device needs is left out."""
    if _environment.switch("FOVJAX_AUTO_OTHER_PLATFORMS"):
        return True
    for device in jax.devices():
        version = str(getattr(device.client, "platform_version", "")).lower()
        if device.platform != "cpu" and not (device.platform in ("gpu", "cuda") and "cuda" in version):
            return True
    return False


def jvp_of(fn: Callable, primals, tangents):
    """`jax.jvp(fn, primals, tangents)` where a tangent may be a `SymbolicZero` (a custom JVP
    rule's operand that does not depend on what is differentiated): those operands are held
    constant, so no tangent arithmetic is traced for them. In forward mode an instantiated zero
    would be multiplied through (XLA does not fold `x * 0` in floating point): work, and NaN
    where a derivative is infinite. Reverse mode drops such terms either way."""
    flat_primals, tree = jax.tree.flatten(primals)
    flat_tangents = tree.flatten_up_to(tangents)  # a SymbolicZero is a leaf
    moving = [i for i, t in enumerate(flat_tangents) if not isinstance(t, SymbolicZero)]

    def of_moving(*xs):
        full = list(flat_primals)
        for i, x in zip(moving, xs, strict=True):
            full[i] = x
        return fn(*jax.tree.unflatten(tree, full))

    return jax.jvp(of_moving, [flat_primals[i] for i in moving], [flat_tangents[i] for i in moving])


def on_platforms(
    reference: Callable,
    *,
    cpu: Callable | None = None,
    cuda: Callable | None = None,
    cpu_only: bool = False,
    derivatives: bool = True,
    cpu_jvp: Callable | None = None,
    differentiate: Callable | None = None,
) -> Callable:
    """One stage as a function of its operands: `cpu` on a CPU, `cuda` on an NVIDIA GPU,
    `reference` (the JAX implementation) wherever neither is given, chosen per platform inside
    the program. `cpu_only`: `cpu` alone (a program for the CPU, or a caller already inside the
    CPU's branch). `derivatives`: the stage's derivatives are `reference`'s (a custom JVP), so
    they do not depend on where the primal ran; False where the outputs are not differentiable
    (integers, masks) or the caller differentiates elsewhere. `cpu_jvp(primals, tangents)`:
    the JVP rule on a CPU instead (tangents may be `SymbolicZero`s: `jvp_of`; it returns the
    primal outputs, the native side's, and their tangents: e.g. the JVP of a replay of what
    the native forward stored), `reference`'s elsewhere, or `differentiate`'s where given: a
    function of the same value whose JVP (and its transpose, for reverse mode) JAX can take
    where `reference`'s cannot (a loop whose trip count depends on the data). All take the
    same operands and return the same structure."""
    if cpu_only:
        if cpu is None:
            raise ValueError("on_platforms: cpu_only needs a cpu function")
        primal = cpu
    elif cpu is None and cuda is None:
        return reference
    else:

        def primal(*args):
            branches = {name: f for name, f in (("cpu", cpu), ("cuda", cuda)) if f is not None}
            if len(branches) < 2 or other_platforms():
                branches["default"] = reference
            return jax.lax.platform_dependent(*args, **branches)

    if not derivatives:
        return primal
    stage = jax.custom_jvp(primal)

    def reference_jvp(primals, tangents):
        return jvp_of(reference if differentiate is None else differentiate, primals, tangents)

    if cpu_jvp is None:
        rule = reference_jvp
    elif cpu_only:
        rule = cpu_jvp
    else:

        def rule(primals, tangents):
            # The symbolic zeros stay out of `platform_dependent`'s operands (arrays only).
            flat, tree = jax.tree.flatten(tangents, is_leaf=lambda t: isinstance(t, SymbolicZero))
            moving = [i for i, t in enumerate(flat) if not isinstance(t, SymbolicZero)]

            def with_zeros(jvp):
                def branch(primals, moved):
                    full = list(flat)
                    for i, t in zip(moving, moved, strict=True):
                        full[i] = t
                    return jvp(primals, jax.tree.unflatten(tree, full))

                return branch

            return jax.lax.platform_dependent(
                primals,
                [flat[i] for i in moving],
                cpu=with_zeros(cpu_jvp),
                default=with_zeros(reference_jvp),
            )

    stage.defjvp(rule, symbolic_zeros=True)
    return stage
