"""Geometry level of detail per region (`Fidelity.lod`): a merged BVH traces each ray against its
own level (brute force per level is the oracle), the default frame is today's bit for bit, a
coarse level in the outside region puts its hits on that level's triangles and leaves the fovea
alone, and bad values fail before any compile."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fovjax
from fovjax.scene import lod_levels
from fovjax.trace import brute_force_closest_hit, build_bvh, closest_hit, merge_bvhs, occluded

RTOL, ATOL = 1e-4, 1e-5
RATIOS = (1.0, 0.5, 0.25, 0.1)


@pytest.fixture(scope="module")
def levels(tmp_path_factory):
    scene = fovjax.scenes.spheres(subdivisions=1, ground_cells=4)
    return lod_levels(scene, RATIOS, cache_dir=tmp_path_factory.mktemp("lod"))


@pytest.fixture(scope="module")
def merged(levels):
    bvhs = [build_bvh(s, cache=False) for s in levels.scenes]
    return merge_bvhs(bvhs), np.cumsum([0, *levels.triangles[:-1]])


def _rays(n, seed):
    """Rays from around the spheres' camera region towards the scene (most hit something)."""
    rng = np.random.default_rng(seed)
    o = rng.uniform(-4, 4, (n, 3)).astype(np.float32)
    o[:, 1] = rng.uniform(0.5, 4, n)
    target = rng.uniform(-1.5, 1.5, (n, 3)).astype(np.float32)
    target[:, 1] = rng.uniform(0.0, 1.5, n)
    return o, (target - o).astype(np.float32)


def _check_level(scene, o, d, t, prim_local):
    """Hits of rays against one level match brute force on that level's triangles."""
    t_ref, prim_ref, t_all = brute_force_closest_hit(scene.vertices, scene.faces, o, d)
    ref_hit = np.isfinite(t_ref)
    assert np.mean(np.isfinite(t) == ref_hit) >= 0.999
    both = np.isfinite(t) & ref_hit
    assert (np.abs(t[both] - t_ref[both]) <= np.maximum(RTOL * np.abs(t_ref[both]), ATOL)).all()
    second = np.sort(t_all, axis=1)[:, 1]
    with np.errstate(invalid="ignore"):
        clear = both & (second - t_ref > RTOL * np.abs(t_ref) + ATOL)
    assert clear.sum() > 0.3 * len(t)  # the test has teeth: most rays hit unambiguously
    assert (prim_local[clear] == prim_ref[clear]).all()


@pytest.mark.parametrize("packet", [None, 16], ids=["single", "packet16"])
def test_merged_bvh_traces_every_level_like_brute_force(levels, merged, packet):
    bvh, face_offset = merged
    assert bvh.num_levels == len(levels)
    o, d = _rays(1200, 0)
    level = np.random.default_rng(1).integers(0, len(levels), len(o)).astype(np.int32)
    hit = closest_hit(bvh, o, d, packet=packet, level=level)
    blocked = np.asarray(occluded(bvh, o, d, packet=packet, level=level))
    t, prim = np.asarray(hit.t), np.asarray(hit.prim)
    for lv, scene in enumerate(levels.scenes):
        sel = level == lv
        local = np.where(prim[sel] >= 0, prim[sel] - face_offset[lv], -1)
        assert ((local >= -1) & (local < scene.num_triangles)).all()  # hits stay on the ray's own level
        _check_level(scene, o[sel], d[sel], t[sel], local)
        t_ref, _, _ = brute_force_closest_hit(scene.vertices, scene.faces, o[sel], d[sel])
        assert np.mean(blocked[sel] == np.isfinite(t_ref)) >= 0.999


def test_tile_packets_with_mixed_levels(levels, merged):
    """8x8 image packets: uniform packets are traced from their level's root, packets that
    straddle two levels ray by ray; either way every ray gets its own level's hit."""
    bvh, face_offset = merged
    o, d = _rays(20 * 28, 2)
    o, d = o.reshape(20, 28, 3), d.reshape(20, 28, 3)
    yy, xx = np.mgrid[:20, :28]
    level = np.where(np.hypot(yy - 9.5, xx - 13.5) < 7, 0, 2).astype(np.int32)  # mixed at the circle
    hit = closest_hit(bvh, o, d, packet=(8, 8), level=level)
    plain = closest_hit(bvh, o, d, level=level)  # one by one
    assert np.array_equal(np.asarray(hit.prim), np.asarray(plain.prim))
    for lv in (0, 2):
        sel = level == lv
        prim = np.asarray(hit.prim)[sel]
        local = np.where(prim >= 0, prim - face_offset[lv], -1)
        _check_level(levels.scenes[lv], o[sel], d[sel], np.asarray(hit.t)[sel], local)


def test_level_zero_of_a_merged_bvh_is_the_plain_bvh(levels, merged):
    bvh, _ = merged
    plain = build_bvh(levels.scenes[0], cache=False)
    o, d = _rays(500, 3)
    a, b = closest_hit(plain, o, d), closest_hit(bvh, o, d, level=0)
    assert np.array_equal(np.asarray(a.prim), np.asarray(b.prim))
    assert np.array_equal(np.asarray(a.t), np.asarray(b.t))


def test_level_argument_errors(levels, merged):
    bvh, _ = merged
    o, d = _rays(8, 4)
    with pytest.raises(ValueError, match="merged BVH"):
        closest_hit(build_bvh(levels.scenes[0], cache=False), o, d, level=0)
    with pytest.raises(ValueError, match="backend 'jax'"):
        occluded(bvh, o, d, backend="embree", level=0)
    with pytest.raises(ValueError, match="single-tree"):
        merge_bvhs([bvh])


def test_level_is_traced_under_jit(levels, merged):
    bvh, face_offset = merged
    o, d = _rays(64, 5)
    f = jax.jit(lambda lv: closest_hit(bvh, o, d, level=lv).prim)
    for lv in range(len(levels)):
        prim = np.asarray(f(jnp.int32(lv)))
        hit = prim >= 0
        assert hit.any()
        assert ((prim[hit] >= face_offset[lv]) & (prim[hit] < face_offset[lv] + levels.triangles[lv])).all()
    assert f._cache_size() == 1
