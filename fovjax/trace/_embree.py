"""Embree backend (CPU only), through embreex, called from JAX with `jax.pure_callback`.

Embree's rays start at t = 0, so a ray with tmin > 0 is moved to o + tmin * d and its distances
shifted back; the same differentiable recomputation as the JAX backend then produces t, u, v.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ._bvh import BVH, host_geometry

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
        scene = rtcore_scene.EmbreeScene()
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


def embree_query(bvh: BVH, o, d, tmin, tmax, *, any_hit: bool):
    def host(host_id, o, d, tmin, tmax):
        key, vertices, faces = host_geometry(host_id)
        scene = embree_scene(key, vertices, faces)
        t, prim = embree_trace_host(scene, o, d, tmin, tmax, any_hit)
        return np.asarray(t, np.float32), np.asarray(prim, np.int32)

    n = o.shape[0]
    shapes = (jax.ShapeDtypeStruct((n,), jnp.float32), jax.ShapeDtypeStruct((n,), jnp.int32))
    return jax.pure_callback(host, shapes, bvh.host_id, o, d, tmin, tmax, vmap_method="sequential")
