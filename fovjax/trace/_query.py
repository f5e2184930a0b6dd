"""Public ray queries: `closest_hit` and `occluded`, on the JAX or the Embree backend."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ._bvh import BVH
from ._traverse import traverse

BACKENDS = ("jax", "embree")

# Traversal tuning (see benchmarks/trace_throughput.py): rays in flight at once, and how many
# traversal steps run between refills of finished lanes.
DEFAULT_LANES = 1 << 14
DEFAULT_STEPS_PER_REFILL = 4


class Hit(NamedTuple):
    """Closest hits. `t` is inf and `prim` -1 on a miss; the hit point is
    (1 - u - v) * p0 + u * p1 + v * p2 for the corners p0, p1, p2 of face `prim`."""

    t: Float[Array, "*batch"]
    prim: Int[Array, "*batch"]
    u: Float[Array, "*batch"]
    v: Float[Array, "*batch"]


def _check_backend(backend: str) -> None:
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")


def _flatten_rays(origins, directions, tmin, tmax):
    origins = jnp.asarray(origins, jnp.float32)
    directions = jnp.asarray(directions, jnp.float32)
    if origins.shape[-1:] != (3,) or directions.shape[-1:] != (3,):
        raise ValueError(
            f"origins and directions must end in a dimension of 3, got {origins.shape} and {directions.shape}"
        )
    batch = jnp.broadcast_shapes(origins.shape[:-1], directions.shape[:-1])
    o = jnp.broadcast_to(origins, batch + (3,)).reshape(-1, 3)
    d = jnp.broadcast_to(directions, batch + (3,)).reshape(-1, 3)
    tmin = jnp.broadcast_to(jnp.asarray(tmin, jnp.float32), batch).reshape(-1)
    tmax = jnp.broadcast_to(jnp.asarray(tmax, jnp.float32), batch).reshape(-1)
    return batch, o, d, tmin, tmax


def hit_geometry(vertices, faces, prim, origins, directions):
    """Differentiable (t, u, v) of rays against the faces `prim` (-1: miss → t = inf, u = v = 0).

    Möller–Trumbore in closed form: smooth in vertices, origins and directions. Visibility (which
    face was hit) is taken as given and not differentiated.
    """
    prim = jax.lax.stop_gradient(prim)
    hit = prim >= 0
    tri = jnp.asarray(vertices)[jnp.asarray(faces)[jnp.where(hit, prim, 0)]]
    p0, p1, p2 = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    e1, e2 = p1 - p0, p2 - p0
    pvec = jnp.cross(directions, e2)
    det = jnp.sum(e1 * pvec, -1)
    ok = hit & (det != 0)
    inv_det = 1.0 / jnp.where(ok, det, 1.0)  # the double-where keeps NaN out of gradients
    tvec = origins - p0
    qvec = jnp.cross(tvec, e1)
    u = jnp.sum(tvec * pvec, -1) * inv_det
    v = jnp.sum(directions * qvec, -1) * inv_det
    t = jnp.sum(e2 * qvec, -1) * inv_det
    return jnp.where(ok, t, jnp.inf), jnp.where(ok, u, 0.0), jnp.where(ok, v, 0.0)


@functools.partial(jax.jit, static_argnames=("backend", "any_hit", "lanes", "steps_per_refill"))
def _raw_query(bvh, o, d, tmin, tmax, *, backend, any_hit, lanes, steps_per_refill):
    o, d = jax.lax.stop_gradient(o), jax.lax.stop_gradient(d)
    if backend == "jax":
        return traverse(
            bvh.table,
            bvh.num_nodes,
            bvh.stack_size,
            o,
            d,
            tmin,
            tmax,
            any_hit=any_hit,
            lanes=lanes,
            steps_per_refill=steps_per_refill,
        )
    from ._embree import embree_query

    return embree_query(bvh, o, d, tmin, tmax, any_hit=any_hit)


def closest_hit(
    bvh: BVH,
    origins: Float[Array, "*batch 3"],
    directions: Float[Array, "*batch 3"],
    tmin: float | Float[Array, "*batch"] = 0.0,
    tmax: float | Float[Array, "*batch"] = jnp.inf,
    *,
    backend: str = "jax",
    vertices: Float[Array, "V 3"] | None = None,
    lanes: int = DEFAULT_LANES,
    steps_per_refill: int = DEFAULT_STEPS_PER_REFILL,
) -> Hit:
    """The nearest triangle hit by each ray with tmin < t < tmax.

    Any batch shape; float32; jit-compatible (compiled once per batch shape and BVH). Directions
    need not be normalised (t is in units of the direction's length). Rays with a NaN/inf
    component or a zero direction miss. `t, u, v` are recomputed from the hit triangle's
    corners, so `jax.grad` flows to `origins`, `directions` and `vertices` (pass `vertices` to
    differentiate w.r.t. positions other than the build-time ones; traversal still uses the
    build-time geometry). Visibility changes are not differentiated.
    """
    _check_backend(backend)
    batch, o, d, tmin_f, tmax_f = _flatten_rays(origins, directions, tmin, tmax)
    _, prim = _raw_query(
        bvh,
        o,
        d,
        tmin_f,
        tmax_f,
        backend=backend,
        any_hit=False,
        lanes=lanes,
        steps_per_refill=steps_per_refill,
    )
    verts = bvh.vertices if vertices is None else vertices
    t, u, v = hit_geometry(verts, bvh.faces, prim, o, d)
    return Hit(t=t.reshape(batch), prim=prim.reshape(batch), u=u.reshape(batch), v=v.reshape(batch))


def occluded(
    bvh: BVH,
    origins: Float[Array, "*batch 3"],
    directions: Float[Array, "*batch 3"],
    tmax: float | Float[Array, "*batch"] = jnp.inf,
    *,
    tmin: float | Float[Array, "*batch"] = 0.0,
    backend: str = "jax",
    lanes: int = DEFAULT_LANES,
    steps_per_refill: int = DEFAULT_STEPS_PER_REFILL,
) -> Bool[Array, "*batch"]:
    """Whether anything lies on each ray with tmin < t < tmax (a shadow ray; stops at the
    first hit found, not the nearest)."""
    _check_backend(backend)
    batch, o, d, tmin_f, tmax_f = _flatten_rays(origins, directions, tmin, tmax)
    _, prim = _raw_query(
        bvh,
        o,
        d,
        tmin_f,
        tmax_f,
        backend=backend,
        any_hit=True,
        lanes=lanes,
        steps_per_refill=steps_per_refill,
    )
    return (prim >= 0).reshape(batch)


def brute_force_closest_hit(vertices, faces, origins, directions, tmin=0.0, tmax=np.inf):
    """Reference: every ray against every triangle, float64 Möller–Trumbore with an
    inclusive edge test, on the host. For tests on small meshes."""
    v = np.asarray(vertices, np.float64)[np.asarray(faces)]
    o = np.asarray(origins, np.float64).reshape(-1, 1, 3)
    d = np.asarray(directions, np.float64).reshape(-1, 1, 3)
    p0, e1, e2 = v[None, :, 0], v[None, :, 1] - v[None, :, 0], v[None, :, 2] - v[None, :, 0]
    pvec = np.cross(d, e2)
    det = np.sum(e1 * pvec, -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        tvec = o - p0
        u = np.sum(tvec * pvec, -1) * inv
        qvec = np.cross(tvec, e1)
        w = np.sum(d * qvec, -1) * inv
        t = np.sum(e2 * qvec, -1) * inv
    tmin = np.reshape(np.asarray(tmin, np.float64), (-1, 1))
    tmax = np.reshape(np.asarray(tmax, np.float64), (-1, 1))
    ok = (det != 0) & (u >= 0) & (w >= 0) & (u + w <= 1) & (t > tmin) & (t < tmax)
    t = np.where(ok, t, np.inf)
    prim = np.argmin(t, axis=1)
    tbest = t[np.arange(t.shape[0]), prim]
    prim = np.where(np.isfinite(tbest), prim, -1)
    return tbest, prim, t
