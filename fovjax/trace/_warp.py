"""NVIDIA Warp backend: `wp.Mesh` + `mesh_query_ray` / `mesh_query_ray_anyhit`, inside the program.

`warp_query(bvh, o, d, tmin, tmax, level, any_hit=...)` is one XLA FFI call (Warp's `jax_callable`,
which registers the same target for XLA's CPU and CUDA platforms), so the program picks the Warp
device from the platform it is lowered for: one traced function lowers for `platforms=("cpu",)` and
`("cuda",)` alike, and a CUDA export needs no GPU on the exporting machine. On CPU Warp runs the
kernel on one thread (no SIMD); on a GPU it is the fast path.

Design:
- **Meshes** are built from the BVH's build-time geometry (`host_geometry(bvh.host_id)`), once per
  geometry key and Warp device, and cached in this module (`_MESHES`); `release_meshes()` frees
  them. They live as long as the process's host geometry registry otherwise (like the Embree
  scenes): a BVH has no hook that says when it is gone. A merged LOD BVH (`merge_bvhs`) becomes
  one *grouped* mesh, group l = tree l's faces, and a ray of level l is traced from
  `mesh_get_group_root(mesh, l)`: only its level's triangles, `prim` indexing the merged faces.
- **The mesh id reaches the kernel at run time, not compile time.** The FFI operands are the BVH's
  `host_id` (an int32 array leaf) and the rays; the Python side of the call (run on every call:
  graph mode NONE) makes sure the mesh exists and passes the kernel a per-device table of mesh ids
  (`wp.array` of uint64, not a JAX operand: JAX without x64 has no uint64 arrays), which the kernel
  indexes with `host_id[0]`. So a new scene with the same array shapes reuses the compiled program
  (nothing about the scene is a constant in it); on CUDA the host id is never copied to the host
  (no stream sync): every registered geometry gets its mesh on that device when the table is
  first needed after it was registered.
- **Ordering**: the mesh build, the table upload and the query kernel are issued from the same
  FFI call on XLA's own stream (Warp runs the callable under that stream), so the build always
  completes before the query; nothing else writes the meshes (there is no refit here: traversal
  geometry is the build-time geometry, as for the other backends).
- Warp has no `tmin`: a ray starts at `o + tmin * d` with `max_t = tmax - tmin` (clamped to 1e37)
  and `tmin` is added back to its distance, as in the Embree path. Rays with a NaN/inf component, a
  zero direction, `tmax <= tmin` (or NaN bounds), or a non-finite start point miss.

Returns `(t, prim)` as the other backends' raw query: prim int32 (-1 on a miss; for `any_hit` 0 if
anything lies on the ray), t float32 (the hit distance where prim >= 0, else `tmax`; for `any_hit`,
`tmax`). Warp is imported on first use: importing this module never needs it.

Each traced call adds a Warp `call_id` attribute to the program (Warp keeps per-trace descriptors
keyed by it), so the HLO of two traces of the same function differs by that number: jit's own
cache is unaffected, but a persistent-compilation-cache hit needs the same trace order.
"""

# Warp kernels are Warp's language, not Python's: their parameters are annotated with
# `wp.array(dtype=...)` calls and their values are Warp's types, which the type checker reads as
# Python (`wp.tid()` as any of its overloads, a mesh query's fields as unknown).
# pyright: reportInvalidTypeForm=false, reportArgumentType=false, reportAttributeAccessIssue=false
# pyright: reportOperatorIssue=false

import functools
import logging
import os
import sys
import tempfile
import threading
import typing
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ._bvh import _HOST_GEOMETRY, BVH, host_geometry, host_level_faces

