"""Ray-query backends: one protocol (`RayBackend`), a registry, and the built-in three.

A backend answers one question for a batch of flat rays: which face each ray hits first (or
whether anything lies on it). Everything after that (the hit's distance, barycentrics and their
derivatives) is recomputed in JAX, so gradients do not depend on the backend. "auto" is not a
backend: it resolves per platform to the first registered backend that prefers that platform
and can run there, else the JAX traversal.
"""

from __future__ import annotations

import abc
import importlib.util
from typing import ClassVar, NamedTuple

import jax

from ..native.internal import plan_native
from ._traverse import Traversal


class RayBatch(NamedTuple):
    """Flat rays for a backend: `origins`, `directions` (n, 3); `tmin`, `tmax` (n,) (scalars where
    the backend takes `scalar_bounds`); `level` (n,): the tree of a merged BVH each ray is traced
    against (None: tree 0)."""

    origins: jax.Array
    directions: jax.Array
    tmin: jax.Array
    tmax: jax.Array
    level: jax.Array | None


class QueryOptions(NamedTuple):
    """How a backend is asked: `any_hit` (occlusion: any hit, not the nearest); `packet_size` rays
    a packet (None: one by one); `traversal` the JAX traversal's tuning; `split`: the rays may be
    split over host devices; `tile`, `batch`: the rays are an image of `batch` to trace in
    tile-sized packets (None otherwise). A backend uses what applies to it."""

    any_hit: bool
    packet_size: int | None = None
    traversal: Traversal = Traversal()
    split: bool = False
    tile: tuple[int, int] | None = None
    batch: tuple[int, ...] | None = None


class RayBackend(abc.ABC):
    """What a ray-query backend provides (register an instance with `register_backend`).

    - `name`: what `backend=` names it by;
    - `preferred_on`: the platforms ("cpu", "cuda", ...) where "auto" chooses it when it can run;
    - `scalar_bounds`: whether `query` takes `tmin`/`tmax` as scalars (else one per ray);
    - `unavailable(platform)`: None where it runs for `platform`, else why not (one phrase);
    - `query(bvh, rays, options)`: (t, prim) of the `RayBatch`, or (t, prim, u, v) where the
      backend reports its own distance and barycentrics (t = inf, prim = -1 on a miss; for
      `options.any_hit`, prim >= 0 marks an occluded ray and t, u, v mean nothing); it runs
      inside a jitted program, on JAX arrays;
    - `describe(platform)`: one line naming what runs.
    """

    name: ClassVar[str]
    preferred_on: ClassVar[tuple[str, ...]] = ()
    scalar_bounds: ClassVar[bool] = False

    def unavailable(self, platform: str) -> str | None:
        """None where the backend runs for `platform`, else why not."""
        del platform
        return None

    @abc.abstractmethod
    def query(self, bvh, rays: RayBatch, options: QueryOptions) -> tuple:
        """The hits of `rays` in `bvh` as `options` ask (see the class docstring)."""

    def describe(self, platform: str) -> str:
        del platform
        return self.name


_REGISTRY: dict[str, RayBackend] = {}


def register_backend(backend: RayBackend, *, replace: bool = False) -> RayBackend:
    """Make `backend` available as `backend=backend.name` in `closest_hit`, `occluded` and
    `RenderConfig`. A name already registered is an error unless `replace`. Returns it."""
    if not isinstance(backend, RayBackend):
        raise TypeError(f"register_backend: expected a fovjax.trace.RayBackend, got {type(backend).__name__}")
    name = getattr(backend, "name", None)
    if not isinstance(name, str) or not name or name == "auto":
        raise ValueError(f"a ray backend needs a name other than 'auto', got {name!r}")
    if name in _REGISTRY and not replace:
        raise ValueError(f"a ray backend named {name!r} is registered already (pass replace=True)")
    _REGISTRY[name] = backend
    return backend


def unregister_backend(name: str) -> None:
    """Remove a registered backend (the built-ins cannot be removed)."""
    if name in BUILTIN_BACKENDS:
        raise ValueError(f"the built-in backend {name!r} cannot be removed")
    if name not in _REGISTRY:
        raise ValueError(f"no ray backend named {name!r}; registered: {sorted(_REGISTRY)}")
    del _REGISTRY[name]


def backend_names() -> tuple[str, ...]:
    """Every name `backend=` accepts: "auto" and the registered backends."""
    return ("auto", *_REGISTRY)


