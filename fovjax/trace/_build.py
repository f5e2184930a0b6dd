"""Binned-SAH BVH construction on the host, vectorised NumPy, one tree level at a time.

No Python loop runs per triangle or per node: every level handles all of its open nodes with
array operations. The trick that keeps it fast is to sort the triangles once along each axis by
centroid and keep the three orders *stably partitioned* node by node. Inside a node, the spatial
bins of an axis are then contiguous runs of that axis's order, so the per-bin bounds are
`np.minimum.reduceat` over runs (no scatter-min, no sort per level).

Cost model: in this package's traversal every step handles one inner node *or* one triangle, so
traversing a node and testing a triangle cost about the same; C_trav = C_isect = 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BuildParams:
    """Build parameters; part of the cache key."""

    bins: int = 16
    max_leaf_size: int = 4
    traversal_cost: float = 1.0
    intersection_cost: float = 1.0
    max_depth: int = 64

    def __post_init__(self):
        if not 2 <= self.bins <= 256:
            raise ValueError(f"bins must be in [2, 256], got {self.bins}")
        if not 1 <= self.max_leaf_size <= 64:
            raise ValueError(f"max_leaf_size must be in [1, 64], got {self.max_leaf_size}")
        if not 8 <= self.max_depth <= 128:
            raise ValueError(f"max_depth must be in [8, 128], got {self.max_depth}")


@dataclass
class BuiltTree:
    """Inner nodes in depth-first order and the triangle order of the leaves.

    `left`/`right` encode children: value >= 0 is an inner node index; value < 0 is a leaf,
    `-1 - leaf_start` where leaf_start indexes `tri_order` (the leaf's triangles are
    `tri_order[leaf_start : leaf_start + count]`, and `leaf_count` gives count for that start).
    `child_lo/child_hi` (n_inner, 2, 3) are the exact bounds of the left and right child.
    """

    left: np.ndarray
    right: np.ndarray
    child_lo: np.ndarray
    child_hi: np.ndarray
    tri_order: np.ndarray
    leaf_last: np.ndarray  # (F,) bool: position i of tri_order ends a leaf
    depth: int  # inner-node depth of the tree (root = 1)
    num_leaves: int


def _area(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    d = np.maximum(hi - lo, 0.0)
    return 2.0 * (d[..., 0] * d[..., 1] + d[..., 1] * d[..., 2] + d[..., 2] * d[..., 0])


def _area_t(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Surface area for boxes laid out (..., 3, n)."""
    d = np.maximum(hi - lo, 0.0)
    return 2.0 * (d[..., 0, :] * d[..., 1, :] + d[..., 1, :] * d[..., 2, :] + d[..., 2, :] * d[..., 0, :])


