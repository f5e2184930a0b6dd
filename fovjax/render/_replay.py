"""Derivatives from stored paths: the native integrator's forward records, per ray and depth
level, the face its ray hit and which lights its shadow rays reached (`native_whitted(...,
store_paths=True)`); `replay_radiance` recomputes the same radiance from those paths in plain
JAX, with no ray query and no data-dependent loop, and its derivatives are the integrator's.

Hits are recomputed from the stored face's corners (`hit_geometry`), so gradients reach vertex
positions and the rays as in the JAX integrator; which face a ray hit and whether a shadow ray
was blocked (visibility) are taken as given, as there. The replay shades with the JAX
integrator's own functions (`_surface_and_shadow_rays`, `_finish_shading`), so the two cannot
drift apart; each level runs on every ray, its dead rays masked (the shapes are the forward's).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int, UInt32

from ..native.internal import layout
from ..trace import Hit, hit_geometry


class StoredPaths(NamedTuple):
    """What a native forward traced, per depth level and ray: `prim` the face hit (-1 a miss,
    `layout.PATH_NOT_TRACED` no ray at that level) and `visible` the lights its shadow rays
    reached (bit l: light l, wanted there and unblocked)."""

    prim: Int[Array, "levels n"]
    visible: UInt32[Array, "levels n"]


def replay_radiance(
    scene, bvh, o: Float[Array, "n 3"], d: Float[Array, "n 3"], offset, paths: StoredPaths, shading
) -> Float[Array, "n 3"]:
    """The radiance of rays `o`, `d` (unit directions) along `paths`: the native integrator's
    arithmetic, written with the JAX integrator's shading. Differentiable in `scene`'s arrays,
    `o`, `d` (not in `paths`)."""
    from ._integrator import _finish_shading, _surface_and_shadow_rays

    scene = jax.tree.map(jnp.asarray, scene)  # host NumPy leaves cannot be indexed by traced faces
    prims = jax.lax.stop_gradient(paths.prim)
    visible = jax.lax.stop_gradient(paths.visible)
    n = o.shape[0]
    lights = jnp.arange(scene.num_lights, dtype=jnp.uint32)[:, None]
    weight = jnp.ones((n, 3), jnp.float32)
    total = jnp.zeros((n, 3), jnp.float32)
    for k in range(prims.shape[0]):
        alive = prims[k] != layout.PATH_NOT_TRACED
        prim = jnp.where(prims[k] >= 0, prims[k], -1)
        t, u, v = hit_geometry(scene.vertices, bvh.faces, prim, o, d)
        surface, rays = _surface_and_shadow_rays(scene, Hit(t, prim, u, v), d, alive, offset)
        blocked = None
        if rays is not None:
            blocked = ((visible[k][None] >> lights) & 1) == 0
        contribution, (o, d, weight, _) = _finish_shading(
            scene, surface, d, alive, weight, rays, blocked, offset=offset, spawn=True, shading=shading
        )
        total = total + contribution
    return total
