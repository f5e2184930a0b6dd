"""The Warp backend (`fovjax.trace._warp.warp_query`, Warp's CPU device here) against brute force and
the JAX traversal: hit/miss, prim (either face at an exact tie), t, occlusion, tmin/tmax, invalid
rays, `level=` on a merged BVH, no recompilation for a new scene, and a CUDA export without a GPU.

Few programs, one ray count (N) throughout: Warp compiles its kernels once per machine (~7 s, then
cached on disk), each jitted query is one XLA program.
"""

from __future__ import annotations

import _extras
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fovjax
from fovjax.trace import Traversal, brute_force_closest_hit, build_bvh, merge_bvhs
from fovjax.trace._query import _raw_query

_extras.require("warp", module_level=True)
from fovjax.trace._warp import ffi_target_names, warp_query  # noqa: E402

N = 1024
RTOL, ATOL = 1e-4, 1e-5
JAX_OPTS = dict(packet_size=None, traversal=Traversal(lanes=256, packets=16, steps_per_refill=4))


@jax.jit
def warp_both(bvh, o, d, tmin, tmax):
    """(t, prim) closest and prim of the any-hit query, in one program."""
    t, prim = warp_query(bvh, o, d, tmin, tmax, None, any_hit=False)
    _, anyp = warp_query(bvh, o, d, tmin, tmax, None, any_hit=True)
    return t, prim, anyp


@jax.jit
def warp_levels(bvh, o, d, tmin, tmax, level):
    t, prim = warp_query(bvh, o, d, tmin, tmax, level, any_hit=False)
    _, anyp = warp_query(bvh, o, d, tmin, tmax, level, any_hit=True)
    return t, prim, anyp


def jax_query(bvh, o, d, tmin, tmax, level=None, any_hit=False):
    t, prim, _, _ = _raw_query(bvh, o, d, tmin, tmax, level, backend="jax", any_hit=any_hit, **JAX_OPTS)
    return t, prim


def _soup(seed, n_tris=300):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-2, 2, (n_tris, 1, 3))
    V = (centres + rng.normal(0, 0.3, (n_tris, 3, 3))).reshape(-1, 3).astype(np.float32)
    F = np.arange(3 * n_tris).reshape(n_tris, 3).astype(np.int32)
    return V, F


def _rays(seed, lo=-3.0, hi=3.0):
    """N rays from a box around the scene towards random targets in it, with random tmin/tmax and
    a few invalid rays at fixed indices (see INVALID)."""
    rng = np.random.default_rng(seed)
    o = rng.uniform(lo, hi, (N, 3)).astype(np.float32)
    d = (rng.uniform(lo / 2, hi / 2, (N, 3)) - o).astype(np.float32)
    tmin = np.where(rng.random(N) < 0.3, rng.uniform(0, 0.5, N), 0.0).astype(np.float32)
    tmax = np.where(rng.random(N) < 0.3, rng.uniform(0.2, 1.0, N), np.inf).astype(np.float32)
    o[0, 1] = np.nan
    d[1, 2] = np.inf
    d[2] = 0.0
    tmax[3] = tmin[3] = 0.25  # empty interval
    tmin[4], tmax[4] = 0.5, 0.1  # inverted
    tmax[5] = np.nan
    o[6] = np.inf
    return o, d, tmin, tmax


INVALID = np.arange(7)


def _check_closest(V, F, o, d, tmin, tmax, t, prim, agree=0.999):
    """Against float64 brute force: hit/miss, t, and prim — where another face is hit at the same
    distance (a shared edge or vertex), the face Warp reports must be one of those."""
    t_ref, prim_ref, t_all = brute_force_closest_hit(V, F, o, d, tmin, tmax)
    t, prim = np.asarray(t), np.asarray(prim)
    hit, ref_hit = prim >= 0, np.isfinite(t_ref)
    assert np.mean(hit == ref_hit) >= agree, "hit/miss disagreement"
    assert not hit[INVALID].any()
    both = hit & ref_hit
    assert both.sum() > 0.3 * N  # the test has teeth
    assert (np.abs(t[both] - t_ref[both]) <= np.maximum(RTOL * np.abs(t_ref[both]), ATOL)).all()
    # The face Warp names is hit at the nearest distance: its plane at t_ref, barycentrics inside
    # up to rounding (at an exact tie on a shared edge or vertex, either face is right).
    t_named, bary = _plane_hit(V, F, prim[both], o[both], d[both])
    assert (np.abs(t_named - t_ref[both]) <= np.maximum(RTOL * np.abs(t_ref[both]), ATOL)).all()
    assert (bary >= -1e-5).all()
    return t_ref, prim_ref


