"""Ray traversal in JAX: a hand-written batched wavefront under `lax.while_loop`.

Every ray holds one "item" (an inner node or a triangle row of `BVH.table`) and a private
stack. One step gathers each ray's row (64 bytes), and
- at a node (4-wide, `_wide.py`): decodes its four child boxes (8-bit, quantised relative to
  the node's own box, stored in the node's row), slab-tests all four, goes to the nearest hit
  child and pushes the other hit children with their entry distances, farthest deepest (a
  popped entry whose box starts beyond the best hit so far is dropped without a table access);
- at a triangle: runs the watertight test (Woop, Benthin & Wald 2013) and moves to the next
  triangle of the leaf or pops the stack.
Both interpretations of the row are computed for every ray and the right one is selected: on
a SIMD machine the arithmetic is cheap next to the gather, and one row per step keeps every
ray's step identical.

Rays that finish early would otherwise idle in their lanes, so a fixed number of lanes is in
flight and finished lanes take the next ray from a queue of live rays (`traverse`): lanes stay
full until the queue runs dry, with one loop body and static shapes.

The traversal is not differentiated (reverse mode does not pass through `while_loop`); callers
recompute the hit from the triangle's vertices (`hit_geometry`).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, ArrayLike, Float, Int

F32_EPS = float(np.finfo(np.float32).eps) / 2
GAMMA3 = 3 * F32_EPS / (1 - 3 * F32_EPS)
# Conservative slab test (Ize 2013, PBRT 3.9.2): rounding never drops a box the ray touches.
BOX_FAR_SCALE = 1.0 + 2.0 * GAMMA3

# Relative size under which an edge function counts as zero (see _watertight): 8 ulps.
EDGE_ULPS = 8 * float(np.finfo(np.float32).eps)

ITEM_DONE = -1
ITEM_POP = -2

# Traversal tuning, measured with benchmarks/trace_throughput.py on a 2-core CPU: rays (or
# packets) in flight, and traversal steps between refills of finished lanes.
DEFAULT_LANES = 1 << 14
DEFAULT_PACKETS = 256
DEFAULT_STEPS_PER_REFILL = 4


@dataclasses.dataclass(frozen=True)
class Traversal:
    """How the JAX traversal runs (`backend="jax"`, or "auto" where no native backend is
    available): its tuning, not its results (the hits are the same whatever the values).
    Hashable: each distinct value is its own compiled program.

    - `lanes`: rays in flight when rays are traced one by one (fewer for small batches);
    - `packets`: packets in flight when rays are traced in packets (`packet=`);
    - `steps_per_refill`: traversal steps between refills of the lanes whose ray finished.
    """

    lanes: int = DEFAULT_LANES
    packets: int = DEFAULT_PACKETS
    steps_per_refill: int = DEFAULT_STEPS_PER_REFILL

    def __post_init__(self):
        for name in ("lanes", "packets", "steps_per_refill"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ValueError(f"Traversal.{name} must be a positive int, got {value!r}")
            object.__setattr__(self, name, int(value))


class Nodes(NamedTuple):
    """What the traversal reads of a `BVH`: its table of rows, the number of inner-node rows
    (the rows after them are triangles) and the depth of a ray's stack (static)."""

    table: Int[ArrayLike, "R 16"]
    num_nodes: Int[ArrayLike, ""]
    stack_size: int


def _ray_setup(o, d):
    """Per-ray constants of the slab and watertight tests."""
    valid = jnp.all(jnp.isfinite(o), -1) & jnp.all(jnp.isfinite(d), -1) & jnp.any(d != 0, -1)
    o = jnp.where(valid[:, None], o, 0.0)
    d = jnp.where(valid[:, None], d, 1.0)
    # A zero component gives an infinite slab parameter; a tiny stand-in keeps 0 * inf out.
    inv_d = 1.0 / jnp.where(d == 0, jnp.float32(1e-37), d)
    kz = jnp.argmax(jnp.abs(d), axis=-1).astype(jnp.int32)
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    dz = jnp.take_along_axis(d, kz[:, None], 1)[:, 0]
    # Swap x and y when the dominant component is negative: keeps the winding consistent.
    kx, ky = jnp.where(dz < 0, ky, kx), jnp.where(dz < 0, kx, ky)
    dx = jnp.take_along_axis(d, kx[:, None], 1)[:, 0]
    dy = jnp.take_along_axis(d, ky[:, None], 1)[:, 0]
    shear = jnp.stack([dx / dz, dy / dz, 1.0 / dz], axis=-1)
    return valid, o, inv_d, jnp.stack([kx, ky, kz], -1), shear


