"""Collapse the binary SAH tree into a 4-wide BVH and pack it into 64-byte rows.

A 4-wide node with its four child boxes quantised to 8 bits (relative to the node's own box,
on a power-of-two grid, rounded outwards) fits one 64-byte row, the same size as a triangle row.
Binary traversal spent ~55 of its ~66 steps per ray at nodes (perf-notes' prototype: 77); a
4-wide tree needs about half as many node steps, and each step still gathers one cache line.

Row layout (16 int32 words):
- node:     0-2 origin xyz (float32 bits); 3 the three scale exponents as biased float32
            exponent bytes (scale = 2**(byte - 127)); 4-9 the quantised child boxes, one word per
            (lo x, hi x, lo y, hi y, lo z, hi z) holding four 8-bit values, child c in bits 8c..8c+7;
            10-13 the child items (-1: empty slot).
- triangle: 0-8 corners (float32 bits); 9 original face index; 10 = 1 on the last triangle
            of its leaf.
A child item >= num_nodes is the first triangle row of a leaf.
"""

from __future__ import annotations

import numpy as np

from ._build import BuiltTree, _area

WIDTH = 4
ROW_WORDS = 16
EMPTY = np.iinfo(np.int64).min  # empty child slot (binary-tree code space)


def collapse(tree: BuiltTree):
    """4-wide nodes from a binary tree (greedy: open the largest inner child until 4 slots).

    Returns (codes (M, 4), lo (M, 4, 3), hi (M, 4, 3), depth) in BFS order; a code >= 0 is a
    wide node index, a leaf is `-1 - leaf_start` as in `BuiltTree`, EMPTY an unused slot.
    """
    level = np.array([0])  # binary ids of this level's wide nodes
    all_codes, all_lo, all_hi = [], [], []
    next_id = 1
    depth = 0
    while level.size:
        depth += 1
        k = level.size
        codes = np.full((k, WIDTH), EMPTY, np.int64)
        lo = np.full((k, WIDTH, 3), np.inf, np.float32)
        hi = np.full((k, WIDTH, 3), -np.inf, np.float32)
        codes[:, 0], codes[:, 1] = tree.left[level], tree.right[level]
        lo[:, :2], hi[:, :2] = tree.child_lo[level], tree.child_hi[level]
        rows = np.arange(k)
        for slot in (2, 3):
            inner = codes >= 0
            area = np.where(inner, _area(lo, hi), -1.0)
            j = np.argmax(area, axis=1)
            can = area[rows, j] >= 0
            r, jj = rows[can], j[can]
            b = codes[r, jj]
            codes[r, jj], codes[r, slot] = tree.left[b], tree.right[b]
            lo[r, jj], hi[r, jj] = tree.child_lo[b, 0], tree.child_hi[b, 0]
            lo[r, slot], hi[r, slot] = tree.child_lo[b, 1], tree.child_hi[b, 1]
        # A slot with an empty box (the single-leaf tree's dummy sibling) holds nothing.
        codes = np.where((lo > hi).any(axis=-1), EMPTY, codes)
        inner = codes >= 0
        n_new = int(inner.sum())
        wide_ids = np.full(codes.shape, -1, np.int64)
        wide_ids[inner] = next_id + np.arange(n_new)
        next_level = codes[inner]  # binary ids, row-major: matches wide_ids order
        codes = np.where(inner, wide_ids, codes)
        next_id += n_new
        all_codes.append(codes)
        all_lo.append(lo)
        all_hi.append(hi)
        level = next_level
    return np.concatenate(all_codes), np.concatenate(all_lo), np.concatenate(all_hi), depth


def _dfs_order(codes: np.ndarray) -> np.ndarray:
    """New index of every BFS-numbered wide node in depth-first order."""
    m = codes.shape[0]
    inner = codes >= 0
    # Subtree sizes bottom-up: children have larger BFS ids than their parent.
    size = np.ones(m, np.int64)
    parent = np.full(m, -1, np.int64)
    slot = np.zeros(m, np.int64)
    rows, cols = np.nonzero(inner)
    parent[codes[rows, cols]] = rows
    slot[codes[rows, cols]] = cols
    frontier = np.array([0])
    levels = []
    while frontier.size:
        levels.append(frontier)
        child = codes[frontier]
        frontier = child[child >= 0]
    for lvl in reversed(levels[1:]):
        np.add.at(size, parent[lvl], size[lvl])
    dfs = np.zeros(m, np.int64)
    for lvl in levels[1:]:
        p = parent[lvl]
        # Offset of a child = 1 + sizes of the earlier siblings.
        sib = codes[p]  # (n, 4)
        sib_sizes = np.where(sib >= 0, size[np.maximum(sib, 0)], 0)
        before = np.cumsum(sib_sizes, axis=1) - sib_sizes
        dfs[lvl] = dfs[p] + 1 + before[np.arange(lvl.size), slot[lvl]]
    return dfs