def get_backend(name: str) -> RayBackend:
    """The registered backend `name` (a ValueError naming the choices where there is none)."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ValueError(f"backend must be one of {backend_names()}, got {name!r}") from None


def lowering_platform(platform: str) -> str:
    """The platform name a program lowers for ("cpu", "cuda", "rocm", "tpu") from a device's or
    `jax.default_backend()`'s ("gpu" for either kind of GPU)."""
    if platform != "gpu":
        return platform
    try:
        version = jax.devices("gpu")[0].client.platform_version.lower()
    except RuntimeError:  # no GPU here: the name is all there is
        return "cuda"
    return "rocm" if "rocm" in version or "hip" in version else "cuda"


def resolve_backend(backend: str, platform: str) -> str:
    """The backend that `backend` runs on `platform` ("cpu", "cuda", ...; "gpu" as
    `lowering_platform` reads it): "auto" is the first registered backend that prefers the
    platform and can run there (Embree on CPU where the native handlers build, Warp on CUDA
    where installed), else the JAX traversal."""
    if backend != "auto":
        get_backend(backend)
        return backend
    platform = lowering_platform(platform)
    for candidate in _REGISTRY.values():
        if platform in candidate.preferred_on and candidate.unavailable(platform) is None:
            return candidate.name
    return "jax"


def describe_backend(backend: str = "auto", platform: str | None = None) -> str:
    """One line naming the backend `backend` runs on `platform` (default: JAX's default
    backend) and, where "auto" falls back to the JAX traversal, why."""
    platform = lowering_platform(platform or jax.default_backend())
    chosen = resolve_backend(backend, platform)
    line = get_backend(chosen).describe(platform)
    if backend != "auto" or chosen != "jax":
        return line
    passed_over = [
        why
        for b in _REGISTRY.values()
        if platform in b.preferred_on and (why := b.unavailable(platform)) is not None
    ]
    why = "; ".join(passed_over) if passed_over else f"no native backend for {platform}"
    return f"jax (the JAX traversal; {why})"


# ---- the built-ins ----------------------------------------------------------------------------


class JaxBackend(RayBackend):
    """The `lax.while_loop` traversal (`_traverse.py`): any XLA device; the oracle."""

    name = "jax"
    scalar_bounds = True

    def query(self, bvh, rays, options):
        from ._query import jax_traversal

        return jax_traversal(bvh, rays, options)

    def describe(self, platform):
        return "jax (the JAX traversal)"


class EmbreeBackend(RayBackend):
    """Embree 4 through the native handlers' FFI call (CPU); where they are unavailable, embreex's
    Python API through `jax.pure_callback` (no `level=`)."""

    name = "embree"
    preferred_on = ("cpu",)

    def unavailable(self, platform):
        if platform != "cpu":
            return f"Embree runs on the CPU, not on {platform}"
        plan = plan_native()
        return None if plan.cpu else f"Embree FFI unavailable: {plan.reason}"

    def query(self, bvh, rays, options):
        from ._embree import embree_ffi_query, embree_query

        o, d, tmin, tmax, level = rays
        any_hit = options.any_hit
        if plan_native().cpu:
            # A packet request: packets of the CPU's native width throughout; one by one:
            # packets only where consecutive rays are coherent (the same hits either way).
            mode = 1 if options.packet_size is not None else -1
            return embree_ffi_query(bvh, o, d, tmin, tmax, level, any_hit=any_hit, packets=mode)
        if level is not None:
            raise ValueError(
                "level= with backend 'embree' needs its FFI handler, which is unavailable: "
                f"{plan_native().reason}"
            )
        return embree_query(bvh, o, d, tmin, tmax, any_hit=any_hit)

    def describe(self, platform):
        plan = plan_native()
        if plan.cpu:
            return f"embree ({plan.reason})"
        return f"embree (embreex through jax.pure_callback; the FFI handler is unavailable: {plan.reason})"


class WarpBackend(RayBackend):
    """NVIDIA Warp's BVH queries through its XLA FFI (CUDA, and Warp's CPU device)."""

    name = "warp"
    preferred_on = ("cuda",)

    def unavailable(self, platform):
        if importlib.util.find_spec("warp") is None:
            return "Warp is not installed: pip install 'fovjax[gpu]'"
        return None

    def query(self, bvh, rays, options):
        from ._warp import warp_query

        return warp_query(bvh, *rays, any_hit=options.any_hit)

    def describe(self, platform):
        return "warp (NVIDIA Warp mesh queries through XLA's FFI)"


BUILTIN_BACKENDS = ("jax", "embree", "warp")
for _backend in (JaxBackend(), EmbreeBackend(), WarpBackend()):
    register_backend(_backend)
# The names the command line offers (a backend registered in Python is not one of them).
BACKENDS = ("auto", *BUILTIN_BACKENDS)