def _fmin(a, b):
    """min(a, b) as one compare and select: XLA's `minimum` also propagates NaN, which costs
    extra instructions per call; the traversal's distances are never NaN (see `_ray_setup`)."""
    return jnp.where(a < b, a, b)


def _fmax(a, b):
    """max(a, b) as one compare and select (see `_fmin`)."""
    return jnp.where(a > b, a, b)


def _xyz(x, i, axis):
    """Component i of x, whose xyz run along `axis`."""
    return x[..., i] if axis == -1 else lax.index_in_dim(x, i, axis=axis, keepdims=False)


def _pick(x, k, axis=-1):
    """x's component k for a per-ray component index k, as selects (no gather)."""
    return jnp.where(k == 0, _xyz(x, 0, axis), jnp.where(k == 1, _xyz(x, 1, axis), _xyz(x, 2, axis)))


def _watertight(v0, v1, v2, o, perm, shear, axis=-1):
    """Woop-Benthin-Wald watertight ray/triangle test. Returns the hit distance t, inf on a miss.
    xyz run along `axis` of every argument (the last by default).

    One array out (not a hit flag and a distance): XLA:CPU materialises it once, where a flag
    and a distance were each re-derived from the edge functions by their consumers."""
    kx, ky, kz = (_xyz(perm, i, axis) for i in range(3))
    sx, sy, sz = (_xyz(shear, i, axis) for i in range(3))
    a, b, c = v0 - o, v1 - o, v2 - o
    az, bz, cz = _pick(a, kz, axis), _pick(b, kz, axis), _pick(c, kz, axis)
    ax = _pick(a, kx, axis) - sx * az
    ay = _pick(a, ky, axis) - sy * az
    bx = _pick(b, kx, axis) - sx * bz
    by = _pick(b, ky, axis) - sy * bz
    cx = _pick(c, kx, axis) - sx * cz
    cy = _pick(c, ky, axis) - sy * cz
    # Edge functions. In exact float arithmetic a shared edge gives exactly opposite values in
    # its two triangles, which is what makes the test watertight. A compiler may contract
    # x*y - z*w into an FMA (XLA:CPU does inside fused loops), which breaks that symmetry by an
    # ulp or so and opens pinholes along shared edges. So values within a few ulps of the
    # products count as on the edge: both neighbours accept such a ray, none misses it.
    u = cx * by - cy * bx
    v = ax * cy - ay * cx
    w = bx * ay - by * ax
    u_s = jnp.where(jnp.abs(u) <= EDGE_ULPS * (jnp.abs(cx * by) + jnp.abs(cy * bx)), 0.0, u)
    v_s = jnp.where(jnp.abs(v) <= EDGE_ULPS * (jnp.abs(ax * cy) + jnp.abs(ay * cx)), 0.0, v)
    w_s = jnp.where(jnp.abs(w) <= EDGE_ULPS * (jnp.abs(bx * ay) + jnp.abs(by * ax)), 0.0, w)
    outside = ((u_s < 0) | (v_s < 0) | (w_s < 0)) & ((u_s > 0) | (v_s > 0) | (w_s > 0))
    det = u + v + w
    t_scaled = u * (sz * az) + v * (sz * bz) + w * (sz * cz)
    t = t_scaled / jnp.where(det == 0, 1.0, det)
    return jnp.where(~outside & (det != 0), t, jnp.inf)