def _plane_hit(V, F, prim, o, d):
    """float64 distance to each named face's plane and the smallest barycentric coordinate there."""
    tri = np.asarray(V, np.float64)[np.asarray(F)[prim]]
    p0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    o, d = np.asarray(o, np.float64), np.asarray(d, np.float64)
    pvec = np.cross(d, e2)
    inv = 1.0 / np.sum(e1 * pvec, -1)
    tvec = o - p0
    qvec = np.cross(tvec, e1)
    u = np.sum(tvec * pvec, -1) * inv
    v = np.sum(d * qvec, -1) * inv
    return np.sum(e2 * qvec, -1) * inv, np.minimum(np.minimum(u, v), 1 - u - v)


@pytest.fixture(scope="module")
def soup():
    V, F = _soup(0)
    return V, F, build_bvh(vertices=V, faces=F, cache=False)


def test_closest_and_any_hit_match_brute_force_and_jax(soup):
    V, F, bvh = soup
    o, d, tmin, tmax = _rays(1)
    t, prim, anyp = warp_both(bvh, o, d, tmin, tmax)
    t_ref, _ = _check_closest(V, F, o, d, tmin, tmax, t, prim)
    prim = np.asarray(prim)
    # Misses report tmax, as the Embree backend does.
    assert np.array_equal(np.asarray(t)[prim < 0], tmax[prim < 0], equal_nan=True)
    # Occlusion: anything on the ray within (tmin, tmax) is exactly "the closest query hit".
    assert np.array_equal(np.asarray(anyp) >= 0, prim >= 0)
    # The JAX traversal on the same rays: same hits, same faces where the nearest is clear.
    tj, pj = (np.asarray(x) for x in jax_query(bvh, o, d, tmin, tmax))
    _, oj = jax_query(bvh, o, d, tmin, tmax, any_hit=True)
    assert np.mean((pj >= 0) == (prim >= 0)) >= 0.999
    assert np.mean((np.asarray(oj) >= 0) == (np.asarray(anyp) >= 0)) >= 0.999
    both = (pj >= 0) & (prim >= 0)
    assert (np.abs(np.asarray(t)[both] - tj[both]) <= np.maximum(RTOL * np.abs(tj[both]), ATOL)).all()
    assert np.mean(pj[both] == prim[both]) >= 0.999
    assert np.isfinite(t_ref[both]).all()


def test_cornell_box_and_shadow_rays():
    scene = fovjax.scenes.cornell_box()
    bvh = build_bvh(scene, cache=False)
    V, F = np.asarray(scene.vertices), np.asarray(scene.faces)
    rng = np.random.default_rng(2)
    lo, hi = (np.asarray(b, np.float32) for b in scene.bounds)
    o = np.broadcast_to((lo + hi) / 2, (N, 3)).astype(np.float32).copy()
    d = (rng.uniform(lo, hi, (N, 3)) - o).astype(np.float32)
    tmin = np.zeros(N, np.float32)
    tmax = np.full(N, np.inf, np.float32)
    tmax[INVALID] = -1.0  # the INVALID rays of _check_closest miss
    t, prim, anyp = warp_both(bvh, o, d, tmin, tmax)
    _check_closest(V, F, o, d, tmin, tmax, t, prim)
    assert np.array_equal(np.asarray(anyp) >= 0, np.asarray(prim) >= 0)
    # Shadow rays from the centre towards each hit point, stopping short of it (tmin > 0 too).
    t, prim = np.asarray(t), np.asarray(prim)
    p = o + d * np.where(prim >= 0, t, 0.0)[:, None]
    sd = (p - o).astype(np.float32)
    a, b = np.full(N, 1e-3, np.float32), np.full(N, 1 - 1e-3, np.float32)
    _, _, blocked = warp_both(bvh, o, sd, a, b)
    _, jb = jax_query(bvh, o, sd, a, b, any_hit=True)
    assert np.array_equal(np.asarray(blocked) >= 0, np.asarray(jb) >= 0)
    assert not (np.asarray(blocked) >= 0).all()  # the test has teeth