def quantise(lo: np.ndarray, hi: np.ndarray, valid: np.ndarray):
    """8-bit outward-rounded child boxes on a power-of-two grid per node and axis.

    Returns (origin (M, 3) float32, exponent (M, 3) int, q_lo (M, 4, 3) uint8, q_hi). The decoded
    box origin + q * 2**exponent, evaluated in float32 (the product is exact, so one rounding
    with or without FMA), always contains the true child box.
    """
    node_lo = np.where(valid[..., None], lo, np.inf).min(axis=1).astype(np.float32)
    node_hi = np.where(valid[..., None], hi, -np.inf).max(axis=1).astype(np.float32)
    origin = node_lo
    extent = node_hi.astype(np.float64) - node_lo.astype(np.float64)
    mag = np.maximum(np.abs(node_lo), np.abs(node_hi)).astype(np.float32)
    ulp = np.spacing(mag).astype(np.float64)
    exponent = np.ceil(np.log2(np.maximum(extent / 250.0, 4.0 * ulp))).astype(np.int64)
    exponent = np.clip(exponent, -126, 127)
    lo_s = np.where(valid[..., None], lo, node_lo[:, None, :])
    hi_s = np.where(valid[..., None], hi, node_lo[:, None, :])
    for _ in range(8):
        scale = np.ldexp(np.float32(1.0), exponent).astype(np.float32)[:, None, :]
        q_lo = np.clip(np.floor((lo_s - origin[:, None, :]) / scale), 0, 255)
        q_hi = np.clip(np.ceil((hi_s - origin[:, None, :]) / scale), 0, 255)
        dec_lo = origin[:, None, :] + (q_lo.astype(np.float32) * scale)
        q_lo = np.where(dec_lo > lo_s, q_lo - 1, q_lo)
        dec_hi = origin[:, None, :] + (q_hi.astype(np.float32) * scale)
        q_hi = np.where(dec_hi < hi_s, q_hi + 1, q_hi)
        dec_lo = origin[:, None, :] + (np.clip(q_lo, 0, 255).astype(np.float32) * scale)
        dec_hi = origin[:, None, :] + (np.clip(q_hi, 0, 255).astype(np.float32) * scale)
        bad = (q_lo < 0) | (q_hi > 255) | (dec_lo > lo_s) | (dec_hi < hi_s)
        bad_axis = bad.any(axis=1)  # (M, 3)
        if not bad_axis.any():
            return origin, exponent, q_lo.astype(np.uint8), q_hi.astype(np.uint8)
        exponent = np.where(bad_axis, exponent + 1, exponent)
    raise AssertionError("BVH quantisation failed to contain a child box")  # not reachable for finite input


def pack(tree: BuiltTree, tri: np.ndarray) -> tuple[np.ndarray, int, int]:
    """The traversal table, its number of node rows and the traversal stack size."""
    codes, lo, hi, depth = collapse(tree)
    dfs = _dfs_order(codes)
    m = codes.shape[0]
    perm = np.empty(m, np.int64)
    perm[dfs] = np.arange(m)  # perm[new] = old
    codes, lo, hi = codes[perm], lo[perm], hi[perm]
    valid = codes != EMPTY
    item = np.where(codes >= 0, dfs[np.maximum(codes, 0)], m + (-1 - codes))
    item = np.where(valid, item, -1)

    origin, exponent, q_lo, q_hi = quantise(lo, hi, valid)
    nf = tri.shape[0]
    table = np.zeros((m + nf, ROW_WORDS), np.int32)
    table[:m, 0:3] = origin.view(np.int32)
    biased = (exponent + 127).astype(np.uint32)
    table[:m, 3] = (biased[:, 0] | (biased[:, 1] << 8) | (biased[:, 2] << 16)).view(np.int32)
    shifts = (8 * np.arange(WIDTH, dtype=np.uint32))[None, :]
    for axis in range(3):
        for half, q in enumerate((q_lo, q_hi)):
            word = np.bitwise_or.reduce(q[:, :, axis].astype(np.uint32) << shifts, axis=1)
            table[:m, 4 + 2 * axis + half] = word.view(np.int32)
    table[:m, 10:14] = item
    corners = tri[tree.tri_order].reshape(nf, 9).astype(np.float32)
    table[m:, :9] = corners.view(np.int32)
    table[m:, 9] = tree.tri_order
    table[m:, 10] = tree.leaf_last
    # Near-first descent pushes at most WIDTH - 1 entries per level.
    stack_size = (WIDTH - 1) * depth + 1
    return table, m, stack_size