def _decode_boxes(row):
    """A wide node's four quantised child boxes: per axis (lo, hi), each row.shape[:-1] + (4,)."""
    origin = lax.bitcast_convert_type(row[..., 0:3], jnp.float32)
    shifts = jnp.arange(4, dtype=jnp.int32) * 8
    boxes = []
    for axis in range(3):
        scale_bits = ((row[..., 3] >> (8 * axis)) & 255) << 23
        scale = lax.bitcast_convert_type(scale_bits, jnp.float32)[..., None]
        q_lo = ((row[..., 4 + 2 * axis, None] >> shifts) & 255).astype(jnp.float32)
        q_hi = ((row[..., 5 + 2 * axis, None] >> shifts) & 255).astype(jnp.float32)
        base = origin[..., axis, None]
        boxes.append((base + q_lo * scale, base + q_hi * scale))
    return boxes


def _slab4(boxes, o, inv_d, axis_dim=-1):
    """Entry/exit distances of rays (o, inv_d: xyz along `axis_dim`, (..., 3) by default) through
    boxes broadcast against (..., 4)."""
    t_lo, t_hi = [], []
    for axis, (lo, hi) in enumerate(boxes):
        oa, ia = _xyz(o, axis, axis_dim), _xyz(inv_d, axis, axis_dim)
        if axis_dim == -1:
            oa, ia = oa[..., None], ia[..., None]
        t0 = (lo - oa) * ia
        t1 = (hi - oa) * ia
        t_lo.append(_fmin(t0, t1))
        t_hi.append(_fmax(t0, t1))
    t_near = _fmax(_fmax(t_lo[0], t_lo[1]), t_lo[2])
    t_far = _fmin(_fmin(t_hi[0], t_hi[1]), t_hi[2]) * BOX_FAR_SCALE
    return t_near, t_far


def _sort4(keys, vals):
    """Sort four (W,) key columns ascending, carrying values (a 5-comparator network)."""
    keys, vals = list(keys), list(vals)
    for i, j in ((0, 1), (2, 3), (0, 2), (1, 3), (1, 2)):
        swap = keys[j] < keys[i]
        keys[i], keys[j] = jnp.where(swap, keys[j], keys[i]), jnp.where(swap, keys[i], keys[j])
        vals[i], vals[j] = jnp.where(swap, vals[j], vals[i]), jnp.where(swap, vals[i], vals[j])
    return keys, vals


def _visit(table, num_nodes, rays, cur, t_limit):
    """The row each lane visits, read as a 4-wide node and as a triangle (the two steps share it):
    (active, is_node, the row, child ids, entry distance of each child (inf where the ray misses it or
    enters beyond `t_limit`), the triangle's hit distance (inf where there is none)), both
    distances materialised once (see `_step`)."""
    o, inv_d, perm, shear, tmin = rays
    active = cur >= 0
    # Lanes with nothing to do read row 0, which stays in cache.
    row = table[jnp.maximum(cur, 0)]
    is_node = cur < num_nodes
    t_near, t_far = _slab4(_decode_boxes(row), o, inv_d)
    t_near = _fmax(t_near, tmin[:, None])
    t_far = _fmin(t_far, t_limit[:, None])
    child = row[:, 10:14]
    key = jnp.where((t_near <= t_far) & (child >= 0), t_near, jnp.inf)
    f = lax.bitcast_convert_type(row[:, :9], jnp.float32)
    t_t = _watertight(f[:, 0:3], f[:, 3:6], f[:, 6:9], o, perm, shear)
    t_tri = jnp.where(active & ~is_node & (t_t > tmin) & (t_t < t_limit), t_t, jnp.inf)
    key, t_tri = lax.optimization_barrier((key, t_tri))
    return active, is_node, row, child, key, t_tri


