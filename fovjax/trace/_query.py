"""Public ray queries: `closest_hit` and `occluded`, on a native backend or the JAX traversal.

Backends answer one question for a batch of rays: which face each ray hits first (or whether
anything lies on it). `"embree"` is Embree through an XLA FFI call (CPU), `"warp"` NVIDIA Warp's
BVH queries (CUDA, and CPU), `"jax"` the `lax.while_loop` traversal of `_traverse.py` (any XLA
device; the reference every other backend is tested against); others can be registered
(`_backends.py`). `"auto"` (the default) picks per platform inside the program
(`fovjax.native.internal.on_platforms`): Embree on CPU where its handler builds, Warp on CUDA
where it is installed, else JAX — so one program lowers for CPU and CUDA (and, where JAX sees a
device of another platform, for it too, on the JAX traversal).
t, u, v are recomputed from the hit face in plain JAX, so gradients do not depend on the backend.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ..native.internal import on_platforms
from ._backends import QueryOptions, RayBatch, get_backend, resolve_backend
from ._bvh import BVH, FacesLike, VerticesLike
from ._order import inverse_order, spatial_order
from ._packet import traverse_packets
from ._traverse import Nodes, Traversal, traverse

DEFAULT_TRAVERSAL = Traversal()
# Packet size of `packet="sorted"` (rays regrouped by their origins): 16, 32 and 64 measured
# alike on the atrium's shadow rays in pixel order; 64 fastest once they are sorted.
SORTED_PACKET = 64

Packet = int | tuple[int, int] | str | None


class Hit(NamedTuple):
    """Closest hits. `t` is inf and `prim` -1 on a miss; the hit point is
    (1 - u - v) * p0 + u * p1 + v * p2 for the corners p0, p1, p2 of face `prim`."""

    t: Float[Array, "*batch"]
    prim: Int[Array, "*batch"]
    u: Float[Array, "*batch"]
    v: Float[Array, "*batch"]


def _check(backend: str, packet: Packet) -> None:
    if backend != "auto":
        get_backend(backend)  # a ValueError naming the registered backends
    if packet is None or packet == "sorted":
        return
    if isinstance(packet, str):
        raise ValueError(
            f"packet must be None, a positive int, a (height, width) tile or 'sorted', got {packet!r}"
        )
    sizes = (packet,) if isinstance(packet, int) else tuple(packet)
    if len(sizes) not in (1, 2) or any(not isinstance(s, int) or s < 1 for s in sizes):
        raise ValueError(f"packet must be None, a positive int or a (height, width) tile, got {packet!r}")


def _tile_order(batch: tuple[int, ...], tile: tuple[int, int]) -> np.ndarray:
    """Flat indices of the rays of an (..., H, W) batch regrouped into tile-sized packets,
    tile by tile; -1 marks padding where H or W is not a multiple of the tile."""
    if len(batch) < 2:
        raise ValueError(f"a (height, width) packet needs rays with at least 2 batch dimensions, got {batch}")
    *lead, h, w = batch
    th, tw = tile
    hp, wp = -(-h // th) * th, -(-w // tw) * tw
    idx = np.full((*lead, hp, wp), -1, np.int64)
    idx[..., :h, :w] = np.arange(int(np.prod(batch))).reshape(batch)
    nl = len(lead)
    idx = idx.reshape(*lead, hp // th, th, wp // tw, tw)
    axes = (*range(nl), nl, nl + 2, nl + 1, nl + 3)
    return idx.transpose(axes).reshape(-1)


def _prepare(origins, directions, tmin, tmax):
    """Flat rays in the caller's order. A bound given as a scalar stays a scalar: a backend
    broadcasts it where it needs one per ray (a gather of a broadcast constant, e.g. into tile
    order, is folded by XLA at compile time: seconds for a frame)."""
    origins = jnp.asarray(origins, jnp.float32)
    directions = jnp.asarray(directions, jnp.float32)
    if origins.shape[-1:] != (3,) or directions.shape[-1:] != (3,):
        raise ValueError(
            f"origins and directions must end in a dimension of 3, got {origins.shape} and {directions.shape}"
        )
    tmin, tmax = jnp.asarray(tmin, jnp.float32), jnp.asarray(tmax, jnp.float32)
    batch = jnp.broadcast_shapes(origins.shape[:-1], directions.shape[:-1], tmin.shape, tmax.shape)
    o = jnp.broadcast_to(origins, batch + (3,)).reshape(-1, 3)
    d = jnp.broadcast_to(directions, batch + (3,)).reshape(-1, 3)

    def flat(x):
        return x if x.ndim == 0 else jnp.broadcast_to(x, batch).reshape(-1)

    return batch, o, d, flat(tmin), flat(tmax)


def _per_ray(x, n):
    return jnp.broadcast_to(x, (n,)) if x.ndim == 0 else x


def hit_geometry(
    vertices: VerticesLike,
    faces: FacesLike,
    prim: Int[ArrayLike, "*batch"],
    origins: Float[ArrayLike, "*batch 3"],
    directions: Float[ArrayLike, "*batch 3"],
) -> tuple[Float[Array, "*batch"], Float[Array, "*batch"], Float[Array, "*batch"]]:
    """Differentiable (t, u, v) of rays against the faces `prim` (-1: miss → t = inf, u = v = 0).

    Möller–Trumbore in closed form: smooth in vertices, origins and directions. Visibility (which
    face was hit) is taken as given and not differentiated.

    The sums over the 3-vectors stay `jnp.sum` (a library kernel on XLA:CPU) although the same
    arithmetic written out per component ran faster in a frame: written out (even fenced by
    optimisation barriers), two frame programs that differ only in another region's texture
    level gave that region's samples differing in the last bit
    (tests/test_fidelity_texture_lod.py), and the per-region guarantees are bit-exact.
    """
    prim = jax.lax.stop_gradient(jnp.asarray(prim))
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


def _host_devices() -> list | None:
    """The CPU devices to split a ray batch over, or None to trace it in one program.

    XLA:CPU runs a program's traversal loop on one thread (measured: every fusion of the loop on
    one thread of its pool, and two independent loops in one program run one after the other), so
    the only way to a second core is a second device: with `JAX_NUM_CPU_DEVICES=2` (or
    `jax.config.update("jax_num_cpu_devices", 2)` before JAX starts) the rays are split over the
    host devices with `shard_map`, one traversal per device and core. A GPU's one program already
    fills the device, so nothing is split there.
    """
    devices = jax.devices()
    if len(devices) < 2 or devices[0].platform != "cpu":
        return None
    if not jax.sharding.get_abstract_mesh().empty:
        return None  # already inside a sharded program (e.g. frames over devices): its part stays whole
    return devices


def _split_over(devices, run, table, num_nodes, o, d, tmin, tmax, granule: int, *level):
    """`run(table, num_nodes, o, d, tmin, tmax[, level])` on equal parts of the rays, one per device.
    Each part is a multiple of `granule` rays (a packet), padded with empty rays."""
    from jax.sharding import Mesh
    from jax.sharding import PartitionSpec as P

    k = len(devices)
    n = o.shape[0]
    pad = (-n) % (k * granule)

    def padded(x, fill):
        return jnp.concatenate([x, jnp.full((pad,) + x.shape[1:], fill, x.dtype)]) if pad else x

    mesh = Mesh(np.array(devices), ("rays",))
    split = jax.shard_map(
        run,
        mesh=mesh,
        in_specs=(P(), P(), P("rays"), P("rays"), P("rays"), P("rays")) + (P("rays"),) * len(level),
        out_specs=(P("rays"), P("rays")),
        check_vma=False,
    )
    rest = tuple(padded(x, 0) for x in level)
    t, prim = split(
        table, num_nodes, padded(o, 0.0), padded(d, 0.0), padded(tmin, 0.0), padded(tmax, 0.0), *rest
    )
    return t[:n], prim[:n]


@functools.partial(
    jax.jit,
    static_argnames=(
        "backend",
        "any_hit",
        "packet_size",
        "traversal",
        "sort",
        "tile",
        "batch",
    ),
)
def _raw_query(
    bvh,
    o,
    d,
    tmin,
    tmax,
    level=None,
    *,
    backend,
    any_hit,
    packet_size,
    traversal,
    sort=False,
    tile=None,
    batch=None,
):
    """(t, prim, u, v) of flat rays in the caller's order (not differentiated: `closest_hit` adds
    the derivatives). `tmin`/`tmax`: per ray or scalars. `tile`:
    the rays are an image of `batch` traced as tile-sized packets (on the JAX traversal, which
    regroups them; native backends take image rows as they come)."""
    o, d = jax.lax.stop_gradient(o), jax.lax.stop_gradient(d)
    n = o.shape[0]
    order = None
    if sort and n > 0:
        # Regroup the rays by origin, trace them as packets, and put the results back.
        tmin, tmax = _per_ray(tmin, n), _per_ray(tmax, n)
        order = spatial_order(o, tmax > tmin)
        o, d, tmin, tmax = o[order], d[order], tmin[order], tmax[order]
        level = None if level is None else level[order]
    hits = _query_backend(
        bvh,
        o,
        d,
        tmin,
        tmax,
        level,
        backend=backend,
        any_hit=any_hit,
        packet_size=packet_size,
        traversal=traversal,
        tile=tile,
        batch=batch,
    )
    if order is None:
        return hits
    back = inverse_order(order)
    return tuple(x[back] for x in hits)


def _query_backend(
    bvh,
    o,
    d,
    tmin,
    tmax,
    level,
    *,
    backend,
    any_hit,
    packet_size,
    traversal,
    tile=None,
    batch=None,
):
    """The rays (in the order given) on the chosen backend and traversal (inside `_raw_query`'s
    jit); "auto" chooses per platform inside the program (`fovjax.native.internal.on_platforms`)."""
    kw = dict(any_hit=any_hit, packet_size=packet_size, traversal=traversal, tile=tile, batch=batch)
    if backend != "auto":
        return _run_backend(backend, bvh, o, d, tmin, tmax, level, split=True, **kw)
    on_cpu, on_cuda = resolve_backend("auto", "cpu"), resolve_backend("auto", "cuda")

    def branch(name, split):
        def run(o, d, tmin, tmax, *lv):
            return _run_backend(name, bvh, o, d, tmin, tmax, lv[0] if lv else None, split=split, **kw)

        return run

    args = (o, d, tmin, tmax) + (() if level is None else (level,))
    if on_cpu == on_cuda == "jax":
        return branch("jax", True)(*args)
    # The JAX traversal outside CPU never splits the rays over host devices.
    stage = on_platforms(
        branch("jax", False), cpu=branch(on_cpu, True), cuda=branch(on_cuda, False), derivatives=False
    )
    return stage(*args)


def _run_backend(
    backend,
    bvh,
    o,
    d,
    tmin,
    tmax,
    level,
    *,
    split,
    any_hit,
    packet_size,
    traversal,
    tile=None,
    batch=None,
):
    """(t, prim, u, v) of the rays on a registered backend; t, u, v recomputed in closed form
    where the backend returns the face only."""
    chosen = get_backend(backend)
    n = o.shape[0]
    if not chosen.scalar_bounds:
        tmin, tmax = _per_ray(tmin, n), _per_ray(tmax, n)
    options = QueryOptions(any_hit, packet_size, traversal, split, tile, batch)
    hits = chosen.query(bvh, RayBatch(o, d, tmin, tmax, level), options)
    if len(hits) == 4:
        return tuple(hits)
    t, prim = hits
    t, u, v = hit_geometry(bvh.vertices, bvh.faces, prim, o, d)
    return t, prim, u, v


def jax_traversal(bvh, rays: RayBatch, options: QueryOptions):
    """(t, prim) of the rays on the JAX traversal (`JaxBackend.query`)."""
    o, d, tmin, tmax, level = rays
    any_hit, packet_size, traversal, split, tile, batch = options
    n = o.shape[0]
    if tile is not None:
        return _tiled_jax(
            bvh,
            o,
            d,
            tmin,
            tmax,
            level,
            split=split,
            tile=tile,
            batch=batch,
            any_hit=any_hit,
            packet_size=packet_size,
            traversal=traversal,
        )
    tmin, tmax = _per_ray(tmin, n), _per_ray(tmax, n)
    stack_size = bvh.stack_size
    roots = bvh.roots

    def per_ray(table, num_nodes, o, d, tmin, tmax, root=None):
        nodes = Nodes(table, num_nodes, stack_size)
        return traverse(nodes, o, d, tmin, tmax, any_hit=any_hit, traversal=traversal, root=root)

    def packets_of(table, num_nodes, o, d, tmin, tmax, root=None):
        assert packet_size is not None  # only called for packets
        return traverse_packets(
            Nodes(table, num_nodes, stack_size),
            o,
            d,
            tmin,
            tmax,
            any_hit=any_hit,
            packet_size=packet_size,
            traversal=traversal,
            root=root,
        )

    def run(table, num_nodes, o, d, tmin, tmax, *level):
        if not level:
            if packet_size is None:
                return per_ray(table, num_nodes, o, d, tmin, tmax)
            return packets_of(table, num_nodes, o, d, tmin, tmax)
        root = jnp.asarray(roots, jnp.int32)[level[0]]
        if packet_size is None:
            return per_ray(table, num_nodes, o, d, tmin, tmax, root)
        return _mixed_packets(packets_of, per_ray, packet_size, table, num_nodes, o, d, tmin, tmax, root)

    level = () if level is None else (level,)
    devices = _host_devices() if split else None
    if devices is None:
        return run(bvh.table, bvh.num_nodes, o, d, tmin, tmax, *level)
    return _split_over(devices, run, bvh.table, bvh.num_nodes, o, d, tmin, tmax, packet_size or 1, *level)


def _tiled_jax(bvh, o, d, tmin, tmax, level, *, split, tile, batch, **kw):
    """The JAX traversal of an image of rays in tile-sized packets: the rays regrouped tile by
    tile (padding where the image is not a multiple of the tile: empty rays), traced, and the
    results put back in image order."""
    order = _tile_order(batch, tile)
    src = np.maximum(order, 0)
    pad = order < 0
    inverse = np.empty(o.shape[0], np.int64)
    inverse[order[~pad]] = np.flatnonzero(~pad)

    def regroup(x):  # a scalar bound needs no gather
        return jnp.full(order.shape, x) if x.ndim == 0 else x[src]

    o_t, d_t = o[src], jnp.where(pad[:, None], 0.0, d[src])
    tmin_t = regroup(tmin)
    tmax_t = jnp.where(pad, tmin_t, regroup(tmax))  # padding is never live (nor mixes levels)
    level_t = None if level is None else level[src]
    options = QueryOptions(kw["any_hit"], kw["packet_size"], kw["traversal"], split)
    t, prim = jax_traversal(bvh, RayBatch(o_t, d_t, tmin_t, tmax_t, level_t), options)
    return t[inverse], prim[inverse]


def _mixed_packets(packets_of, per_ray, p: int, table, num_nodes, o, d, tmin, tmax, root):
    """Packets whose live rays (tmax > tmin) all start at one root are traced as packets from
    it; the rays of the others (a packet straddling two levels) one by one, in a second
    traversal whose queue holds only them (the rest have tmax = tmin and cost nothing)."""
    n = o.shape[0]
    n_packets = -(-n // p)
    pad = n_packets * p - n
    live = jnp.pad(tmax > tmin, (0, pad)).reshape(n_packets, p)
    r = jnp.pad(root, (0, pad)).reshape(n_packets, p)
    hi = jnp.max(jnp.where(live, r, -1), axis=1)
    lo = jnp.min(jnp.where(live, r, jnp.iinfo(jnp.int32).max), axis=1)
    mixed = jnp.repeat(hi > lo, p)[:n]
    t_p, prim_p = packets_of(table, num_nodes, o, d, tmin, jnp.where(mixed, tmin, tmax), jnp.maximum(hi, 0))
    t_r, prim_r = per_ray(table, num_nodes, o, d, tmin, jnp.where(mixed, tmax, tmin), root)
    return jnp.where(mixed, t_r, t_p), jnp.where(mixed, prim_r, prim_p)


def _levels(bvh, level, batch):
    """The per-ray level as flat int32, clipped to the BVH's levels; None when not given."""
    if level is None:
        return None
    if bvh.roots is None:
        raise ValueError("level= needs a merged BVH (fovjax.trace.merge_bvhs); this one has one tree")
    lv = jnp.broadcast_to(jnp.asarray(level, jnp.int32), batch).reshape(-1)
    return jnp.clip(lv, 0, bvh.num_levels - 1)


