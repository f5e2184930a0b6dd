"""Ray queries against oracles: brute force on small meshes, Embree on the built-in scenes.

Tolerances (perf-notes.md: float32 distances disagree between any two tracers by rounding, so
distances are compared with an absolute floor): t within 1e-4 relative or 1e-5 absolute;
`prim` compared only where the nearest hit is unambiguous (the second-nearest face is more
than that tolerance further away).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import _extras
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import fovjax
from fovjax.trace import brute_force_closest_hit, build_bvh, closest_hit, hit_geometry, occluded

RTOL, ATOL = 1e-4, 1e-5
# Every backend against the same oracles: the JAX traversal (the reference) and Embree through
# its FFI handler (tests/test_trace_native.py checks the handler built; NVIDIA Warp has its own
# file, tests/test_trace_warp.py).
BACKENDS = ["jax", "embree"]
TRAVERSALS = [
    pytest.param({"backend": b, **opts}, id=f"{b}-{name}")
    for b in BACKENDS
    for name, opts in (("single", {}), ("packet16", {"packet": 16}))
]
# packet="sorted" (rays regrouped by origin, then packets) against brute force here; against
# the one-by-one traversal, ray for ray, in tests/test_trace_sorted.py.
WITH_SORTED = [
    *TRAVERSALS,
    *(pytest.param({"backend": b, "packet": "sorted"}, id=f"{b}-sorted") for b in BACKENDS),
]


def t_close(a, b):
    return np.abs(a - b) <= np.maximum(RTOL * np.abs(b), ATOL)


def assert_matches_brute_force(V, F, o, d, hit, tmin=0.0, tmax=np.inf):
    t_ref, prim_ref, t_all = brute_force_closest_hit(V, F, o, d, tmin, tmax)
    t = np.asarray(hit.t).reshape(-1)
    prim = np.asarray(hit.prim).reshape(-1)
    ref_hit = np.isfinite(t_ref)
    # A float64 hit exactly on an edge may be a float32 miss (or vice versa): exclude rays whose
    # reference hit is within a hair of a triangle's edge (the margin below).
    assert np.mean(np.isfinite(t) == ref_hit) >= 0.9999, "hit/miss disagreement"
    both = np.isfinite(t) & ref_hit
    assert t_close(t[both], t_ref[both]).all(), np.max(np.abs(t[both] - t_ref[both]))
    second = np.sort(t_all, axis=1)[:, 1] if t_all.shape[1] > 1 else np.full(len(t), np.inf)
    with np.errstate(invalid="ignore"):  # inf - inf where a ray misses everything
        clear = both & (second - t_ref > RTOL * np.abs(t_ref) + ATOL)
    assert (prim[clear] == prim_ref[clear]).all()


@pytest.fixture(scope="module")
def soup():
    rng = np.random.default_rng(0)
    centres = rng.uniform(-2, 2, (300, 1, 3))
    V = (centres + rng.normal(0, 0.3, (300, 3, 3))).reshape(-1, 3).astype(np.float32)
    F = np.arange(900).reshape(300, 3)
    return V, F, build_bvh(vertices=V, faces=F, cache=False)


@pytest.mark.parametrize("opts", WITH_SORTED)
def test_random_soup_matches_brute_force(soup, opts):
    V, F, bvh = soup
    rng = np.random.default_rng(1)
    o = rng.uniform(-3, 3, (4000, 3)).astype(np.float32)
    d = rng.normal(size=(4000, 3)).astype(np.float32)
    assert_matches_brute_force(V, F, o, d, closest_hit(bvh, o, d, **opts))


@pytest.mark.parametrize("opts", TRAVERSALS)
def test_tmin_tmax_bounds(soup, opts):
    V, F, bvh = soup
    rng = np.random.default_rng(2)
    o = rng.uniform(-3, 3, (2000, 3)).astype(np.float32)
    d = rng.normal(size=(2000, 3)).astype(np.float32)
    tmin = rng.uniform(0, 1.5, 2000).astype(np.float32)
    tmax = (tmin + rng.uniform(0, 3, 2000)).astype(np.float32)
    hit = closest_hit(bvh, o, d, tmin, tmax, **opts)
    assert_matches_brute_force(V, F, o, d, hit, tmin, tmax)
    t = np.asarray(hit.t)
    ok = np.isfinite(t)
    assert (t[ok] > tmin[ok] * (1 - RTOL) - ATOL).all() and (t[ok] < tmax[ok] * (1 + RTOL) + ATOL).all()


@pytest.mark.parametrize("opts", WITH_SORTED)
def test_occluded_agrees_with_closest_hit(soup, opts):
    V, F, bvh = soup
    rng = np.random.default_rng(3)
    o = rng.uniform(-3, 3, (3000, 3)).astype(np.float32)
    d = rng.normal(size=(3000, 3)).astype(np.float32)
    tmax = rng.uniform(0.1, 4, 3000).astype(np.float32)
    t_ref, _, _ = brute_force_closest_hit(V, F, o, d, 0.0, tmax)
    occ = np.asarray(occluded(bvh, o, d, tmax, **opts))
    assert np.mean(occ == np.isfinite(t_ref)) >= 0.9999


@pytest.mark.parametrize("opts", TRAVERSALS)
def test_batch_shapes_and_invalid_rays(soup, opts):
    """Invalid rays (a zero or NaN direction, an infinite origin, an empty interval) miss, one
    by one and inside packets (30 rays: a full packet of 16 and a partial one)."""
    V, F, bvh = soup
    backend = opts["backend"]
    rng = np.random.default_rng(4)
    o = rng.uniform(-3, 3, (2, 3, 5, 3)).astype(np.float32)
    d = rng.normal(size=(2, 3, 5, 3)).astype(np.float32)
    d[0, 0, 0] = 0.0
    d[0, 0, 1] = np.nan
    o[0, 0, 2] = np.inf
    # A ray that hits the soup, given an empty interval (tmax == tmin): a miss.
    t_ref, _, _ = brute_force_closest_hit(V, F, o[1].reshape(-1, 3), d[1].reshape(-1, 3))
    k = int(np.flatnonzero(np.isfinite(t_ref))[0])
    o[0, 0, 3], d[0, 0, 3] = o[1].reshape(-1, 3)[k], d[1].reshape(-1, 3)[k]
    tmin = np.zeros((2, 3, 5), np.float32)
    tmax = np.full((2, 3, 5), np.inf, np.float32)
    tmin[0, 0, 3] = tmax[0, 0, 3] = 0.5 * t_ref[k]
    hit = closest_hit(bvh, o, d, tmin, tmax, **opts)
    assert hit.t.shape == hit.prim.shape == hit.u.shape == (2, 3, 5)
    assert (np.asarray(hit.prim)[0, 0, :4] == -1).all() and np.isinf(np.asarray(hit.t)[0, 0, :4]).all()
    assert not np.isnan(np.asarray(hit.t)).any()
    assert np.isfinite(np.asarray(closest_hit(bvh, o[0, 0, 3], d[0, 0, 3], backend=backend).t))
    flat = closest_hit(bvh, o.reshape(-1, 3), d.reshape(-1, 3), tmin.reshape(-1), tmax.reshape(-1), **opts)
    np.testing.assert_array_equal(np.asarray(flat.prim), np.asarray(hit.prim).reshape(-1))
    occ = occluded(bvh, o, d, tmax, tmin=tmin, **opts)
    assert occ.shape == (2, 3, 5) and not np.asarray(occ)[0, 0, :4].any()


@pytest.mark.no_typecheck
def test_bad_arguments(soup):
    _, _, bvh = soup
    with pytest.raises(ValueError, match="backend"):
        closest_hit(bvh, np.zeros((1, 3)), np.ones((1, 3)), backend="optix")
    with pytest.raises(ValueError, match="dimension of 3"):
        closest_hit(bvh, np.zeros((4, 2)), np.ones((4, 2)))
    with pytest.raises(ValueError, match="packet"):
        closest_hit(bvh, np.zeros((1, 3)), np.ones((1, 3)), packet=0)
    with pytest.raises(ValueError, match="'sorted'.*'morton'"):
        occluded(bvh, np.zeros((1, 3)), np.ones((1, 3)), packet="morton")
    with pytest.raises(ValueError, match="2 batch dimensions"):
        closest_hit(bvh, np.zeros((5, 3)), np.ones((5, 3)), packet=(2, 2))


def test_annotations_hold_for_numpy_and_broadcast_arguments(soup):
    """closest_hit and occluded under jaxtyping's runtime checker: NumPy arrays, a direction
    broadcast against many origins and scalar or per-ray bounds are what the annotations admit,
    and the result has the broadcast batch shape; a trailing dimension other than 3 is refused."""
    beartype = _extras.require("beartype").beartype
    from jaxtyping import TypeCheckError, jaxtyped

    _, _, bvh = soup
    checked_hit = jaxtyped(typechecker=beartype)(closest_hit)
    checked_occ = jaxtyped(typechecker=beartype)(occluded)
    o = np.zeros((4, 5, 3), np.float32)
    d = np.array([0.0, 0.0, 1.0], np.float64)
    hit = checked_hit(bvh, o, d, 0.0, np.full((4, 5), 10.0, np.float32))
    assert hit.t.shape == hit.prim.shape == (4, 5)
    assert checked_occ(bvh, o, d[None, None], np.float32(10.0)).shape == (4, 5)
    with pytest.raises(TypeCheckError):
        checked_hit(bvh, np.zeros((4, 2)), np.ones((4, 2)))


@pytest.mark.parametrize("backend", BACKENDS)
def test_tile_packets_restore_image_order(backend):
    scene = fovjax.scenes.spheres()
    bvh = build_bvh(scene, cache=False)
    cam = fovjax.Camera.from_pose(fovjax.scenes.default_camera(scene), width=37, height=29)
    o, d = cam.primary_rays()
    single = closest_hit(bvh, o, d, backend=backend)
    tiled = closest_hit(bvh, o, d, packet=(8, 8), backend=backend)
    np.testing.assert_array_equal(np.asarray(single.prim), np.asarray(tiled.prim))
    np.testing.assert_array_equal(np.asarray(single.t), np.asarray(tiled.t))
    np.testing.assert_array_equal(
        np.asarray(occluded(bvh, o, d, backend=backend)),
        np.asarray(occluded(bvh, o, d, packet=(8, 8), backend=backend)),
    )


# --- watertightness on closed meshes ---------------------------------------------------------


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    V, F = m.vertices.astype(np.float32), m.faces.astype(np.int32)
    return V, F, build_bvh(vertices=V, faces=F, cache=False)


@pytest.mark.parametrize("opts", TRAVERSALS)
def test_no_leaks_through_vertices_and_edges(sphere, opts):
    """Rays from inside aimed exactly at shared vertices and edge midpoints must all hit."""
    V, F, bvh = sphere
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    targets = np.concatenate([V, 0.5 * (V[edges[:, 0]] + V[edges[:, 1]])]).astype(np.float32)
    rng = np.random.default_rng(5)
    for origin in [np.zeros(3), rng.uniform(-0.3, 0.3, 3), rng.uniform(-0.3, 0.3, 3)]:
        o = np.broadcast_to(origin, targets.shape).astype(np.float32)
        d = (targets - o).astype(np.float32)
        hit = closest_hit(bvh, o, d, **opts)
        assert (np.asarray(hit.prim) >= 0).all(), "a ray leaked through a shared vertex or edge"
        assert np.asarray(occluded(bvh, o, d, **opts)).all()
        # From outside, aimed at the same points: never a miss either.
        o_out = (targets * 3.0).astype(np.float32)
        assert (np.asarray(closest_hit(bvh, o_out, -targets, **opts).prim) >= 0).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_axis_parallel_rays(sphere, backend):
    V, F, bvh = sphere
    axes = np.concatenate([np.eye(3), -np.eye(3)]).astype(np.float32)
    rng = np.random.default_rng(6)
    o = rng.uniform(-0.5, 0.5, (600, 3)).astype(np.float32)
    d = np.repeat(axes, 100, axis=0)
    o[::7, :] = 0.0  # rays starting exactly on the slab planes of the root's children
    hit = closest_hit(bvh, o, d, backend=backend)
    assert (np.asarray(hit.prim) >= 0).all()
    assert_matches_brute_force(V, F, o, d, hit)


@pytest.mark.parametrize("backend", BACKENDS)
def test_rays_starting_on_a_surface(sphere, backend):
    """With tmin > 0, a ray leaving its own surface does not hit it; going inwards it hits the
    far side."""
    V, F, bvh = sphere
    rng = np.random.default_rng(7)
    f = rng.integers(0, len(F), 500)
    w = rng.dirichlet(np.ones(3), 500)
    p = np.einsum("nk,nkc->nc", w, V[F[f]]).astype(np.float32)
    n = p / np.linalg.norm(p, axis=1, keepdims=True)
    out = closest_hit(bvh, p, n, tmin=1e-4, backend=backend)
    assert (np.asarray(out.prim) == -1).all()
    inward = closest_hit(bvh, p, -n, tmin=1e-4, backend=backend)
    t = np.asarray(inward.t)
    assert (np.asarray(inward.prim) >= 0).all() and (t > 1.5).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_grazing_rays_match_brute_force(sphere, backend):
    V, F, bvh = sphere
    rng = np.random.default_rng(8)
    # Tangent to the unit sphere at random points: most miss, some clip a facet.
    p = rng.normal(size=(3000, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    tangent = np.cross(p, rng.normal(size=(3000, 3)))
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    o = (p * 0.999 - 2 * tangent).astype(np.float32)
    d = tangent.astype(np.float32)
    assert_matches_brute_force(V, F, o, d, closest_hit(bvh, o, d, backend=backend))


# --- every backend on every built-in scene, against the JAX traversal --------------------------


needs_embree = _extras.needs("embreex")


@pytest.fixture(scope="module", params=["cornell_box", "spheres", "atrium"])
def builtin(request):
    scene = fovjax.scenes.BUILTIN[request.param]()
    return scene, build_bvh(scene)


def scene_rays(scene, seed):
    cam = fovjax.Camera.from_pose(fovjax.scenes.default_camera(scene), width=160, height=128)
    o, d = cam.primary_rays()
    rng = np.random.default_rng(seed)
    lo, hi = scene.bounds
    ro = rng.uniform(lo, hi, (20000, 3)).astype(np.float32)
    rd = rng.normal(size=(20000, 3)).astype(np.float32)
    return {"camera": (np.asarray(o), np.asarray(d)), "random": (ro, rd)}


def assert_same_hits(bvh, o, d, hit, ref, what):
    """Hit/miss and t agree; the face too wherever the hit is unambiguous. Built-in solids
    touch (coplanar faces), so where the faces differ, each must lie on the ray at the same
    distance: a tie, which any tracer may break either way."""
    t, t_ref = np.asarray(hit.t).reshape(-1), np.asarray(ref.t).reshape(-1)
    agree = np.isfinite(t) == np.isfinite(t_ref)
    assert agree.mean() >= 0.9999, f"{what}: hit/miss agreement {agree.mean()}"
    both = np.isfinite(t) & np.isfinite(t_ref)
    assert t_close(t[both], t_ref[both]).mean() >= 0.9999
    prim, prim_ref = np.asarray(hit.prim).reshape(-1), np.asarray(ref.prim).reshape(-1)
    differ = both & (prim != prim_ref)
    t_other, _, _ = hit_geometry(bvh.vertices, bvh.faces, prim_ref, o.reshape(-1, 3), d.reshape(-1, 3))
    tie = t_close(t[differ], np.asarray(t_other)[differ])
    assert tie.all(), f"{what}: {int((~tie).sum())} unambiguous hits on a different face"


@needs_embree
def test_builtin_scenes_every_backend_matches_the_jax_traversal(builtin):
    scene, bvh = builtin
    for kind, (o, d) in scene_rays(scene, 9).items():
        ref = closest_hit(bvh, o, d, backend="jax")
        occ_ref = np.asarray(occluded(bvh, o, d, 5.0, backend="jax")).reshape(-1)
        options = [{}] + ([{"packet": (8, 8)}] if kind == "camera" else [])
        for opts in options:
            hit = closest_hit(bvh, o, d, backend="embree", **opts)
            assert_same_hits(bvh, o, d, hit, ref, f"{scene.name} {kind} {opts}")
            occ = np.asarray(occluded(bvh, o, d, 5.0, backend="embree", **opts)).reshape(-1)
            assert np.mean(occ == occ_ref) >= 0.9999


@needs_embree
def test_embree_pure_callback_fallback_under_jit(soup):
    """The fallback where the FFI handler cannot be built: embreex's own API through
    jax.pure_callback, against brute force."""
    import jax

    from fovjax.trace._embree import embree_query

    V, F, bvh = soup
    rng = np.random.default_rng(10)
    o = rng.uniform(-3, 3, (500, 3)).astype(np.float32)
    d = rng.normal(size=(500, 3)).astype(np.float32)
    tmin = np.full(500, 0.5, np.float32)
    tmax = np.full(500, np.inf, np.float32)
    _, prim = jax.jit(lambda o, d: embree_query(bvh, o, d, tmin, tmax, any_hit=False))(o, d)
    t, u, v = hit_geometry(bvh.vertices, bvh.faces, prim, o, d)
    assert_matches_brute_force(V, F, o, d, fovjax.trace.Hit(t, prim, u, v), tmin, tmax)


SPLIT_SCRIPT = textwrap.dedent(
    """
    import jax, numpy as np
    assert jax.device_count() == 2, jax.devices()
    from fovjax.trace import brute_force_closest_hit, build_bvh, closest_hit, occluded
    rng = np.random.default_rng(0)
    centres = rng.uniform(-2, 2, (200, 1, 3))
    V = (centres + rng.normal(0, 0.3, (200, 3, 3))).reshape(-1, 3).astype(np.float32)
    F = np.arange(600).reshape(200, 3)
    bvh = build_bvh(vertices=V, faces=F, cache=False)
    o = rng.uniform(-3, 3, (999, 3)).astype(np.float32)  # odd: the parts are padded
    d = rng.normal(size=(999, 3)).astype(np.float32)
    t_ref, _, _ = brute_force_closest_hit(V, F, o, d)
    for packet in (None, 16, "sorted"):
        hit = jax.jit(lambda o, d: closest_hit(bvh, o, d, packet=packet, backend="jax"))(o, d)
        assert len(hit.t.sharding.device_set) == 2, hit.t.sharding  # both devices traced
        t = np.asarray(hit.t)
        assert np.mean(np.isfinite(t) == np.isfinite(t_ref)) >= 0.999
        both = np.isfinite(t) & np.isfinite(t_ref)
        assert np.allclose(t[both], t_ref[both], rtol=1e-4, atol=1e-5)
        occ = np.asarray(occluded(bvh, o, d, packet=packet, backend="jax"))
        assert np.mean(occ == np.isfinite(t_ref)) >= 0.999
    print("OK")
    """
)


def test_rays_split_over_two_host_devices():
    """With two CPU devices (JAX_NUM_CPU_DEVICES=2) the rays are traced in two parts, one per
    device, with the same results as the brute-force reference."""
    env = {**os.environ, "JAX_NUM_CPU_DEVICES": "2", "JAX_PLATFORMS": "cpu"}
    result = subprocess.run(
        [sys.executable, "-c", SPLIT_SCRIPT], env=env, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0 and result.stdout.strip().endswith("OK"), result.stderr[-3000:]


@pytest.mark.parametrize("opts", TRAVERSALS)
def test_any_hit_traversal_finds_a_face_on_the_ray_iff_there_is_one(soup, opts):
    """The any-hit traversal (`occluded`, its own kernel) against brute force: the same hit/miss
    as the closest-hit traversal and as every-ray-against-every-triangle, and the face it stops
    at lies on the ray within (tmin, tmax)."""
    from fovjax.trace import Traversal
    from fovjax.trace._packet import traverse_packets
    from fovjax.trace._traverse import Nodes, traverse

    V, F, bvh = soup
    rng = np.random.default_rng(7)
    n = 4096
    o = rng.uniform(-3, 3, (n, 3)).astype(np.float32)
    d = rng.normal(size=(n, 3)).astype(np.float32)
    tmin = rng.uniform(0, 1, n).astype(np.float32)
    tmax = (tmin + rng.uniform(0, 4, n)).astype(np.float32)
    nodes = Nodes(jnp.asarray(bvh.table), bvh.num_nodes, bvh.stack_size)
    args = (nodes, *map(jnp.asarray, (o, d, tmin, tmax)))
    if "packet" in opts:
        kw = {"packet_size": opts["packet"], "traversal": Traversal(packets=32, steps_per_refill=4)}
        run = traverse_packets
    else:
        kw = {"traversal": Traversal(lanes=512, steps_per_refill=4)}
        run = traverse
    _, prim_any = run(*args, any_hit=True, **kw)
    _, prim_closest = run(*args, any_hit=False, **kw)
    prim_any, prim_closest = np.asarray(prim_any), np.asarray(prim_closest)
    assert ((prim_any >= 0) == (prim_closest >= 0)).all()
    t_ref, _, t_all = brute_force_closest_hit(V, F, o, d, tmin, tmax)
    assert np.mean((prim_any >= 0) == np.isfinite(t_ref)) >= 0.9999
    hit = np.flatnonzero(prim_any >= 0)
    assert hit.size > n // 20  # the test has hits to check (about 12% of the rays)
    on_ray = np.isfinite(t_all[hit, prim_any[hit]])  # brute force: within (tmin, tmax)
    assert np.mean(on_ray) >= 0.9999