def test_ties_on_shared_edges_and_vertices():
    """A 16x16 grid of squares, two triangles each: rays at its interior vertices, edge midpoints
    and diagonals hit two (or up to six) faces at the same t. Each names one of the faces it
    touches, at the right t. Warp's ray-triangle test is not watertight: on a CPU a slanted ray
    through a vertex shared by six faces can fall through (4 of ~130 here; the JAX traversal and
    float64 brute force hit them all), through edges none did; on CUDA (an H200, `gpu.sh`)
    slanted rays fell through edges too (13 edge and 22 vertex rays of the slanted half). Rays
    straight down never fell through."""
    n = 16
    xs = np.linspace(-2, 2, n + 1, dtype=np.float32)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size, np.float32)], -1)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a, b, c, e = (i * (n + 1) + j), (i + 1) * (n + 1) + j, (i + 1) * (n + 1) + j + 1, i * (n + 1) + j + 1
    F = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, e], -1).reshape(-1, 3)])
    F = F.astype(np.int32)
    bvh = build_bvh(vertices=V, faces=F, cache=False)
    rng = np.random.default_rng(3)
    gi = rng.integers(1, n, (N, 2)).astype(np.float32)
    kind = rng.integers(0, 4, N)  # vertex, edge midpoint (x), edge midpoint (y), diagonal midpoint
    off = np.stack([(kind == 1) | (kind == 3), (kind == 2) | (kind == 3)], -1) * 0.5
    step = 4.0 / n
    target = np.concatenate([-2 + (gi - off) * step, np.zeros((N, 1))], -1).astype(np.float32)
    o = target + np.concatenate([rng.uniform(-1, 1, (N, 2)), rng.uniform(1, 3, (N, 1))], -1)
    o[: N // 2, :2] = target[: N // 2, :2]  # half straight down
    o = o.astype(np.float32)
    d = (target - o).astype(np.float32)
    tmin = np.zeros(N, np.float32)
    tmax = np.full(N, np.inf, np.float32)
    tmax[INVALID] = -1.0
    t, prim, anyp = warp_both(bvh, o, d, tmin, tmax)
    prim = np.asarray(prim)
    live = np.arange(N) >= len(INVALID)
    down = np.arange(N) < N // 2
    # Rays that fell through, by where they aim and how (said in full when an assertion fails).
    missed = {
        f"{where} {how}": int(np.sum(live & (prim < 0) & at & way))
        for where, at in (("vertex", kind == 0), ("edge", (kind == 1) | (kind == 2)), ("diagonal", kind == 3))
        for how, way in (("down", down), ("slanted", ~down))
    }
    assert missed["vertex down"] + missed["edge down"] + missed["diagonal down"] == 0, missed
    if jax.devices()[0].platform == "cpu":
        assert missed["edge slanted"] + missed["diagonal slanted"] == 0, missed
        assert np.mean(prim[live & (kind == 0)] >= 0) >= 0.95, missed  # slanted at vertices: see above
        _check_closest(V, F, o, d, tmin, tmax, t, prim, agree=0.99)
    else:  # every disagreement with brute force is one of the slanted rays that fell through
        _check_closest(V, F, o, d, tmin, tmax, t, prim, agree=(N - sum(missed.values())) / N - 1e-9)
    assert np.array_equal(np.asarray(anyp) >= 0, prim >= 0)


def test_new_scene_same_shapes_reuses_the_program(soup):
    """A second geometry of the same array shapes: no retrace (so no recompile), and its own mesh."""
    V, F, bvh = soup
    V2 = (V + np.float32([0.25, -0.5, 0.125])).astype(np.float32)  # moved: the same tree shape
    bvh2 = build_bvh(vertices=V2, faces=F, cache=False)
    assert np.shape(bvh2.table) == np.shape(bvh.table)
    o, d, tmin, tmax = _rays(3)
    warp_both(bvh, o, d, tmin, tmax)
    size = warp_both._cache_size()
    t, prim, _ = warp_both(bvh2, o, d, tmin, tmax)
    assert warp_both._cache_size() == size
    _check_closest(V2, F, o, d, tmin, tmax, t, prim)
    t1, prim1, _ = warp_both(bvh, o, d, tmin, tmax)  # and back: each scene keeps its own mesh
    _check_closest(V, F, o, d, tmin, tmax, t1, prim1)


def test_level_on_a_merged_bvh_traces_only_that_level():
    (V0, F0), (V1, F1) = _soup(7, 200), _soup(8, 120)
    merged = merge_bvhs(
        [build_bvh(vertices=V0, faces=F0, cache=False), build_bvh(vertices=V1, faces=F1, cache=False)]
    )
    o, d, tmin, tmax = _rays(4)
    level = (np.arange(N) % 2).astype(np.int32)
    t, prim, anyp = (np.asarray(x) for x in warp_levels(merged, o, d, tmin, tmax, level))
    assert not (prim[INVALID] >= 0).any()
    for lv, (V, F, off) in enumerate([(V0, F0, 0), (V1, F1, len(F0))]):
        sel = level == lv
        local = np.where(prim[sel] >= 0, prim[sel] - off, -1)
        assert ((local >= -1) & (local < len(F))).all()  # a face of its own level
        t_ref, _, t_all = brute_force_closest_hit(V, F, o[sel], d[sel], tmin[sel], tmax[sel])
        assert np.mean((local >= 0) == np.isfinite(t_ref)) >= 0.999
        both = (local >= 0) & np.isfinite(t_ref)
        assert both.sum() > 0.2 * sel.sum()
        tol = np.maximum(RTOL * np.abs(t_ref[both]), ATOL)
        assert (np.abs(t[sel][both] - t_ref[both]) <= tol).all()
        assert (np.abs(t_all[np.flatnonzero(both), local[both]] - t_ref[both]) <= tol).all()
    assert np.array_equal(anyp >= 0, prim >= 0)
    # The JAX traversal with the same levels.
    _, pj = jax_query(merged, o, d, tmin, tmax, jnp.asarray(level))
    assert np.mean(np.asarray(pj) == prim) >= 0.999
    # No level on a merged BVH is level 0, as in the JAX traversal.
    _, p0, _ = warp_levels(merged, o, d, tmin, tmax, np.zeros(N, np.int32))
    t_none, p_none = jax.jit(lambda *a: warp_query(merged, *a, None, any_hit=False))(o, d, tmin, tmax)
    assert np.array_equal(np.asarray(p_none), np.asarray(p0))


def test_level_needs_a_merged_bvh(soup):
    o, d, tmin, tmax = _rays(1)
    with pytest.raises(ValueError, match="merged BVH"):
        warp_query(soup[2], o, d, tmin, tmax, np.zeros(N, np.int32), any_hit=False)


def test_exports_for_cuda_without_a_gpu(soup):
    """The same program lowers for CUDA on a machine without one (Warp's FFI target is registered
    for both platforms), and for CPU and CUDA at once."""
    from jax import export

    bvh = soup[2]
    o, d, tmin, tmax = (jax.ShapeDtypeStruct(x.shape, x.dtype) for x in _rays(1))
    args = (bvh, o, d, tmin, tmax)
    # Warp's FFI targets carry no compatibility guarantee across versions: export says so unless
    # told (an exported program also needs this process's Warp registrations to run).
    checks = [export.DisabledSafetyCheck.custom_call(name) for name in ffi_target_names()]
    for platforms in (("cuda",), ("cpu", "cuda")):
        exp = export.export(warp_both, platforms=platforms, disabled_checks=checks)(*args)
        assert exp.platforms == platforms
        text = exp.mlir_module()
        assert all(name in text for name in ffi_target_names())