# (device alias, geometry key) -> (wp.Mesh, its points, indices and groups arrays).
_MESHES: dict[tuple[str, str], tuple] = {}
# device alias -> (mesh id per host id, 0 where none is built; that tuple as a wp.array of uint64).
_TABLES: dict[str, tuple] = {}
# Warp's BVH builder for the meshes: "sah" (Warp's default on CPU; on CUDA Warp defaults to "lbvh",
# faster to build, slower to trace — the scenes here are built once and traced many times).
# benchmarks/trace_warp.py --warp-bvh compares them.
BVH_CONSTRUCTOR = "sah"
# Replaced id tables (8 bytes per geometry each), kept until release_meshes().
_RETIRED: list = []
_LOCK = threading.RLock()


def _require_warp():
    try:
        import warp
    except ImportError as exc:
        raise ImportError("the Warp backend needs warp-lang: pip install 'fovjax[gpu]'") from exc
    # No start-up banner in a command's output (Warp reads this when it initialises).
    if warp.config.log_level < logging.WARNING:
        warp.config.log_level = logging.WARNING
    _init_quietly(warp)
    return warp


# What Warp's native library prints (to the process's stderr, not Python's) when it finds no
# CUDA driver; on a machine without an NVIDIA device that is expected, not news.
_NO_DRIVER = "Could not find or load the NVIDIA CUDA driver"


def _nvidia_device_present() -> bool:
    return Path("/proc/driver/nvidia").exists() or any(Path("/dev").glob("nvidia[0-9]*"))


def _init_quietly(warp) -> None:
    """`warp.init()`, leaving out Warp's "no CUDA driver" line on a machine with no NVIDIA
    device (every program that lowers the "auto" backend initialises Warp for its CUDA branch).
    Anything else it prints is passed on, and the line too where an NVIDIA device is present
    (a driver that does not load there is a real problem)."""
    if not sys.platform.startswith("linux") or _nvidia_device_present():
        warp.init()
        return
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with tempfile.TemporaryFile() as captured:
            os.dup2(captured.fileno(), 2)
            try:
                warp.init()
            finally:
                os.dup2(saved, 2)
                captured.seek(0)
                text = captured.read().decode(errors="replace")
            kept = [line for line in text.splitlines(keepends=True) if _NO_DRIVER not in line]
            if kept:
                sys.stderr.write("".join(kept))
                sys.stderr.flush()
    finally:
        os.close(saved)


def warp_available() -> bool:
    try:
        _require_warp()
    except ImportError:
        return False
    return True


def release_meshes() -> None:
    """Free every cached Warp mesh (and id table); the next query rebuilds what it needs. Call it
    with no query in flight (after `jax.block_until_ready` on their results)."""
    with _LOCK:
        _TABLES.clear()
        _RETIRED.clear()
        _MESHES.clear()


def _mesh(wp, device, host_id: int):
    """The cached `wp.Mesh` of this host geometry on `device` (built on the current stream)."""
    key, vertices, faces = host_geometry(host_id)
    slot = (device.alias, key)  # the builder is not in the key: release_meshes() after changing it
    entry = _MESHES.get(slot)
    if entry is None:
        points = wp.array(np.ascontiguousarray(vertices, np.float32), dtype=wp.vec3, device=device)
        indices = wp.array(np.ascontiguousarray(faces, np.int32).reshape(-1), dtype=wp.int32, device=device)
        counts = host_level_faces(host_id)
        groups = None
        if counts is not None:
            per_face = np.repeat(np.arange(len(counts), dtype=np.int32), counts)
            groups = wp.array(per_face, dtype=wp.int32, device=device)
        mesh = wp.Mesh(points=points, indices=indices, groups=groups, bvh_constructor=BVH_CONSTRUCTOR)
        entry = _MESHES[slot] = (mesh, points, indices, groups)
    return entry[0]