def _query(
    bvh,
    origins,
    directions,
    tmin,
    tmax,
    *,
    any_hit,
    backend,
    packet,
    traversal,
    level=None,
):
    _check(backend, packet)
    if not isinstance(traversal, Traversal):
        raise TypeError(f"traversal must be a fovjax.trace.Traversal, got {type(traversal).__name__}")
    batch, o, d, tmin_f, tmax_f = _prepare(origins, directions, tmin, tmax)
    level = _levels(bvh, level, batch)
    tile = tuple(packet) if isinstance(packet, tuple | list) else None
    if tile is not None and len(batch) < 2:
        raise ValueError(f"a (height, width) packet needs rays with at least 2 batch dimensions, got {batch}")
    sort = packet == "sorted"
    packet_size = None if packet is None else SORTED_PACKET if sort else int(np.prod(packet))
    hits = _raw_query(
        bvh,
        o,
        d,
        tmin_f,
        tmax_f,
        level,
        backend=backend,
        any_hit=any_hit,
        packet_size=packet_size,
        traversal=traversal,
        sort=sort,
        tile=tile,
        batch=batch if tile is not None else None,
    )
    return batch, o, d, hits


@jax.custom_jvp
def _backend_geometry(vertices, faces, prim, o, d, t, u, v):
    """The backend's own (t, u, v) of the hit face, with the derivatives of `hit_geometry`: a
    native backend's distance and barycentrics need no recomputation, but the gradients are
    the same closed form whatever the backend."""
    return t, u, v