def _step(table, num_nodes, stack_size, any_hit, rays, state):
    """One traversal step for every lane.

    `lax.optimization_barrier` marks where intermediate arrays must be materialised: without
    them XLA:CPU re-derives the child-box decode inside every consumer kernel (eight copies,
    ~4x the step time, measured with jax.profiler).
    """
    barrier = lax.optimization_barrier
    # A step is a unit: nothing is fused across its start (it would be recomputed per consumer).
    rays, state = barrier((rays, state))
    cur, sp, stack, t_best, prim = state
    w = cur.shape[0]
    lane = jnp.arange(w)

    active, is_node, row, child, key, t_tri = _visit(table, num_nodes, rays, cur, t_best)

    keys, items = _sort4([key[:, c] for c in range(4)], [child[:, c] for c in range(4)])
    # (w, 4, 2): sorted (item, entry-distance bits) pairs, the stack's entry format.
    sorted_kv = barrier(
        jnp.stack(
            [
                jnp.stack([i, lax.bitcast_convert_type(k, jnp.int32)], -1)
                for i, k in zip(items, keys, strict=True)
            ],
            1,
        )
    )
    n_hit = jnp.sum(jnp.isfinite(jnp.stack(keys, 1)), axis=1).astype(jnp.int32)

    # The triangle test is materialised once, as the new best distance; its other consumers
    # read whether it improved (t_tri < t_best by construction) instead of recomputing it.
    t_new = barrier(_fmin(t_tri, t_best))
    found = t_new < t_best
    t_best = t_new
    prim = jnp.where(found, row[:, 9], prim)
    node_next = jnp.where(n_hit > 0, sorted_kv[:, 0, 0], ITEM_POP)
    tri_next = jnp.where(row[:, 10] != 0, ITEM_POP, cur + 1)
    nxt = jnp.where(is_node, node_next, tri_next)
    if any_hit:
        nxt = jnp.where(found, ITEM_DONE, nxt)

    # Push the other hit children, farthest deepest, so the nearest is popped first.
    at_node = active & is_node
    n_push = jnp.where(at_node, jnp.maximum(n_hit - 1, 0), 0)
    pos = jnp.stack([jnp.where(j <= n_push, sp + n_push - j, stack_size) for j in (1, 2, 3)], 1)
    stack = stack.at[pos, lane[:, None]].set(sorted_kv[:, 1:], mode="drop")
    sp = sp + n_push
    cur = jnp.where(active, nxt, cur)
    cur, sp, t_best, prim = barrier((cur, sp, t_best, prim))

    # Resolve pops last: the stack is read only after this step's pushes, so XLA updates it in
    # place. An entry whose box starts beyond the best hit so far is dropped without a table
    # access; up to two per step.
    for _ in range(2):
        popping = cur == ITEM_POP
        has = sp > 0
        top = jnp.maximum(sp - 1, 0)
        entry = stack[top, lane]
        item, t_entry = entry[:, 0], lax.bitcast_convert_type(entry[:, 1], jnp.float32)
        sp = sp - (popping & has).astype(jnp.int32)
        live = jnp.where(t_entry < t_best, item, ITEM_POP)
        cur = jnp.where(popping, jnp.where(has, live, ITEM_DONE), cur)
    return cur, sp, stack, t_best, prim