def _id_table(wp, device, host_id: int | None):
    """The uint64 mesh-id table the kernel indexes by host id, on `device`.

    With `host_id` (CPU: the operand is host memory, read for free) only that geometry's mesh is
    ensured; with None (CUDA: the operand stays on the device) every registered geometry's is."""
    with _LOCK:
        n = len(_HOST_GEOMETRY)
        wanted = range(n) if host_id is None else [host_id] if 0 <= host_id < n else []
        for h in wanted:
            _mesh(wp, device, h)
        ids = tuple(
            int(e[0].id) if (e := _MESHES.get((device.alias, _HOST_GEOMETRY[h][0]))) is not None else 0
            for h in range(n)
        )
        cached = _TABLES.get(device.alias)
        if cached is None or cached[0] != ids:
            if cached is not None:
                # A kernel queued earlier on the stream may still read the old table: keep it.
                _RETIRED.append(cached[1])
            table = wp.array(np.array(ids or (0,), np.uint64), dtype=wp.uint64, device=device)
            cached = _TABLES[device.alias] = (ids, table)
        return cached[1]


# Not type-checked by the tests' jaxtyping/beartype import hook: Warp's annotations are its own
# (`wp.array(dtype=...)` instances), and they are evaluated here, eagerly (no `from __future__
# import annotations` in this module: Warp evaluates them against the function's closure).
@functools.cache
@typing.no_type_check
def _callables():
    """The two FFI callables (closest, any hit), made once per process on first use."""
    wp = _require_warp()
    from warp import JaxCallableGraphMode, jax_callable

    @wp.func
    def _setup(
        meshes: wp.array(dtype=wp.uint64),
        host_id: wp.array(dtype=wp.int32),
        i: int,
        o: wp.array(dtype=wp.vec3),
        d: wp.array(dtype=wp.vec3),
        tmin: wp.array(dtype=wp.float32),
        tmax: wp.array(dtype=wp.float32),
        level: wp.array(dtype=wp.int32),
    ):
        # -> (mesh id or 0 for "skip this ray", start, max_t, root)
        h = host_id[0]
        mesh = wp.uint64(0)
        if h >= 0 and h < meshes.shape[0]:
            mesh = meshes[h]
        oi = o[i]
        di = d[i]
        a = tmin[i]
        b = tmax[i]
        start = oi + a * di
        ok = b > a and wp.isfinite(oi) and wp.isfinite(di) and wp.length_sq(di) > 0.0 and wp.isfinite(start)
        if not ok:
            mesh = wp.uint64(0)
        root = -1
        lv = level[wp.min(i, level.shape[0] - 1)]
        if mesh != wp.uint64(0) and lv >= 0:
            root = wp.mesh_get_group_root(mesh, lv)
        # An infinite tmax is "no limit": Warp's max_t stays finite.
        return mesh, start, wp.min(b - a, 1.0e37), root

    @wp.kernel
    def _closest_kernel(
        meshes: wp.array(dtype=wp.uint64),
        host_id: wp.array(dtype=wp.int32),
        o: wp.array(dtype=wp.vec3),
        d: wp.array(dtype=wp.vec3),
        tmin: wp.array(dtype=wp.float32),
        tmax: wp.array(dtype=wp.float32),
        level: wp.array(dtype=wp.int32),
        t_out: wp.array(dtype=wp.float32),
        prim_out: wp.array(dtype=wp.int32),
    ):
        i = wp.tid()
        mesh, start, far, root = _setup(meshes, host_id, i, o, d, tmin, tmax, level)
        t_out[i] = tmax[i]
        prim_out[i] = -1
        if mesh != wp.uint64(0):
            q = wp.mesh_query_ray(mesh, start, d[i], far, root)
            if q.result:
                t_out[i] = q.t + tmin[i]
                prim_out[i] = q.face

    @wp.kernel
    def _anyhit_kernel(
        meshes: wp.array(dtype=wp.uint64),
        host_id: wp.array(dtype=wp.int32),
        o: wp.array(dtype=wp.vec3),
        d: wp.array(dtype=wp.vec3),
        tmin: wp.array(dtype=wp.float32),
        tmax: wp.array(dtype=wp.float32),
        level: wp.array(dtype=wp.int32),
        t_out: wp.array(dtype=wp.float32),
        prim_out: wp.array(dtype=wp.int32),
    ):
        i = wp.tid()
        mesh, start, far, root = _setup(meshes, host_id, i, o, d, tmin, tmax, level)
        t_out[i] = tmax[i]
        prim_out[i] = -1
        if mesh != wp.uint64(0):
            if wp.mesh_query_ray_anyhit(mesh, start, d[i], far, root):
                prim_out[i] = 0

    def make(kernel, name):
        def query(
            host_id: wp.array(dtype=wp.int32),
            o: wp.array(dtype=wp.vec3),
            d: wp.array(dtype=wp.vec3),
            tmin: wp.array(dtype=wp.float32),
            tmax: wp.array(dtype=wp.float32),
            level: wp.array(dtype=wp.int32),
            t_out: wp.array(dtype=wp.float32),
            prim_out: wp.array(dtype=wp.int32),
        ):
            device = o.device
            # On CPU the operand is host memory: read the one id; on CUDA leave it on the device.
            h = int(host_id.numpy()[0]) if device.is_cpu else None
            meshes = _id_table(wp, device, h)
            wp.launch(
                kernel,
                dim=o.shape[0],
                inputs=[meshes, host_id, o, d, tmin, tmax, level],
                outputs=[t_out, prim_out],
                device=device,
            )

        # The FFI target is named after this (Warp appends "_0").
        query.__name__ = query.__qualname__ = name
        # NONE: the Python side runs on every call (it may build a mesh and upload the id table),
        # so it must not be frozen into a CUDA graph.
        return jax_callable(
            query, num_outputs=2, graph_mode=JaxCallableGraphMode.NONE, vmap_method="sequential"
        )

    return make(_closest_kernel, "fovjax_warp_closest"), make(_anyhit_kernel, "fovjax_warp_anyhit")