def _segment_ids(starts: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions covered by the ranges [start, start+count) and the range index of each."""
    total = int(counts.sum())
    seg = np.repeat(np.arange(len(counts)), counts)
    offsets = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    return starts[seg] + offsets, seg


# Nodes binned with fewer bins than this (fewer than this many triangles) are split along
# their widest centroid axis only: a third of the work where most of the nodes are.
SMALL_NODE_BINS = 8


def _sah_group(orders, starts, counts, nb, centroid_axis, tri_lo_axis, tri_hi_axis):
    """Best binned-SAH split of each node in [start, start+count), with `nb` bins per axis.

    Returns (cost, axis, n_left, centroid extent): cost is sum(area*count) over both sides (inf
    if no split separates the centroids), n_left the size of the left side, which is a prefix of
    that axis's order inside the node.
    """
    k = starts.size
    pos, seg = _segment_ids(starts, counts)
    seg_starts = np.cumsum(counts) - counts
    t0 = orders[0][pos]
    cmin = np.stack([np.minimum.reduceat(centroid_axis[a][t0], seg_starts) for a in range(3)], 1)
    cmax = np.stack([np.maximum.reduceat(centroid_axis[a][t0], seg_starts) for a in range(3)], 1)
    extent = cmax - cmin
    scale = np.where(extent > 0, nb * (1.0 - 1e-6) / np.where(extent > 0, extent, 1.0), 0.0)
    cols = np.arange(k)

    def axis_best(a):
        """Best split along axis a (an int, or an array giving each node's own axis)."""
        if isinstance(a, int | np.integer):
            t_a = orders[a][pos]
            b = (centroid_axis[a][t_a] - cmin[:, a][seg]) * scale[:, a][seg]
        else:
            a_pos = a[seg]
            t_a = np.choose(a_pos, [orders[0][pos], orders[1][pos], orders[2][pos]])
            c = np.choose(a_pos, [centroid_axis[0][t_a], centroid_axis[1][t_a], centroid_axis[2][t_a]])
            b = (c - cmin[cols, a][seg]) * scale[cols, a][seg]
        b = b.astype(np.int64)
        np.clip(b, 0, nb - 1, out=b)
        # Inside a node a bin is a contiguous run of this axis's order.
        run_start = np.flatnonzero(np.r_[True, (b[1:] != b[:-1]) | (seg[1:] != seg[:-1])])
        flat = b[run_start] * (3 * k) + seg[run_start]  # index of (bin, component 0, node)
        # Layout (bins, 3, nodes): accumulations run over bins along long contiguous rows.
        lo = np.full((nb, 3, k), np.inf, np.float32)
        hi = np.full((nb, 3, k), -np.inf, np.float32)
        lo_flat, hi_flat = lo.reshape(-1), hi.reshape(-1)
        for c in range(3):
            lo_flat[flat + c * k] = np.minimum.reduceat(tri_lo_axis[c][t_a], run_start)
            hi_flat[flat + c * k] = np.maximum.reduceat(tri_hi_axis[c][t_a], run_start)
        cnt = np.bincount(b * k + seg, minlength=k * nb).reshape(nb, k)
        left_lo = np.minimum.accumulate(lo[:-1], axis=0)
        left_hi = np.maximum.accumulate(hi[:-1], axis=0)
        right_lo = np.minimum.accumulate(lo[:0:-1], axis=0)[::-1]
        right_hi = np.maximum.accumulate(hi[:0:-1], axis=0)[::-1]
        l_n = np.cumsum(cnt[:-1], axis=0)
        r_n = counts[None, :] - l_n
        cost = _area_t(left_lo, left_hi) * l_n + _area_t(right_lo, right_hi) * r_n
        cost = np.where((l_n > 0) & (r_n > 0), cost, np.inf).astype(np.float32)
        i = np.argmin(cost, axis=0)
        return cost[i, cols], l_n[i, cols]

    if nb >= SMALL_NODE_BINS:
        results = [axis_best(a) for a in range(3)]
        costs = np.stack([c for c, _ in results])
        best_axis = np.argmin(costs, axis=0)  # first axis on ties, as a sequential scan would pick
        best_cost = costs[best_axis, cols]
        best_left = np.stack([n for _, n in results])[best_axis, cols]
    else:
        # Small nodes (the deep levels, most of the nodes): only the widest centroid axis.
        best_axis = np.argmax(extent, axis=1)
        best_cost, best_left = axis_best(best_axis)
    return best_cost, best_axis, best_left, extent


def build_tree(tri_lo: np.ndarray, tri_hi: np.ndarray, params: BuildParams = BuildParams()) -> BuiltTree:
    """Build a binary BVH over boxes `tri_lo`, `tri_hi` (F, 3)."""
    tri_lo = np.asarray(tri_lo, np.float32)
    tri_hi = np.asarray(tri_hi, np.float32)
    nf = tri_lo.shape[0]
    if nf == 0:
        raise ValueError("build_tree: no triangles")
    centroid = 0.5 * (tri_lo + tri_hi)
    centroid_axis = [np.ascontiguousarray(centroid[:, a]) for a in range(3)]
    tri_lo_axis = [np.ascontiguousarray(tri_lo[:, a]) for a in range(3)]
    tri_hi_axis = [np.ascontiguousarray(tri_hi[:, a]) for a in range(3)]
    nbins = params.bins
    ci, ct = params.intersection_cost, params.traversal_cost

    # One permutation per axis, each grouped by node and sorted by centroid inside a node.
    orders = [np.argsort(centroid[:, a], kind="stable") for a in range(3)]

    # Node records, appended level by level (BFS ids); a binary tree has at most 2F - 1 nodes.
    cap = 2 * nf
    n_start = np.zeros(cap, np.int64)
    n_count = np.zeros(cap, np.int64)
    n_lo = np.zeros((cap, 3))
    n_hi = np.zeros((cap, 3))
    n_left = np.zeros(cap, np.int64)
    n_right = np.zeros(cap, np.int64)
    n_is_leaf = np.zeros(cap, bool)
    n_depth = np.zeros(cap, np.int64)
    n_count[0] = nf
    n_lo[0] = tri_lo.min(axis=0)
    n_hi[0] = tri_hi.max(axis=0)
    n_depth[0] = 1
    n_nodes = 1

    open_nodes = np.array([0])
    depth = 1
    while open_nodes.size:
        starts = n_start[open_nodes]
        counts = n_count[open_nodes]
        k = open_nodes.size
        if depth >= params.max_depth:
            raise ValueError(
                f"build_bvh: tree depth exceeded max_depth={params.max_depth}; "
                "the mesh has too many coincident triangles for the leaf size"
            )
        # SAH per group of nodes with the same bin count: a node of n triangles gets
        # min(bins, next power of two >= n) bins, so deep levels full of tiny nodes stay cheap.
        best_cost = np.full(k, np.inf)
        split_axis = np.zeros(k, np.int64)
        left_size = np.zeros(k, np.int64)  # the first left_size triangles in split_axis's order go left
        extent = np.zeros((k, 3), np.float32)
        nb_node = np.minimum(nbins, 2 ** np.ceil(np.log2(np.maximum(counts, 2))).astype(np.int64))
        for nb in np.unique(nb_node[counts > 1]).tolist():
            sel = np.flatnonzero((nb_node == nb) & (counts > 1))
            g_cost, g_axis, g_left, g_extent = _sah_group(
                orders, starts[sel], counts[sel], nb, centroid_axis, tri_lo_axis, tri_hi_axis
            )
            best_cost[sel], split_axis[sel], left_size[sel], extent[sel] = g_cost, g_axis, g_left, g_extent

        node_area = np.maximum(_area(n_lo[open_nodes], n_hi[open_nodes]), 1e-30)
        split_cost = ct + ci * best_cost / node_area
        leaf_cost = ci * counts
        # The root is always split (when it can be) so that traversal starts at an inner node.
        force_split = (counts > params.max_leaf_size) | ((depth == 1) & (counts > 1))
        make_leaf = ~force_split & (leaf_cost <= split_cost)
        # No usable SAH split (all centroids in one bin): split at the median of the widest axis.
        rank_split = ~make_leaf & ~np.isfinite(best_cost)
        split_axis = np.where(rank_split, np.argmax(extent, axis=1), split_axis)
        left_size = np.where(rank_split, counts // 2, left_size)

        n_is_leaf[open_nodes] = make_leaf
        split_nodes = np.flatnonzero(~make_leaf)
        if split_nodes.size == 0:
            break

        pos, seg = _segment_ids(starts, counts)
        seg_starts = np.cumsum(counts) - counts
        rank_in_node = np.arange(pos.size) - seg_starts[seg]
        in_split = ~make_leaf[seg]
        # Side of each triangle in a splitting node: 0 left, 1 right (by rank in its split order).
        side_by_tri = np.zeros(nf, bool)
        for a in range(3):
            m = np.flatnonzero(in_split & (split_axis[seg] == a))
            side_by_tri[orders[a][pos[m]]] = rank_in_node[m] >= left_size[seg[m]]
        n_left_cnt = np.where(make_leaf, counts, left_size)

        # Stable partition of every order inside each splitting node.
        start_pos = starts[seg]
        right_base = start_pos + n_left_cnt[seg]
        moved = np.flatnonzero(in_split)
        for a in range(3):
            t_a = orders[a][pos]
            go_left = ~side_by_tri[t_a]
            cum_left = np.cumsum(go_left)
            cum_left -= go_left
            rank_left = cum_left - cum_left[seg_starts][seg]
            new_pos = np.where(go_left, start_pos + rank_left, right_base + (rank_in_node - rank_left))
            orders[a][new_pos[moved]] = t_a[moved]

        # Children bounds, exact, by reduceat over the partitioned ranges.
        sn = split_nodes
        c_start = np.stack([starts[sn], starts[sn] + n_left_cnt[sn]], axis=1).reshape(-1)
        c_count = np.stack([n_left_cnt[sn], counts[sn] - n_left_cnt[sn]], axis=1).reshape(-1)
        if (c_count <= 0).any():
            raise AssertionError("build_bvh: an empty child was produced")  # guarded by SAH/rank split
        cpos, _ = _segment_ids(c_start, c_count)
        ctris = orders[0][cpos]
        cseg_starts = np.cumsum(c_count) - c_count
        c_lo = np.minimum.reduceat(tri_lo[ctris], cseg_starts, axis=0)
        c_hi = np.maximum.reduceat(tri_hi[ctris], cseg_starts, axis=0)

        first_child = n_nodes
        n_new = c_start.size
        new = slice(first_child, first_child + n_new)
        n_start[new] = c_start
        n_count[new] = c_count
        n_lo[new] = c_lo
        n_hi[new] = c_hi
        n_depth[new] = depth + 1
        parents = open_nodes[sn]
        n_left[parents] = first_child + 2 * np.arange(sn.size)
        n_right[parents] = first_child + 2 * np.arange(sn.size) + 1
        n_nodes += n_new
        open_nodes = np.arange(first_child, first_child + n_new)
        depth += 1

    if n_nodes == 1:  # a single triangle: the root is a leaf
        n_is_leaf[0] = True
    m = slice(0, n_nodes)
    return _flatten(
        n_start[m], n_count[m], n_lo[m], n_hi[m], n_left[m], n_right[m], n_is_leaf[m], n_depth[m], orders[0]
    )


def _flatten(start, count, lo, hi, left, right, is_leaf, depth, order) -> BuiltTree:
    """Renumber inner nodes depth-first (the near child is usually next in memory)."""
    n = start.size
    inner = ~is_leaf
    if not inner.any():
        # A single leaf: give it a root whose right child is an empty box that no ray enters.
        leaf_last = np.zeros(order.size, bool)
        leaf_last[-1] = True
        empty_lo, empty_hi = np.full(3, np.inf), np.full(3, -np.inf)
        return BuiltTree(
            left=np.array([-1]),
            right=np.array([-1]),
            child_lo=np.stack([lo[0], empty_lo])[None],
            child_hi=np.stack([hi[0], empty_hi])[None],
            tri_order=order.astype(np.int64),
            leaf_last=leaf_last,
            depth=1,
            num_leaves=1,
        )
    # Subtree inner-node counts, bottom-up by depth (children always have larger BFS ids).
    size = inner.astype(np.int64)
    for d in range(int(depth.max()), 0, -1):
        at = np.flatnonzero((depth == d) & inner)
        size[at] += size[left[at]] + size[right[at]]
    dfs = np.full(n, -1, np.int64)
    dfs[0] = 0
    for d in range(1, int(depth.max()) + 1):
        at = np.flatnonzero((depth == d) & inner)
        dfs[left[at]] = dfs[at] + 1
        dfs[right[at]] = dfs[at] + 1 + size[left[at]]
    inner_ids = np.flatnonzero(inner)
    n_inner = inner_ids.size
    perm = np.empty(n_inner, np.int64)
    perm[dfs[inner_ids]] = inner_ids  # perm[new] = old

    def encode(child):
        return np.where(inner[child], dfs[child], -1 - start[child])

    l_old = left[perm]
    r_old = right[perm]
    child_lo = np.stack([lo[l_old], lo[r_old]], axis=1)
    child_hi = np.stack([hi[l_old], hi[r_old]], axis=1)
    leaf_last = np.zeros(order.size, bool)
    leaves = np.flatnonzero(is_leaf)
    leaf_last[start[leaves] + count[leaves] - 1] = True
    return BuiltTree(
        left=encode(l_old).astype(np.int64),
        right=encode(r_old).astype(np.int64),
        child_lo=child_lo,
        child_hi=child_hi,
        tri_order=order.astype(np.int64),
        leaf_last=leaf_last,
        depth=int(depth[inner].max()),
        num_leaves=int(leaves.size),
    )