def _step_any(table, num_nodes, stack_size, any_hit, rays, state):
    """One any-hit traversal step for every lane (`occluded`): `_step` without the sorting.

    A lane stops at its first hit, so there is no best distance to shrink: the nearest child
    the ray enters is still visited next (three comparisons; visiting children in their stored
    order instead took 2-5x the steps), but the other entered children are pushed in stored
    order, which replaces the sorting network, and the stack holds bare items (an entry is
    never culled: the ray's interval does not shrink). One pop per step (every entry is live).

    The triangle test is materialised once, as the carried distance `t_new`, and the other
    consumers read whether it shrank: given to them as a boolean, XLA:CPU re-derived the whole
    test inside each consumer. Likewise the nearest child is picked with selects, not a gather
    (a gather fused the box tests into itself).
    """
    del any_hit
    barrier = lax.optimization_barrier
    rays, state = barrier((rays, state))
    cur, sp, stack, t_max, prim = state
    w = cur.shape[0]
    lane = jnp.arange(w)

    active, is_node, row, child, key, t_tri = _visit(table, num_nodes, rays, cur, t_max)
    # Materialised once as the carried distance (see `_step`); consumers compare with it.
    t_new = barrier(_fmin(t_tri, t_max))
    found = t_new < t_max

    # The nearest entered child is visited next; the others are pushed in slot order.
    k = [key[:, c] for c in range(4)]
    near01 = k[1] < k[0]
    near23 = k[3] < k[2]
    k01 = jnp.minimum(k[0], k[1])
    k23 = jnp.minimum(k[2], k[3])
    s01 = jnp.where(near01, 1, 0)
    s23 = jnp.where(near23, 3, 2)
    nearest = jnp.where(k23 < k01, s23, s01)
    counts = [(jnp.isfinite(k[c]) & (nearest != c)).astype(jnp.int32) for c in range(4)]
    ranks = [counts[0]]
    for c in range(1, 4):
        ranks.append(ranks[-1] + counts[c])
    n_push = ranks[3]
    has_hit = jnp.isfinite(jnp.minimum(k01, k23))
    first = jnp.where(
        nearest == 0,
        child[:, 0],
        jnp.where(nearest == 1, child[:, 1], jnp.where(nearest == 2, child[:, 2], child[:, 3])),
    )
    at_node = active & is_node
    pos = jnp.stack(
        [jnp.where(at_node & (counts[c] > 0), sp + ranks[c] - 1, stack_size) for c in range(4)], 1
    )
    pos, first, n_push, has_hit = barrier((pos, first, n_push, has_hit))
    stack = stack.at[pos, lane[:, None]].set(child, mode="drop")
    sp = sp + jnp.where(at_node, n_push, 0)

    prim = jnp.where(found, row[:, 9], prim)
    node_next = jnp.where(has_hit, first, ITEM_POP)
    tri_next = jnp.where(row[:, 10] != 0, ITEM_POP, cur + 1)
    nxt = jnp.where(found, ITEM_DONE, jnp.where(is_node, node_next, tri_next))
    cur = jnp.where(active, nxt, cur)
    cur, sp, prim = barrier((cur, sp, prim))

    # Pop after pushing (in place); one pop per step, every entry is live.
    popping = cur == ITEM_POP
    has = sp > 0
    item = stack[jnp.maximum(sp - 1, 0), lane]
    sp = sp - (popping & has).astype(jnp.int32)
    cur = jnp.where(popping, jnp.where(has, item, ITEM_DONE), cur)
    return cur, sp, stack, t_new, prim


def live_first(live):
    """(number live, queue): a stable permutation of the indices with the live ones first."""
    live = live.astype(jnp.int32)
    n_live = jnp.sum(live)
    rank = jnp.where(live > 0, jnp.cumsum(live) - 1, n_live + jnp.cumsum(1 - live) - 1)
    queue = jnp.zeros_like(rank).at[rank].set(jnp.arange(live.shape[0], dtype=rank.dtype))
    return n_live, queue


def lanes_for(n: int, lanes: int, floor: int = 256) -> int:
    """Lanes in flight for n rays: at most `lanes`, and few enough that each lane traces ~16
    rays, so the tail (the last rays finishing while the queue is empty) stays a small part."""
    target = 1 << max(int(np.log2(max(n, 1) / 16)), 0)
    return int(min(lanes, max(floor, target)))


def _run_steps(step, table, num_nodes, stack_size, any_hit, rays, state, count, like):
    """`count` steps, each its own while-loop iteration.

    A loop iteration is a hard boundary for XLA's fusion; unrolled steps were fused across
    (optimization barriers are expanded before fusion on XLA:CPU), and then every consumer
    re-derived its inputs from earlier steps. The trip count is a traced value so XLA does not
    unroll the loop either.
    """
    count = jnp.asarray(count, jnp.int32) + jnp.zeros_like(like, jnp.int32)

    def body(c):
        i, st = c
        return i + 1, step(table, num_nodes, stack_size, any_hit, rays, st)

    return lax.while_loop(lambda c: c[0] < count, body, (jnp.int32(0), state))[1]