@functools.cache
@typing.no_type_check
def _mesh_id_callable():
    """The FFI callable that hands a kernel its mesh (`warp_mesh_words`), made once per process."""
    wp = _require_warp()
    from warp import JaxCallableGraphMode, jax_callable

    # A module of its own: its hash (the name of its compiled file) does not depend on which
    # other kernels of this file were made first (`compile_ahead`).
    @wp.kernel(enable_backward=False, module="unique")
    def _words_kernel(
        meshes: wp.array(dtype=wp.uint64),
        host_id: wp.array(dtype=wp.int32),
        words: wp.array(dtype=wp.int32),
    ):
        h = host_id[0]
        mesh = wp.uint64(0)
        if h >= 0 and h < meshes.shape[0]:
            mesh = meshes[h]
        words[0] = wp.int32(wp.uint32(mesh & wp.uint64(0xFFFFFFFF)))
        words[1] = wp.int32(wp.uint32(mesh >> wp.uint64(32)))

    def fovjax_warp_mesh(host_id: wp.array(dtype=wp.int32), words: wp.array(dtype=wp.int32)):
        device = host_id.device
        # As the queries' (`_callables`): on CPU read the one id, on CUDA leave it on the device.
        h = int(host_id.numpy()[0]) if device.is_cpu else None
        meshes = _id_table(wp, device, h)
        wp.launch(_words_kernel, dim=1, inputs=[meshes, host_id], outputs=[words], device=device)

    # The FFI target is named after this (Warp appends "_0").
    fovjax_warp_mesh.__qualname__ = fovjax_warp_mesh.__name__
    # NONE: the Python side must run on every call (it may build the mesh and upload the table).
    call = jax_callable(fovjax_warp_mesh, graph_mode=JaxCallableGraphMode.NONE, vmap_method="sequential")
    return call, _words_kernel.module