@_backend_geometry.defjvp
def _backend_geometry_jvp(primals, tangents):
    vertices, faces, prim, o, d, t, u, v = primals
    dvertices, _, _, do, dd, *_ = tangents
    _, out = jax.jvp(
        lambda vs, o, d: hit_geometry(vs, faces, prim, o, d),
        (jnp.asarray(vertices, jnp.float32), o, d),
        (dvertices, do, dd),
    )
    return (t, u, v), out


def closest_hit(
    bvh: BVH,
    origins: Float[ArrayLike, "*#batch 3"],
    directions: Float[ArrayLike, "*#batch 3"],
    tmin: float | Float[ArrayLike, "*#batch"] = 0.0,
    tmax: float | Float[ArrayLike, "*#batch"] = jnp.inf,
    *,
    backend: str = "auto",
    packet: Packet = None,
    vertices: Float[ArrayLike, "V 3"] | None = None,
    level: Int[ArrayLike, "*#batch"] | None = None,
    traversal: Traversal = DEFAULT_TRAVERSAL,
) -> Hit:
    """The nearest triangle hit by each ray with tmin < t < tmax.

    Any batch shape: `origins`, `directions`, `tmin` and `tmax` are JAX or NumPy arrays (or
    scalars for the bounds) that broadcast against each other, and the result has the broadcast
    batch shape. float32; jit-compatible (compiled once per batch shape, BVH and options).
    Directions need not be normalised (t is in units of the direction's length). Rays with a
    NaN/inf component or a zero direction miss.

    `packet` chooses the traversal: None traces every ray on its own (any rays); an int P groups
    consecutive rays into packets of P that share one traversal; a tile (h, w) does the same for
    h x w tiles of the last two batch dimensions (camera rays of an image); "sorted" regroups
    the rays by their origins first (a Morton order within blocks of 16384 rays) into packets
    of 64, for rays that are coherent but not in a coherent order (shadow rays from a list of
    surface points). Packets pay off for coherent rays only; results are identical either way.

    `t, u, v` are recomputed from the hit triangle's corners, so `jax.grad` flows to `origins`,
    `directions` and `vertices` (pass `vertices` to differentiate w.r.t. positions other than
    the build-time ones; traversal still uses the build-time geometry). Which triangle is hit
    (visibility) is not differentiated.

    `level` (a merged BVH, `merge_bvhs`): which of its trees each ray is traced against (int,
    broadcast against the batch; traced values, clipped to the trees); `prim` then indexes the
    merged faces. One traversal for any mix of levels; a packet whose rays are not all of one
    level has its rays traced one by one.

    `traversal`: the JAX traversal's tuning (`Traversal`: rays and packets in flight, steps
    between refills); the hits are the same whatever it is.
    """
    batch, o, d, (t_b, prim, u_b, v_b) = _query(
        bvh,
        origins,
        directions,
        tmin,
        tmax,
        any_hit=False,
        backend=backend,
        packet=packet,
        traversal=traversal,
        level=level,
    )
    if vertices is None:  # the build-time geometry the backend traced: its own t, u, v
        t, u, v = _backend_geometry(
            jnp.asarray(bvh.vertices, jnp.float32), bvh.faces, prim, o, d, t_b, u_b, v_b
        )
    else:
        t, u, v = hit_geometry(vertices, bvh.faces, prim, o, d)
    return Hit(*(x.reshape(batch) for x in (t, prim, u, v)))


