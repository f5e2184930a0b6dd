"""Embree backend (CPU): Embree 4 through an XLA FFI call (`_embree_queries.cc`, one of the native
handlers built on first use: `fovjax.native`),
or, where that handler cannot be built, embreex's Python API through `jax.pure_callback`.

The FFI call runs on XLA's buffers and CPU thread pool inside the compiled program: rays in
16-ray packets (`rtcIntersect16` / `rtcOccluded16`) when they come in a coherent order (tiles,
sorted), one by one otherwise; `tmin` is Embree's `tnear`; a merged BVH's trees are one Embree
scene each, chosen per ray (`level=`). The fallback moves a ray with tmin > 0 to o + tmin * d and
shifts its distances back (embreex's rays start at 0) and supports no `level=`. Either way only
the face index leaves the backend: t, u, v are recomputed differentiably from it.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..native.internal import handler
from ._bvh import BVH, host_geometry

QUERY_TARGET = "fovjax_embree_query"

_SCENES: dict[str, object] = {}


def _require_embreex():
    try:
        from embreex import rtcore_scene  # noqa: F401
        from embreex.mesh_construction import TriangleMesh  # noqa: F401
    except ImportError as exc:
        raise ImportError("the Embree backend needs embreex: pip install 'fovjax[embree]'") from exc


def embree_scene(key: str, vertices: np.ndarray, faces: np.ndarray):
    """The committed embreex scene for a BVH key (built once per process)."""
    _require_embreex()
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    scene = _SCENES.get(key)
    if scene is None:
        # embreex's package __getattr__ returns a str, which the checker reads rtcore_scene as.
        scene = rtcore_scene.EmbreeScene()  # pyright: ignore[reportAttributeAccessIssue]
        TriangleMesh(
            scene=scene, vertices=np.asarray(vertices, np.float32), indices=np.asarray(faces, np.int32)
        )
        _SCENES[key] = scene
    return scene


def embree_trace_host(scene, o, d, tmin, tmax, any_hit):
    """Host-side Embree query on flat float32 arrays. Returns (t, prim), t = tmax on a miss."""
    o = np.asarray(o, np.float32)
    d = np.asarray(d, np.float32)
    tmin = np.asarray(tmin, np.float32)
    tmax = np.asarray(tmax, np.float32)
    valid = np.isfinite(o).all(1) & np.isfinite(d).all(1) & (d != 0).any(1) & (tmax > tmin)
    start = np.ascontiguousarray(np.where(valid[:, None], o + tmin[:, None] * d, 0.0), np.float32)
    dirs = np.ascontiguousarray(np.where(valid[:, None], d, 1.0), np.float32)
    far = np.ascontiguousarray(np.where(valid, np.minimum(tmax - tmin, 1e37), 0.0), np.float32)
    if any_hit:
        geom = scene.run(start, dirs, dists=far.copy(), query="OCCLUDED")
        prim = np.where(valid & (np.asarray(geom) != -1), 0, -1).astype(np.int32)
        return tmax, prim
    res = scene.run(start, dirs, dists=far.copy(), output=1)
    prim = np.where(valid & (res["geomID"] != -1), res["primID"], -1).astype(np.int32)
    t = np.where(prim >= 0, res["tfar"] + tmin, tmax).astype(np.float32)
    return t, prim


def embree_ffi_query(bvh: BVH, o, d, tmin, tmax, level, *, any_hit: bool, packets: int):
    """(t, prim, u, v) of flat rays through the Embree FFI handler (Embree's own distance and
    barycentrics of the hit; t = inf, prim = -1 and u = v = 0 on a miss; prim 0 for an occluded
    ray, whose t, u, v mean nothing).
    `packets`: 1 (every run of consecutive rays one packet of the CPU's native width: 8 with AVX2,
    16 with AVX-512), -1 (a packet where its rays are coherent, else one by one) or 0 (one by
    one)."""
    o, d, tmin, tmax = (jax.lax.stop_gradient(x) for x in (o, d, tmin, tmax))  # visibility only
    level = jnp.zeros((0,), jnp.int32) if level is None else jnp.asarray(level, jnp.int32)
    scene = (
        jnp.asarray(bvh.host_id, jnp.int32),
        jnp.asarray(bvh.vertices, jnp.float32),
        jnp.asarray(bvh.faces, jnp.int32),
        jnp.asarray(bvh.tree_faces(), jnp.int32),
    )
    return _ffi_call(bool(any_hit), int(packets), bool(bvh.watertight))(o, d, tmin, tmax, level, *scene)


@functools.cache
def _ffi_call(any_hit: bool, packets: int, robust: bool):
    """The FFI call for one query kind, with a batching rule: under vmap the frames' rays are
    broadcast to the batch and traced in one call against the one (unbatched) scene."""

    @jax.custom_batching.custom_vmap
    def call(o, d, tmin, tmax, level, host_id, vertices, faces, first_face):
        n = tmin.shape[0]
        f32, i32 = jax.ShapeDtypeStruct((n,), jnp.float32), jax.ShapeDtypeStruct((n,), jnp.int32)
        out = (f32, i32, f32, f32)
        ffi = handler(QUERY_TARGET, out, what="backend 'embree'")
        return ffi(
            o,
            d,
            tmin,
            tmax,
            level,
            host_id,
            vertices,
            faces,
            first_face,
            any_hit=np.int32(any_hit),
            packet=np.int32(packets),
            robust=np.int32(robust),
        )

    @call.def_vmap
    def _batched(axis_size, in_batched, o, d, tmin, tmax, level, *scene):
        if any(in_batched[5:]):
            # A batched scene (its own BVH per frame, or one broadcast by a batched lax.cond):
            # one call per frame, each against its own scene.
            args = [
                x if b else jnp.broadcast_to(x, (axis_size, *x.shape))
                for x, b in zip((o, d, tmin, tmax, level, *scene), in_batched, strict=True)
            ]
            return jax.lax.map(lambda a: call(*a), tuple(args)), (True,) * 4
        rays = [o, d, tmin, tmax] + ([level] if level.shape[0] else [])
        rays = [
            x if b else jnp.broadcast_to(x, (axis_size, *x.shape))
            for x, b in zip(rays, in_batched, strict=False)
        ]
        n = rays[2].shape[1]
        flat = [rays[0].reshape(-1, 3), rays[1].reshape(-1, 3), rays[2].reshape(-1), rays[3].reshape(-1)]
        flat.append(rays[4].reshape(-1) if level.shape[0] else level)
        out = call(*flat, *scene)
        return tuple(x.reshape(axis_size, n) for x in out), (True,) * 4

    return call


def embree_query(bvh: BVH, o, d, tmin, tmax, *, any_hit: bool):
    """(t, prim) through embreex's Python API and `jax.pure_callback` (the fallback)."""

    def host(host_id, o, d, tmin, tmax):
        key, vertices, faces = host_geometry(host_id)
        scene = embree_scene(key, vertices, faces)
        t, prim = embree_trace_host(scene, o, d, tmin, tmax, any_hit)
        return np.asarray(t, np.float32), np.asarray(prim, np.int32)

    n = o.shape[0]
    shapes = (jax.ShapeDtypeStruct((n,), jnp.float32), jax.ShapeDtypeStruct((n,), jnp.int32))
    return jax.pure_callback(host, shapes, bvh.host_id, o, d, tmin, tmax, vmap_method="sequential")
