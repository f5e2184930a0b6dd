"""The flattened BVH pytree, its packing for traversal, and the on-disk cache.

Layout: one int32 table of 16-word (64-byte) rows, indexed by a single "item" id: rows
[0, num_nodes) are 4-wide inner nodes with quantised child boxes, depth-first; rows
[num_nodes, num_nodes + F) are triangles in leaf order (`_wide.py` gives the words of each). A
child item >= num_nodes is a leaf: traversal walks its triangles row by row until the "last"
flag. A node and a triangle are both one row, one cache line: a traversal step gathers exactly
one row, whether the ray is at a node or at a triangle (perf-notes: gathers dominate on XLA CPU).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import TypeAlias

import equinox as eqx
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, Real

from .. import _environment
from ..scene import Scene
from ._build import BuildParams, build_tree
from ._wide import ROW_WORDS, pack

FORMAT_VERSION = 2

# A mesh as arrays or nested sequences: (V, 3) corner positions, (F, 3) corner indices per face.
VerticesLike: TypeAlias = Real[ArrayLike, "V 3"] | Sequence[Sequence[float]]
FacesLike: TypeAlias = Int[ArrayLike, "F 3"] | Sequence[Sequence[int]]

# Host copies of each BVH's geometry for host callbacks (the Embree backend), indexed by
# `BVH.host_id`. The id is an array leaf, not a static field, so a new scene of the same array
# shapes reuses the compiled traversal instead of recompiling.
_HOST_GEOMETRY: list[tuple[str, np.ndarray, np.ndarray]] = []
_HOST_ID: dict[str, int] = {}
# For a merged BVH's key: the number of faces of each of its trees, in order (native backends that
# build their own acceleration structure per level need it; the merged faces hold no level).
_HOST_LEVEL_FACES: dict[str, np.ndarray] = {}


class BVH(eqx.Module):
    """A BVH ready for `closest_hit` / `occluded`.

    `table` drives the (non-differentiated) traversal; `vertices`/`faces` are the scene's own
    arrays, used to recompute hit distances and barycentrics differentiably.
    """

    table: Int[np.ndarray | Array, "R 16"]
    vertices: Float[np.ndarray | Array, "V 3"]
    faces: Int[np.ndarray | Array, "F 3"]
    num_nodes: Int[np.ndarray | np.number | Array, ""]
    host_id: Int[np.ndarray | np.number | Array, ""]
    stack_size: int = eqx.field(static=True)
    # A merged BVH (`merge_bvhs`): the item each level's traversal starts at; None: one tree, root 0.
    roots: Int[np.ndarray | Array, " L"] | None = None
    # A merged BVH: the first face of each level's tree, then the face count (native backends
    # build one scene per tree from it); None: one tree.
    first_face: Int[np.ndarray | Array, " L1"] | None = None
    # The Embree backend's intersector (`with_watertight`): robust, which closes most gaps at
    # shared edges and vertices (not every one, see `with_watertight`), or Embree's default, faster one.
    watertight: bool = eqx.field(static=True, default=True)

    def with_watertight(self, watertight: bool) -> BVH:
        """This BVH with the Embree backend's intersector chosen (a static setting: one program
        each). `True` (the default, what `build_bvh` makes): Embree's robust mode, its watertight
        triangle test and conservative box tests: a ray through the shared edges and vertices of
        a flat grid hits one of their faces (`tests/test_trace_native.py`), but a ray aimed
        exactly at a vertex of a closed tetrahedron can pass through (a known limitation of
        Embree's robust mode, found by `tests/test_trace_properties.py`, which therefore pins the
        JAX traversal; that one hits them all). `False`: Embree's default
        intersector, as Mitsuba 3 builds its scenes unless asked
        (`embree_use_robust_intersections`): faster (`benchmarks/trace_throughput.py
        --not-watertight`), and a ray that grazes such an edge or vertex may miss both faces, a
        pinhole of light in a closed mesh. The JAX traversal and Warp do not read it."""
        if not isinstance(watertight, bool):
            raise TypeError(f"watertight must be True or False, got {watertight!r}")
        return dataclasses.replace(self, watertight=watertight)

    def tree_faces(self) -> Int[np.ndarray | Array, " L1"]:
        """The first face of each tree and the face count: [0, F] for a single tree."""
        if self.first_face is None:
            return np.array([0, self.num_triangles], np.int32)
        return self.first_face

    @property
    def num_levels(self) -> int:
        return 1 if self.roots is None else int(np.shape(self.roots)[0])

    @property
    def num_triangles(self) -> int:
        return int(np.shape(self.faces)[0])

    @property
    def key(self) -> str:
        """The cache key (geometry hash and build parameters); host-side only."""
        return _HOST_GEOMETRY[int(self.host_id)][0]

    @property
    def nbytes(self) -> int:
        return int(np.asarray(self.table).nbytes)


def _cache_dir(cache_dir) -> Path:
    return Path(cache_dir) if cache_dir is not None else _environment.cache_dir("bvh")


def _key(geometry_hash: str, params: BuildParams) -> str:
    p = json.dumps(asdict(params), sort_keys=True)
    return hashlib.sha256(f"{geometry_hash}|{p}|v{FORMAT_VERSION}".encode()).hexdigest()[:32]


def _load_cached(path: Path, key: str, n_faces: int):
    """Return (table, num_nodes, stack_size) or None if the file is absent, unreadable or stale."""
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            table = np.array(z["table"])
        ok = (
            meta.get("key") == key
            and meta.get("format") == FORMAT_VERSION
            and table.dtype == np.int32
            and table.ndim == 2
            and table.shape[1] == ROW_WORDS
            and table.shape[0] == meta["num_nodes"] + n_faces
            and meta.get("sha256") == hashlib.sha256(table.tobytes()).hexdigest()
        )
        if not ok:
            warnings.warn(f"BVH cache {path} is stale or corrupt; rebuilding", stacklevel=3)
            return None
        return table, int(meta["num_nodes"]), int(meta["stack_size"])
    except Exception as exc:  # unreadable: rebuild, never trust
        warnings.warn(f"BVH cache {path} is unreadable ({exc}); rebuilding", stacklevel=3)
        return None


def _save_cached(path: Path, key: str, table: np.ndarray, num_nodes: int, stack_size: int) -> None:
    meta = {
        "key": key,
        "format": FORMAT_VERSION,
        "num_nodes": num_nodes,
        "stack_size": stack_size,
        "sha256": hashlib.sha256(table.tobytes()).hexdigest(),
    }
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
        np.savez(tmp, table=table, meta=np.array(json.dumps(meta)))
        os.replace(tmp, path)  # atomic: a concurrent reader never sees half a file
    except OSError as exc:
        warnings.warn(f"could not write BVH cache {path}: {exc}", stacklevel=3)


LAST_BUILD: dict = {}


def build_bvh(
    scene: Scene | None = None,
    *,
    vertices: VerticesLike | None = None,
    faces: FacesLike | None = None,
    params: BuildParams | None = None,
    cache: bool = True,
    cache_dir: str | os.PathLike | None = None,
) -> BVH:
    """Build (or load from the disk cache) the BVH of a `Scene`, or of `vertices`/`faces`.

    The cache key is the geometry hash plus the build parameters; a cached file whose contents
    do not match its recorded checksum or key is rebuilt. `fovjax.trace.last_build_info()`
    reports the time taken and whether the cache was used.
    """
    from ..scene import geometry_hash, validate_geometry

    params = params or BuildParams()
    if scene is not None:
        if vertices is not None or faces is not None:
            raise ValueError("build_bvh: pass either a scene or vertices/faces, not both")
        vertices, faces = scene.vertices, scene.faces
    if vertices is None or faces is None:
        raise ValueError("build_bvh: need a scene, or both vertices and faces")
    v, f = validate_geometry(np.asarray(vertices), np.asarray(faces), "build_bvh")
    ghash = scene.content_hash if scene is not None and scene.content_hash else geometry_hash(v, f)
    key = _key(ghash, params)
    t0 = time.perf_counter()
    path = _cache_dir(cache_dir) / f"{key}.npz"
    cached = _load_cached(path, key, f.shape[0]) if cache else None
    if cached is not None:
        table, num_nodes, stack_size = cached
        depth = None
    else:
        tri = v[f]
        tree = build_tree(tri.min(axis=1), tri.max(axis=1), params)
        table, num_nodes, stack_size = pack(tree, tri)
        depth = tree.depth
        if cache:
            _save_cached(path, key, table, num_nodes, stack_size)
    seconds = time.perf_counter() - t0
    LAST_BUILD.clear()
    LAST_BUILD.update(
        seconds=seconds, from_cache=cached is not None, num_nodes=num_nodes, depth=depth, nbytes=table.nbytes
    )
    host_id = _HOST_ID.get(key)
    if host_id is None:
        host_id = _HOST_ID[key] = len(_HOST_GEOMETRY)
        _HOST_GEOMETRY.append((key, v, f))
    return BVH(
        table=table,
        vertices=v,
        faces=f,
        num_nodes=np.int32(num_nodes),
        host_id=np.int32(host_id),
        stack_size=stack_size,
    )


def merge_bvhs(bvhs: Iterable[BVH]) -> BVH:
    """One BVH holding several trees (e.g. a scene's levels of detail), each still its own tree.

    The table is every tree's node rows, then every tree's triangle rows (so `item < num_nodes`
    still tells a node from a triangle), child items shifted accordingly; `roots[l]` is the item
    tree l starts at. `vertices`/`faces` are the trees' concatenated, faces re-indexed, and a hit's
    `prim` is an index into them: tree l's face j is `sum(len(faces of trees < l)) + j`. A query
    picks a tree per ray with `level=` (`closest_hit`, `occluded`): one traversal for rays of any
    mix of trees, with static shapes. Host-side (numpy); cheap next to building the trees."""
    bvhs = tuple(bvhs)
    if not bvhs or not all(isinstance(b, BVH) and b.roots is None for b in bvhs):
        raise ValueError("merge_bvhs: need one or more single-tree BVHs (from build_bvh)")
    tables = [np.asarray(b.table) for b in bvhs]
    nodes = [int(b.num_nodes) for b in bvhs]
    tris = [t.shape[0] - m for t, m in zip(tables, nodes, strict=True)]
    total_nodes = sum(nodes)
    node_off = np.cumsum([0, *nodes[:-1]])
    tri_off = np.cumsum([0, *tris[:-1]])
    vert_off = np.cumsum([0, *(np.shape(b.vertices)[0] for b in bvhs[:-1])])
    node_rows, tri_rows = [], []
    for table, m, no, to in zip(tables, nodes, node_off, tri_off, strict=True):
        rows = table[:m].copy()
        child = rows[:, 10:14]
        shifted = np.where(child < m, child + no, child - m + total_nodes + to)
        rows[:, 10:14] = np.where(child < 0, child, shifted)
        node_rows.append(rows)
        trows = table[m:].copy()
        trows[:, 9] += to  # the merged face index
        tri_rows.append(trows)
    table = np.concatenate(node_rows + tri_rows).astype(np.int32)
    vertices = np.concatenate([np.asarray(b.vertices, np.float32) for b in bvhs])
    faces = np.concatenate([np.asarray(b.faces) + vo for b, vo in zip(bvhs, vert_off, strict=True)]).astype(
        np.int32
    )
    key = hashlib.sha256("|".join(b.key for b in bvhs).encode()).hexdigest()[:32] + "-merged"
    host_id = _HOST_ID.get(key)
    if host_id is None:
        host_id = _HOST_ID[key] = len(_HOST_GEOMETRY)
        _HOST_GEOMETRY.append((key, vertices, faces))
    _HOST_LEVEL_FACES[key] = np.asarray(tris, np.int64)
    return BVH(
        table=table,
        vertices=vertices,
        faces=faces,
        num_nodes=np.int32(total_nodes),
        host_id=np.int32(host_id),
        stack_size=max(b.stack_size for b in bvhs),
        roots=node_off.astype(np.int32),
        first_face=np.append(tri_off, sum(tris)).astype(np.int32),
        watertight=all(b.watertight for b in bvhs),
    )


def last_build_info() -> dict:
    """Timing and shape of the most recent `build_bvh` call (seconds, from_cache, num_nodes, ...)."""
    return dict(LAST_BUILD)


def host_geometry(host_id: int | np.integer | np.ndarray | Array) -> tuple[str, np.ndarray, np.ndarray]:
    """(key, vertices, faces) at build time of the BVH with this host id (for host callbacks)."""
    try:
        return _HOST_GEOMETRY[int(host_id)]
    except IndexError:
        raise ValueError(
            f"BVH host id {int(host_id)} is unknown in this process; build it with build_bvh()"
        ) from None


def host_level_faces(host_id: int | np.integer | np.ndarray | Array) -> np.ndarray | None:
    """Faces per tree of the merged BVH with this host id, in level order (they are consecutive in
    its merged faces); None for a single-tree BVH."""
    key, _, _ = host_geometry(host_id)
    return _HOST_LEVEL_FACES.get(key)