def occluded(
    bvh: BVH,
    origins: Float[ArrayLike, "*#batch 3"],
    directions: Float[ArrayLike, "*#batch 3"],
    tmax: float | Float[ArrayLike, "*#batch"] = jnp.inf,
    *,
    tmin: float | Float[ArrayLike, "*#batch"] = 0.0,
    backend: str = "auto",
    packet: Packet = None,
    level: Int[ArrayLike, "*#batch"] | None = None,
    traversal: Traversal = DEFAULT_TRAVERSAL,
) -> Bool[Array, "..."]:
    """Whether anything lies on each ray with tmin < t < tmax (a shadow ray; stops at the
    first hit found, not the nearest). Options (`packet`, `level`, `traversal`) as for
    `closest_hit`."""
    batch, _, _, (_, prim, _, _) = _query(
        bvh,
        origins,
        directions,
        tmin,
        tmax,
        any_hit=True,
        backend=backend,
        packet=packet,
        traversal=traversal,
        level=level,
    )
    return (prim >= 0).reshape(batch)


def brute_force_closest_hit(
    vertices: VerticesLike,
    faces: FacesLike,
    origins: Float[ArrayLike, "*batch 3"],
    directions: Float[ArrayLike, "*batch 3"],
    tmin: float | Float[ArrayLike, "*batch"] = 0.0,
    tmax: float | Float[ArrayLike, "*batch"] = np.inf,
) -> tuple[Float[np.ndarray, " n"], Int[np.ndarray, " n"], Float[np.ndarray, "n F"]]:
    """Reference: every ray against every triangle, float64 Möller–Trumbore with an
    inclusive edge test, on the host. Returns (t, prim, t_all) with t = inf, prim = -1 on a
    miss and t_all the (rays, faces) distances (inf where a face is missed). For small meshes."""
    v = np.asarray(vertices, np.float64)[np.asarray(faces)]
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    n = o.shape[0]
    tmin = np.broadcast_to(np.reshape(np.asarray(tmin, np.float64), (-1, 1)), (n, 1))
    tmax = np.broadcast_to(np.reshape(np.asarray(tmax, np.float64), (-1, 1)), (n, 1))
    # Per component, (faces,) rows: the arithmetic of `np.cross` and of a sum over x, y, z.
    p0 = v[:, 0].T
    e1, e2 = (v[:, 1] - v[:, 0]).T, (v[:, 2] - v[:, 0]).T
    t_all = np.empty((n, v.shape[0]))
    if v.shape[0] == 0:  # no faces: every ray misses
        return np.full(n, np.inf), np.full(n, -1, np.int64), t_all
    # Rays in chunks, so the (rays, faces) temporaries stay in the cache.
    step = max(1, (1 << 16) // max(1, v.shape[0]))
    for lo in range(0, n, step):
        hi = min(n, lo + step)
        dx, dy, dz = (d[lo:hi, k, None] for k in range(3))
        with np.errstate(divide="ignore", invalid="ignore"):  # NaN where det == 0: not a hit
            px, py, pz = dy * e2[2] - dz * e2[1], dz * e2[0] - dx * e2[2], dx * e2[1] - dy * e2[0]
            det = e1[0] * px + e1[1] * py + e1[2] * pz
            inv = 1.0 / det
            tx, ty, tz = (o[lo:hi, k, None] - p0[k] for k in range(3))
            u = (tx * px + ty * py + tz * pz) * inv
            qx, qy, qz = ty * e1[2] - tz * e1[1], tz * e1[0] - tx * e1[2], tx * e1[1] - ty * e1[0]
            w = (dx * qx + dy * qy + dz * qz) * inv
            t = (e2[0] * qx + e2[1] * qy + e2[2] * qz) * inv
            ok = (det != 0) & (u >= 0) & (w >= 0) & (u + w <= 1) & (t > tmin[lo:hi]) & (t < tmax[lo:hi])
        t_all[lo:hi] = np.where(ok, t, np.inf)
    prim = np.argmin(t_all, axis=1)
    tbest = t_all[np.arange(n), prim]
    prim = np.where(np.isfinite(tbest), prim, -1)
    return tbest, prim, t_all
