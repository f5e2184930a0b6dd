"""`packet="sorted"`: rays regrouped by origin into packets, results identical to one by one.

The order (fovjax.trace._order) is checked against a NumPy oracle of its definition; the
traversal against the one-by-one traversal (identical hits, distances and gradients) and,
through tests/test_trace.py's TRAVERSALS, against brute force.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fovjax.trace import build_bvh, closest_hit, merge_bvhs, occluded
from fovjax.trace._order import MORTON_BITS, block_bits, morton_codes, spatial_order


def interleave(q):
    """Morton code of integer cells (n, 3), bit by bit: bit b of axis a goes to bit 3b + a."""
    code = np.zeros(len(q), np.int64)
    for b in range(MORTON_BITS):
        for a in range(3):
            code |= ((q[:, a] >> b) & 1) << (3 * b + a)
    return code


def test_morton_codes_interleave_the_cells():
    rng = np.random.default_rng(0)
    cells = rng.integers(0, 1024, (500, 3))
    # Corners at 0 and 1024 make the box [0, 1024]^3: cell = coordinate, exactly in float32
    # (1024 itself is clipped into the last cell). The last point is far away and not live:
    # it must not stretch the box.
    points = np.concatenate([cells, [[0, 0, 0], [1024, 1024, 1024], [1e6, -1e6, 1e6]]]).astype(np.float32)
    live = np.ones(len(points), bool)
    live[-1] = False
    codes = np.asarray(morton_codes(jnp.asarray(points), jnp.asarray(live)))
    want = interleave(np.minimum(points[:-1].astype(np.int64), 1023))
    np.testing.assert_array_equal(codes[:-1], want)
    assert 0 <= codes[-1] < 1 << 30


@pytest.mark.parametrize("n", [1, 7, 40_000])
def test_spatial_order_sorts_each_block_and_keeps_blocks_in_place(n):
    rng = np.random.default_rng(n)
    o = rng.normal(size=(n, 3)).astype(np.float32)
    live = rng.uniform(size=n) < 0.8
    order = np.asarray(spatial_order(jnp.asarray(o), jnp.asarray(live)))
    assert sorted(order.tolist()) == list(range(n))  # a permutation
    size = 1 << block_bits(n)
    assert (order // size == np.arange(n) // size).all()  # every ray stays in its block
    bits = block_bits(n)
    key_bits = 31 - bits
    key = np.asarray(morton_codes(jnp.asarray(o), jnp.asarray(live))) >> (3 * MORTON_BITS - key_bits)
    key = np.where(live, key, (1 << key_bits) - 1)  # rays that are not live: last in their block
    want = np.lexsort((np.arange(n), key, np.arange(n) // size))
    np.testing.assert_array_equal(order, want)


@pytest.fixture(scope="module")
def boxes():
    """Random boxes on a floor, a point light above: shadow rays from scattered floor points."""
    rng = np.random.default_rng(3)
    faces, verts = [], []
    cube = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    for _ in range(40):
        lo, size = rng.uniform(-4, 4, 3) * [1, 0, 1], rng.uniform(0.2, 1.0, 3)
        base = len(verts) * 8
        verts.append(lo + cube * size)
        for a, b, c, d in quads:
            faces += [(base + a, base + b, base + c), (base + a, base + c, base + d)]
    V = np.concatenate(verts).astype(np.float32)
    F = np.asarray(faces, np.int32)
    return V, F, build_bvh(vertices=V, faces=F, cache=False)


def shadow_rays(n, seed):
    rng = np.random.default_rng(seed)
    p = np.stack([rng.uniform(-5, 5, n), np.full(n, 1e-3), rng.uniform(-5, 5, n)], 1).astype(np.float32)
    light = np.array([0.5, 6.0, -0.5], np.float32)
    d = light - p
    tmax = np.linalg.norm(d, axis=1).astype(np.float32)
    d = (d / tmax[:, None]).astype(np.float32)
    tmin = np.zeros(n, np.float32)
    tmin[::13] = tmax[::13]  # empty intervals: not live
    d[5::97] = np.nan  # invalid rays miss
    return p, d, tmin, tmax


@pytest.mark.parametrize("n", [1, 20_000])
def test_sorted_packets_equal_one_by_one(boxes, n):
    V, F, bvh = boxes
    o, d, tmin, tmax = shadow_rays(n, n)
    occ = np.asarray(occluded(bvh, o, d, tmax, tmin=tmin, packet="sorted"))
    np.testing.assert_array_equal(occ, np.asarray(occluded(bvh, o, d, tmax, tmin=tmin)))
    if n > 1000:
        assert 0.1 < occ.mean() < 0.9  # both outcomes are exercised
    # Closest hits from the light end: identical faces and distances.
    light = o + d * tmax[:, None]
    back = -d
    h_sorted = closest_hit(bvh, light, back, 0.0, tmax, packet="sorted")
    h_plain = closest_hit(bvh, light, back, 0.0, tmax)
    np.testing.assert_array_equal(np.asarray(h_sorted.prim), np.asarray(h_plain.prim))
    np.testing.assert_array_equal(np.asarray(h_sorted.t), np.asarray(h_plain.t))


def test_sorted_packets_under_jit_with_gradients(boxes):
    V, F, bvh = boxes
    o, d, _, tmax = shadow_rays(2000, 11)
    ok = np.isfinite(d).all(axis=1)
    light = (o + d * tmax[:, None])[ok]
    back = -d[ok]

    def total_t(origins, packet):
        hit = closest_hit(bvh, origins, back, 0.0, tmax[ok], packet=packet, vertices=V)
        return jnp.sum(jnp.where(jnp.isfinite(hit.t), hit.t, 0.0))

    g_sorted = jax.jit(jax.grad(lambda x: total_t(x, "sorted")))(jnp.asarray(light))
    g_plain = jax.grad(lambda x: total_t(x, None))(jnp.asarray(light))
    np.testing.assert_array_equal(np.asarray(g_sorted), np.asarray(g_plain))
    assert np.abs(np.asarray(g_plain)).sum() > 0


def test_sorted_packets_with_levels(boxes):
    """A merged BVH (two trees): rays of either level, mixed in one batch, as one by one (the
    sorted packets that mix levels are traced one by one, `_mixed_packets`)."""
    V, F, bvh = boxes
    half = build_bvh(vertices=V, faces=F[: len(F) // 2], cache=False)
    merged = merge_bvhs([bvh, half])
    o, d, tmin, tmax = shadow_rays(5000, 5)
    level = (np.arange(5000) // 3) % 2
    occ = occluded(merged, o, d, tmax, tmin=tmin, packet="sorted", level=level)
    plain_occ = occluded(merged, o, d, tmax, tmin=tmin, level=level)
    np.testing.assert_array_equal(np.asarray(occ), np.asarray(plain_occ))