def traverse(
    nodes: Nodes,
    o: Float[Array, "n 3"],
    d: Float[Array, "n 3"],
    tmin: Float[Array, " n"],
    tmax: Float[Array, " n"],
    *,
    any_hit: bool,
    traversal: Traversal,
    root: Int[Array, " n"] | None = None,
) -> tuple[Float[Array, " n"], Int[Array, " n"]]:
    """Trace flat rays o, d (n, 3) with per-ray tmin, tmax (n,). Returns (t, prim), t = tmax on a miss.
    `root` (n,) int32: the item each ray starts at (a merged BVH's level roots); None: item 0.

    A fixed set of `traversal.lanes` rays is in flight; every `traversal.steps_per_refill`
    steps, lanes whose ray has
    finished write its result and take the next ray from the queue (in input order, so
    neighbouring lanes trace neighbouring rays). One loop body, one compiled program, full lanes
    until the queue runs dry.

    The queue holds only live rays (finite, non-zero direction, tmax > tmin), so a caller marks
    rays it does not want traced with tmax <= tmin and they cost nothing: this is the
    compaction foveation relies on, with static array shapes and no bucket sizes.
    """
    table, num_nodes, stack_size = nodes
    n = o.shape[0]
    w = lanes_for(n, traversal.lanes)
    valid, o_all, inv_d_all, perm_all, shear_all = _ray_setup(o, d)
    valid = valid & (tmax > tmin)
    all_rays = (o_all, inv_d_all, perm_all, shear_all, tmin)
    n_live, queue = live_first(valid)

    lane_ray = jnp.full(w, n, jnp.int32)  # n = no ray
    rays = jax.tree.map(lambda x: jnp.zeros((w,) + x.shape[1:], x.dtype), all_rays)
    state = (
        jnp.full(w, ITEM_DONE, jnp.int32),
        jnp.zeros(w, jnp.int32),
        jnp.zeros((stack_size, w) if any_hit else (stack_size, w, 2), jnp.int32),
        jnp.zeros(w, jnp.float32),
        jnp.full(w, -1, jnp.int32),
    )
    out_t = tmax
    out_prim = jnp.full(n, -1, jnp.int32)

    def write_back(lane_ray, state, out_t, out_prim):
        cur, _, _, t_best, prim = state
        dst = jnp.where(cur == ITEM_DONE, lane_ray, n)  # n is out of range: dropped
        return out_t.at[dst].set(t_best, mode="drop"), out_prim.at[dst].set(prim, mode="drop")

    def cond(carry):
        next_ray, _, _, state, _, _ = carry
        return (next_ray < n_live) | jnp.any(state[0] != ITEM_DONE)

    def body(carry):
        next_ray, lane_ray, rays, state, out_t, out_prim = carry
        out_t, out_prim = write_back(lane_ray, state, out_t, out_prim)
        cur, sp, stack, t_best, prim = state
        idle = cur == ITEM_DONE
        new = next_ray + jnp.cumsum(idle.astype(jnp.int32)) - 1
        take = idle & (new < n_live)
        src = jnp.where(take, queue[jnp.minimum(new, n - 1)], 0)
        lane_ray = jnp.where(take, src, jnp.where(idle, n, lane_ray))
        rays = jax.tree.map(
            lambda lane_x, all_x: jnp.where(
                take.reshape((w,) + (1,) * (lane_x.ndim - 1)), all_x[src], lane_x
            ),
            rays,
            all_rays,
        )
        cur = jnp.where(take, 0 if root is None else root[src], cur)
        sp = jnp.where(take, 0, sp)
        t_best = jnp.where(take, tmax[src], t_best)
        prim = jnp.where(take, -1, prim)
        next_ray = jnp.minimum(next_ray + jnp.sum(idle.astype(jnp.int32)), n_live)
        state = (cur, sp, stack, t_best, prim)
        state = _run_steps(
            _step_any if any_hit else _step,
            table,
            num_nodes,
            stack_size,
            any_hit,
            rays,
            state,
            traversal.steps_per_refill,
            next_ray,
        )
        return next_ray, lane_ray, rays, state, out_t, out_prim

    carry = (jnp.int32(0), lane_ray, rays, state, out_t, out_prim)
    _, lane_ray, _, state, out_t, out_prim = lax.while_loop(cond, body, carry)
    out_t, out_prim = write_back(lane_ray, state, out_t, out_prim)
    return out_t, out_prim
