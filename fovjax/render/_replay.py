"""Derivatives from stored paths: the native integrator's forward records, per ray and depth
level, the face its ray hit and which lights its shadow rays reached (`native_whitted(...,
store_paths=True)`); `replay_radiance` recomputes the same radiance from those paths in plain
JAX, with no ray query and no data-dependent loop, and its derivatives are the integrator's.

Hits are recomputed from the stored face's corners (`hit_geometry`), so gradients reach vertex
positions and the rays as in the JAX integrator; which face a ray hit and whether a shadow ray
was blocked (visibility) are taken as given, as there. The replay shades with the JAX
integrator's own functions (`_surface_and_shadow_rays`, `_finish_shading`), so the two cannot
drift apart; a level shades the rays it holds, chunk by chunk, at the forward's fixed shapes.

The shading parameters (materials, the lights' colours, the ambient colour) have a native
adjoint along the same paths (`render/_whitted_adjoint.cc`): `split_tangents` and
`shading_tangent` send their derivatives there (the replay's JVP stays their forward mode, and
the oracle the adjoint is tested against), and everything else through the replay.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.custom_derivatives import SymbolicZero, linear_call
from jaxtyping import Array, Float, Int, UInt32

from ..native.internal import jvp_of, layout
from ..trace import Hit, hit_geometry


class StoredPaths(NamedTuple):
    """What a native forward traced, per depth level and ray: `prim` the face hit (-1 a miss,
    `layout.PATH_NOT_TRACED` no ray at that level) and `visible` the lights its shadow rays
    reached (bit l: light l, wanted there and unblocked)."""

    prim: Int[Array, "levels n"]
    visible: UInt32[Array, "levels n"]


# Rays shaded per chunk of a level. The reverse pass pays per chunk for stacking its residuals,
# and a deep level with a few live rays pays a whole chunk: benchmarks/gradients.py.
CHUNK = 16384


def replay_radiance(
    scene,
    bvh,
    o: Float[Array, "n 3"],
    d: Float[Array, "n 3"],
    offset,
    paths: StoredPaths,
    shading,
    chunk: int = CHUNK,
) -> Float[Array, "n 3"]:
    """The radiance of rays `o`, `d` (unit directions) along `paths`: the native integrator's
    arithmetic, written with the JAX integrator's shading. Differentiable in `scene`'s arrays,
    `o`, `d` (not in `paths`).

    Each level shades its rays `chunk` at a time, a `lax.cond` skipping the chunks without a
    live ray (a deeper level puts its live rays first): the cost follows the rays the forward
    traced. (Rematerialising each
    chunk in the reverse pass, `jax.checkpoint`, would keep only its inputs, but made a gradient
    several times slower.)"""
    from ._integrator import _finish_shading, _surface_and_shadow_rays

    scene = jax.tree.map(jnp.asarray, scene)  # host NumPy leaves cannot be indexed by traced faces
    prims = jax.lax.stop_gradient(paths.prim)
    visible = jax.lax.stop_gradient(paths.visible)
    n = o.shape[0]
    size = max(1, min(chunk, n))
    count = -(-n // size)
    pad = count * size - n
    if pad:
        o = jnp.pad(o, ((0, pad), (0, 0)))
        d = jnp.pad(d, ((0, pad), (0, 0)))
        prims = jnp.pad(prims, ((0, 0), (0, pad)), constant_values=layout.PATH_NOT_TRACED)
        visible = jnp.pad(visible, ((0, 0), (0, pad)))
    lights = jnp.arange(scene.num_lights, dtype=jnp.uint32)[:, None]

    def shade(scene, o, d, weight, prim, visible):
        alive = prim != layout.PATH_NOT_TRACED
        prim = jnp.where(prim >= 0, prim, -1)
        t, u, v = hit_geometry(scene.vertices, bvh.faces, prim, o, d)
        surface, rays = _surface_and_shadow_rays(scene, Hit(t, prim, u, v), d, alive, offset)
        blocked = None if rays is None else ((visible[None] >> lights) & 1) == 0
        contribution, (o, d, weight, _) = _finish_shading(
            scene, surface, d, alive, weight, rays, blocked, offset=offset, spawn=True, shading=shading
        )
        return contribution, o, d, weight

    weight = jnp.ones_like(o)
    total = jnp.zeros_like(o)
    chunks = jnp.arange(count)

    def permuted(x, by):  # `by` a permutation: unique indices, here and in the reverse pass
        return x.at[by].get(unique_indices=True)

    for k in range(prims.shape[0]):
        alive = prims[k] != layout.PATH_NOT_TRACED
        level = (o, d, weight, prims[k], visible[k])
        if k == 0:
            # The first level, the largest, shades its rays where they are: every ray a frame
            # traces is live there and a foveated frame's unused slots come last, so only
            # chunks without a live ray are skipped, and no permutation is paid for.
            back = None
            live_chunk = jnp.any(alive.reshape(count, size), axis=1)
        else:
            # A deeper level puts its live rays first (a stable permutation: `back`, each ray's
            # place, and its inverse `order`).
            live = alive.astype(jnp.int32)
            n_live = jnp.sum(live)
            index = jnp.arange(live.shape[0], dtype=jnp.int32)
            before = jnp.cumsum(live)  # live rays up to each, itself included
            back = jnp.where(alive, before - 1, n_live + index - before)
            order = jnp.zeros_like(back).at[back].set(index, unique_indices=True)
            level = tuple(permuted(x, order) for x in level)
            live_chunk = chunks * size < n_live
        # The level's rays as the scan's per-chunk inputs and outputs (no carry: a carried
        # array would be copied whole every chunk of the reverse pass).
        ins = tuple(x.reshape((count, size) + x.shape[1:]) for x in level)

        def body(_, chunk):
            is_live, taken = chunk[0], chunk[1:]

            def skip(taken):
                return tuple(jnp.zeros((size, 3), jnp.float32) for _ in range(4))

            return None, jax.lax.cond(is_live, lambda t: shade(scene, *t), skip, taken)

        _, outs = jax.lax.scan(body, None, (live_chunk, *ins))
        contribution, o_next, d_next, w_next = (x.reshape(count * size, 3) for x in outs)
        if back is not None:
            contribution, o_next, d_next, w_next = (
                permuted(x, back) for x in (contribution, o_next, d_next, w_next)
            )
        total = total + contribution
        o, d, weight = o_next, d_next, w_next
    return total[:n]


def _is_zero(t) -> bool:
    return isinstance(t, SymbolicZero)


def split_tangents(primals, tangents, fields: tuple[str, ...], where: int = 0):
    """A custom JVP rule's tangents in two: (the tangents with the scene's `fields` held still,
    or None where nothing else moves; the tangents of the `fields` that move, by name, or None
    where none moves). The scene is operand `where` of `primals`."""
    flat, tree = jax.tree_util.tree_flatten_with_path(tangents, is_leaf=_is_zero)
    primal_leaves = tree.flatten_up_to(primals)
    rest, moving = [], {}
    for (path, t), x in zip(flat, primal_leaves, strict=True):
        key = path[1] if len(path) == 2 and path[0] == jax.tree_util.SequenceKey(where) else None
        name = getattr(key, "name", None)
        if name in fields:
            moving[name] = t
            rest.append(SymbolicZero(jax.typeof(x).to_tangent_aval()))
        else:
            rest.append(t)
    rest_tangents = None if all(_is_zero(t) for t in rest) else jax.tree.unflatten(tree, rest)
    shading = {name: t for name, t in moving.items() if not _is_zero(t)}
    return rest_tangents, (shading or None)


def shading_tangent(
    replayed, adjoint, primals, stored, shading: dict, fields: tuple[str, ...], where: int = 0
):
    """The tangent of `replayed(*primals)`'s first output along the scene's `fields` (the scene
    operand `where`), `shading` their tangents: a linear map whose forward is the replay's own
    JVP and whose transpose is `adjoint(primals, stored, cotangent, moving)` (the native
    adjoint, given what the forward `stored` and the fields that move: a dict of their
    gradients), so that reverse mode never transposes the replay for these fields."""
    names = tuple(name for name in fields if name in shading)

    def forward(residuals, linear):
        primals, _ = residuals
        flat, tree = jax.tree_util.tree_flatten_with_path(primals)
        tangents = []
        for path, x in flat:
            key = path[1] if len(path) == 2 and path[0] == jax.tree_util.SequenceKey(where) else None
            name = getattr(key, "name", None)
            if name in names:
                tangents.append(linear[names.index(name)])
            else:
                tangents.append(SymbolicZero(jax.typeof(x).to_tangent_aval()))
        _, out = jvp_of(replayed, primals, jax.tree.unflatten(tree, tangents))
        return out[0]

    def transpose(residuals, cotangent):
        grads = adjoint(*residuals, cotangent, names)
        return tuple(grads[name].astype(jnp.float32).reshape(shading[name].shape) for name in names)

    return linear_call(forward, transpose, (primals, stored), tuple(shading[name] for name in names))