def compile_ahead(arch: int, module_dir: str | None = None) -> list:
    """Compile this file's Warp modules (the queries, the mesh id's) for the CUDA architecture
    `arch` (90: H100, H200), as PTX and as CUBIN (Warp picks one by the driver's version), into
    Warp's kernel cache (`WARP_CACHE_PATH`) or `module_dir`, on any machine: a GPU with that cache
    then loads them instead of compiling them on first use. Returns the paths Warp wrote."""
    wp = _require_warp()
    _callables()
    modules = (__name__, _mesh_id_callable()[1])  # the queries' module is named after this file
    return [
        path
        for module in modules
        for use_ptx in (True, False)
        for path in wp.compile_aot_module(module, arch=arch, module_dir=module_dir, use_ptx=use_ptx)
    ]


def mesh_id_target() -> str:
    """The XLA FFI target name of `warp_mesh_words`'s call (registered for "cpu" and "CUDA")."""
    return _mesh_id_callable()[0].name


def warp_mesh_words(bvh: BVH):
    """The id of `bvh`'s Warp mesh (its build-time geometry) on the device of the platform being
    lowered, as int32 (2,): its low and high 32-bit words (JAX without x64 has no uint64), 0 where
    the BVH's host geometry is unknown. One FFI call whose Python side runs every time (the mesh
    is built there on first use and cached, as for the queries); a kernel that takes the words
    as an operand (`fovjax.render`'s Warp integrator) needs no Python of its own to find the
    mesh, so it can be a plain kernel launch."""
    host_id = jnp.reshape(jnp.asarray(bvh.host_id, jnp.int32), (1,))
    (words,) = _mesh_id_callable()[0](host_id, output_dims=(2,))
    return words


def ffi_target_names() -> tuple[str, str]:
    """The XLA FFI target names of the closest-hit and any-hit calls (registered for "cpu" and
    "CUDA" on first use), e.g. for `jax.export`'s `DisabledSafetyChecks.custom_call`."""
    closest, anyhit = _callables()
    return closest.name, anyhit.name


def warp_query(bvh: BVH, o, d, tmin, tmax, level=None, *, any_hit: bool):
    """(t, prim) of flat rays (o, d: float32 (n, 3); tmin, tmax: float32 (n,); level: int32 (n,) or
    None) against `bvh`'s build-time geometry, on Warp's device for the platform being lowered."""
    closest, anyhit = _callables()
    # Which face is hit is not differentiated (the hit is recomputed from it): no gradient into
    # the FFI call, which has no derivative rule.
    o = jax.lax.stop_gradient(jnp.asarray(o, jnp.float32))
    d = jax.lax.stop_gradient(jnp.asarray(d, jnp.float32))
    tmin, tmax = jax.lax.stop_gradient(tmin), jax.lax.stop_gradient(tmax)
    n = o.shape[0]
    tmin = jnp.broadcast_to(jnp.asarray(tmin, jnp.float32), (n,))
    tmax = jnp.broadcast_to(jnp.asarray(tmax, jnp.float32), (n,))
    if level is None:
        # No level: a single tree traces from its root (-1); a merged BVH's level 0, as in the JAX
        # traversal (which starts at item 0, tree 0's root).
        lv = jnp.full((1,), -1 if bvh.roots is None else 0, jnp.int32)
    else:
        if bvh.roots is None:
            raise ValueError("level= needs a merged BVH (fovjax.trace.merge_bvhs); this one has one tree")
        lv = jnp.clip(jnp.broadcast_to(jnp.asarray(level, jnp.int32), (n,)), 0, bvh.num_levels - 1)
    if n == 0:
        return jnp.zeros((0,), jnp.float32), jnp.zeros((0,), jnp.int32)
    host_id = jnp.reshape(jnp.asarray(bvh.host_id, jnp.int32), (1,))
    call = anyhit if any_hit else closest
    t, prim = call(host_id, o, d, tmin, tmax, lv, output_dims=(n,))
    return t, prim
