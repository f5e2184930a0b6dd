"""Packet traversal for coherent rays (camera rays of an image tile, shadow rays from a tile).

A packet of P consecutive rays walks the BVH together: one table row per packet and step, one
stack per packet, and every per-ray test is dense arithmetic over the packet (no per-ray gather,
no per-ray stack). A packet visits a child box when any of its live rays enters it before its
own best hit, in the order of the packet's nearest entry. Rays that disagree cost extra steps,
so this pays only when consecutive rays are coherent; the caller decides (`packet_size`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, Float, Int

from ._traverse import (
    ITEM_DONE,
    ITEM_POP,
    Nodes,
    Traversal,
    _decode_boxes,
    _fmax,
    _fmin,
    _ray_setup,
    _run_steps,
    _slab4,
    _sort4,
    _watertight,
    lanes_for,
    live_first,
)


def _load(table, cur):
    """Each packet's row (K, 16) and, decoded, its child boxes (K, 6, 4): per axis lo, hi."""
    row = table[jnp.maximum(cur, 0)]
    boxes = jnp.stack([b for lo_hi in _decode_boxes(row) for b in lo_hi], 1)
    return row, boxes


def _packet_step(table, num_nodes, stack_size, any_hit, rays, state):
    """One step of every packet. The packet's row and decoded child boxes come with the state
    (loaded at the end of the previous step): carried through the loop, they are materialised
    once per packet, where decoding inside the step was fused into the per-ray box test and
    repeated for each of the packet's rays (seen in the optimised HLO of the loop body)."""
    barrier = lax.optimization_barrier
    rays, state = barrier((rays, state))
    o, inv_d, perm, shear, tmin = rays  # (K, 3, P) and tmin (K, P): rays minor
    cur, sp, stack, t_best, prim, done, row, box = state
    k = cur.shape[0]
    packet = jnp.arange(k)

    # Rays that may still gain a hit: not finished (any-hit) and valid.
    t_limit = jnp.where(done, -jnp.inf, t_best)
    active = cur >= 0
    is_node = cur < num_nodes

    # Children before rays, (K, 4, P): the packet's minimum runs over the contiguous axis.
    boxes = [(box[:, 2 * a, :, None], box[:, 2 * a + 1, :, None]) for a in range(3)]  # (K, 4, 1)
    t_near, t_far = _slab4(boxes, o[:, None], inv_d[:, None], axis_dim=-2)  # (K, 4, P)
    t_near = _fmax(t_near, tmin[:, None, :])
    t_far = _fmin(t_far, t_limit[:, None, :])
    child = row[:, 10:14]
    ray_key = jnp.where(t_near <= t_far, t_near, jnp.inf)
    key = jnp.where(child >= 0, jnp.min(ray_key, axis=2), jnp.inf)  # (K, 4): packet entry distance

    f = lax.bitcast_convert_type(row[:, :9], jnp.float32)[:, :, None]  # (K, 9, 1)
    t_t = _watertight(f[:, 0:3], f[:, 3:6], f[:, 6:9], o, perm, shear, axis=1)  # (K, P)
    tri_lane = (active & ~is_node)[:, None]
    t_tri = jnp.where(tri_lane & (t_t > tmin) & (t_t < t_limit), t_t, jnp.inf)
    key, t_tri = barrier((key, t_tri))

    keys, items = _sort4([key[:, c] for c in range(4)], [child[:, c] for c in range(4)])
    sorted_kv = barrier(
        jnp.stack(
            [
                jnp.stack([i, lax.bitcast_convert_type(t, jnp.int32)], -1)
                for i, t in zip(items, keys, strict=True)
            ],
            1,
        )
    )
    n_hit = jnp.sum(jnp.isfinite(jnp.stack(keys, 1)), axis=1).astype(jnp.int32)

    # Materialised once (see _traverse._step): the consumers read whether the best improved.
    t_new = barrier(_fmin(t_tri, t_best))
    found = t_new < t_best
    t_best = t_new
    prim = jnp.where(found, row[:, None, 9], prim)
    if any_hit:
        done = done | found
    node_next = jnp.where(n_hit > 0, sorted_kv[:, 0, 0], ITEM_POP)
    tri_next = jnp.where(row[:, 10] != 0, ITEM_POP, cur + 1)
    nxt = jnp.where(is_node, node_next, tri_next)
    if any_hit:
        nxt = jnp.where(jnp.all(done, axis=1), ITEM_DONE, nxt)

    at_node = active & is_node
    n_push = jnp.where(at_node, jnp.maximum(n_hit - 1, 0), 0)
    pos = jnp.stack([jnp.where(j <= n_push, sp + n_push - j, stack_size) for j in (1, 2, 3)], 1)
    stack = stack.at[pos, packet[:, None]].set(sorted_kv[:, 1:], mode="drop")
    sp = sp + n_push
    cur = jnp.where(active, nxt, cur)
    cur, sp, t_best, prim, done = barrier((cur, sp, t_best, prim, done))

    # Pop after pushing (in-place stack update); skip entries no live ray can still use.
    reach = jnp.max(jnp.where(done, -jnp.inf, t_best), axis=1)
    for _ in range(2):
        popping = cur == ITEM_POP
        has = sp > 0
        top = jnp.maximum(sp - 1, 0)
        entry = stack[top, packet]
        item, t_entry = entry[:, 0], lax.bitcast_convert_type(entry[:, 1], jnp.float32)
        sp = sp - (popping & has).astype(jnp.int32)
        live = jnp.where(t_entry < reach, item, ITEM_POP)
        cur = jnp.where(popping, jnp.where(has, live, ITEM_DONE), cur)
    return (cur, sp, stack, t_best, prim, done, *_load(table, cur))


def traverse_packets(
    nodes: Nodes,
    o: Float[Array, "n 3"],
    d: Float[Array, "n 3"],
    tmin: Float[Array, " n"],
    tmax: Float[Array, " n"],
    *,
    any_hit: bool,
    packet_size: int,
    traversal: Traversal,
    root: Int[Array, " n_packets"] | None = None,
) -> tuple[Float[Array, " n"], Int[Array, " n"]]:
    """Like `traverse`, for rays grouped into packets of `packet_size` consecutive rays, with
    `traversal.packets` packets in flight. Returns (t, prim), t = tmax on a miss. `root`
    (n_packets,) int32: the item each packet starts at (None: item 0)."""
    table, num_nodes, stack_size = nodes
    n = o.shape[0]
    p = int(packet_size)
    n_packets = -(-n // p)
    pad = n_packets * p - n

    def padded(x, fill):
        return jnp.concatenate([x, jnp.full((pad,) + x.shape[1:], fill, x.dtype)]) if pad else x

    valid, o_all, inv_d_all, perm_all, shear_all = _ray_setup(padded(o, 0.0), padded(d, 0.0))
    tmin_all, tmax_all = padded(tmin, 0.0), padded(tmax, 0.0)
    valid = valid & (tmax_all > tmin_all)
    group = lambda x: x.reshape((n_packets, p) + x.shape[1:])  # noqa: E731
    # Per packet (3, P): each component's rays contiguous, the axis the packet's tests run along.
    minor = lambda x: jnp.swapaxes(group(x), 1, 2)  # noqa: E731
    all_rays = (*map(minor, (o_all, inv_d_all, perm_all, shear_all)), group(tmin_all))
    valid, tmax_all = group(valid), group(tmax_all)

    k = lanes_for(n_packets, traversal.packets, floor=16)
    # Only packets with a live ray are queued (see `traverse`).
    n_live, queue = live_first(jnp.any(valid, axis=1))
    lane_packet = jnp.full(k, n_packets, jnp.int32)
    rays = jax.tree.map(lambda x: jnp.zeros((k,) + x.shape[1:], x.dtype), all_rays)
    state = (
        jnp.full(k, ITEM_DONE, jnp.int32),
        jnp.zeros(k, jnp.int32),
        jnp.zeros((stack_size, k, 2), jnp.int32),
        jnp.zeros((k, p), jnp.float32),
        jnp.full((k, p), -1, jnp.int32),
        jnp.ones((k, p), bool),
    )
    state = (*state, *_load(table, state[0]))
    out_t = tmax_all
    out_prim = jnp.full((n_packets, p), -1, jnp.int32)

    def write_back(lane_packet, state, out_t, out_prim):
        cur, t_best, prim = state[0], state[3], state[4]
        dst = jnp.where(cur == ITEM_DONE, lane_packet, n_packets)
        return out_t.at[dst].set(t_best, mode="drop"), out_prim.at[dst].set(prim, mode="drop")

    def cond(carry):
        next_packet, _, _, state, _, _ = carry
        return (next_packet < n_live) | jnp.any(state[0] != ITEM_DONE)

    def body(carry):
        next_packet, lane_packet, rays, state, out_t, out_prim = carry
        out_t, out_prim = write_back(lane_packet, state, out_t, out_prim)
        cur, sp, stack, t_best, prim, done = state[:6]
        idle = cur == ITEM_DONE
        new = next_packet + jnp.cumsum(idle.astype(jnp.int32)) - 1
        take = idle & (new < n_live)
        src = jnp.where(take, queue[jnp.minimum(new, n_packets - 1)], 0)
        lane_packet = jnp.where(take, src, jnp.where(idle, n_packets, lane_packet))
        rays = jax.tree.map(
            lambda lane_x, all_x: jnp.where(
                take.reshape((k,) + (1,) * (lane_x.ndim - 1)), all_x[src], lane_x
            ),
            rays,
            all_rays,
        )
        ray_ok = valid[src]
        cur = jnp.where(take, 0 if root is None else root[src], cur)
        sp = jnp.where(take, 0, sp)
        t_best = jnp.where(take[:, None], tmax_all[src], t_best)
        prim = jnp.where(take[:, None], -1, prim)
        done = jnp.where(take[:, None], ~ray_ok, done)
        next_packet = jnp.minimum(next_packet + jnp.sum(idle.astype(jnp.int32)), n_live)
        state = (cur, sp, stack, t_best, prim, done, *_load(table, cur))
        state = _run_steps(
            _packet_step,
            table,
            num_nodes,
            stack_size,
            any_hit,
            rays,
            state,
            traversal.steps_per_refill,
            next_packet,
        )
        return next_packet, lane_packet, rays, state, out_t, out_prim

    carry = (jnp.int32(0), lane_packet, rays, state, out_t, out_prim)
    _, lane_packet, _, state, out_t, out_prim = lax.while_loop(cond, body, carry)
    out_t, out_prim = write_back(lane_packet, state, out_t, out_prim)
    return out_t.reshape(-1)[:n], out_prim.reshape(-1)[:n]
