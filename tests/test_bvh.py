"""BVH construction: structure invariants, conservative quantised boxes, the disk cache, bad input,
and the differentiable hit recomputation against finite differences."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import fovjax
from fovjax.trace import BuildParams, build_bvh, closest_hit, hit_geometry, last_build_info
from fovjax.trace._wide import ROW_WORDS


def decode_tree(bvh):
    """Host decode of the table: per node its 4 child items and decoded (lo, hi) boxes."""
    table = np.asarray(bvh.table)
    m = int(bvh.num_nodes)
    rows = table[:m]
    origin = rows[:, 0:3].view(np.float32)
    exps = np.stack([(rows[:, 3] >> (8 * a)) & 255 for a in range(3)], 1)
    scale = (exps.astype(np.int32) << 23).view(np.float32)
    lo = np.empty((m, 4, 3), np.float32)
    hi = np.empty((m, 4, 3), np.float32)
    for c in range(4):
        for a in range(3):
            q_lo = ((rows[:, 4 + 2 * a] >> (8 * c)) & 255).astype(np.float32)
            q_hi = ((rows[:, 5 + 2 * a] >> (8 * c)) & 255).astype(np.float32)
            lo[:, c, a] = origin[:, a] + q_lo * scale[:, a]
            hi[:, c, a] = origin[:, a] + q_hi * scale[:, a]
    return table, rows[:, 10:14], lo, hi


def subtree_triangles(table, m, item):
    """Triangle rows below an item."""
    if item >= m:
        out = [item]
        while table[out[-1], 10] == 0:
            out.append(out[-1] + 1)
        return out
    return [t for c in table[item, 10:14] if c >= 0 for t in subtree_triangles(table, m, int(c))]


@pytest.mark.parametrize("n", [1, 2, 3, 7, 100, 3000])
def test_structure_and_conservative_boxes(n):
    rng = np.random.default_rng(n)
    V = rng.uniform(-50, 50, (n, 3, 3)).astype(np.float32)
    V[: n // 2] *= 1e-3  # tiny triangles far from the origin stress the quantisation
    V[: n // 2] += 30.0
    V = V.reshape(-1, 3)
    F = np.arange(3 * n).reshape(n, 3)
    bvh = build_bvh(vertices=V, faces=F, cache=False)
    table, children, lo, hi = decode_tree(bvh)
    m = int(bvh.num_nodes)
    assert table.shape == (m + n, ROW_WORDS)
    # Every triangle appears exactly once, and leaves end with the "last" flag.
    assert sorted(table[m:, 9].tolist()) == list(range(n))
    assert table[-1, 10] == 1
    tri = V[F]
    for node in range(m):
        for c in range(4):
            item = int(children[node, c])
            if item < 0:
                continue
            rows = subtree_triangles(table, m, item)
            corners = tri[table[rows, 9]].reshape(-1, 3)
            assert (corners >= lo[node, c]).all() and (corners <= hi[node, c]).all(), (node, c)


def test_degenerate_layouts_build():
    # All triangles identical (no SAH split separates them) and axis-aligned flat meshes.
    V = np.tile(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32), (50, 1))
    F = np.arange(150).reshape(50, 3)
    bvh = build_bvh(vertices=V, faces=F, cache=False)
    hit = closest_hit(bvh, np.array([[0.2, 0.2, 1.0]]), np.array([[0.0, 0.0, -1.0]]))
    assert int(hit.prim[0]) >= 0 and abs(float(hit.t[0]) - 1.0) < 1e-6


def test_build_params_validated():
    with pytest.raises(ValueError, match="bins"):
        BuildParams(bins=1)
    with pytest.raises(ValueError, match="max_leaf_size"):
        BuildParams(max_leaf_size=0)


def test_bad_geometry_is_rejected():
    V = np.zeros((3, 3), np.float32)
    with pytest.raises(ValueError, match="NaN or infinite"):
        build_bvh(vertices=np.array([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]]), faces=[[0, 1, 2]])
    with pytest.raises(ValueError, match="out of range"):
        build_bvh(vertices=V, faces=[[0, 1, 3]])
    with pytest.raises(ValueError, match="no triangles"):
        build_bvh(vertices=V, faces=np.zeros((0, 3), int))
    with pytest.raises(ValueError, match="either a scene or"):
        build_bvh(fovjax.scenes.cornell_box(), vertices=V, faces=[[0, 1, 2]])


def test_disk_cache_roundtrip_and_corruption(tmp_path):
    scene = fovjax.scenes.spheres()
    first = build_bvh(scene, cache_dir=tmp_path)
    assert not last_build_info()["from_cache"]
    second = build_bvh(scene, cache_dir=tmp_path)
    assert last_build_info()["from_cache"]
    np.testing.assert_array_equal(np.asarray(first.table), np.asarray(second.table))
    assert (first.num_nodes, first.stack_size) == (second.num_nodes, second.stack_size)
    # Different build parameters: a different cache entry, not the old tree.
    build_bvh(scene, cache_dir=tmp_path, params=BuildParams(bins=8))
    assert not last_build_info()["from_cache"]
    (path,) = [p for p in tmp_path.glob("*.npz") if p.name.startswith(first.key)]
    # A truncated file is rebuilt with a warning, never trusted.
    path.write_bytes(path.read_bytes()[:100])
    with pytest.warns(UserWarning, match="unreadable|stale or corrupt"):
        third = build_bvh(scene, cache_dir=tmp_path)
    assert not last_build_info()["from_cache"]
    np.testing.assert_array_equal(np.asarray(first.table), np.asarray(third.table))
    # A file whose contents do not match its checksum (bit flipped in the table) likewise.
    with np.load(path) as z:
        table, meta = np.array(z["table"]), z["meta"]
    table[5, 3] ^= 1
    np.savez(path, table=table, meta=meta)
    with pytest.warns(UserWarning, match="stale or corrupt"):
        build_bvh(scene, cache_dir=tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        build_bvh(scene, cache_dir=tmp_path)  # rewritten: clean again
    assert last_build_info()["from_cache"]


# --- gradients through the differentiable re-intersection ------------------------------------


@pytest.fixture(scope="module")
def mesh():
    m = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    V, F = m.vertices.astype(np.float32), m.faces.astype(np.int32)
    return V, F, build_bvh(vertices=V, faces=F, cache=False)


def rays(n, seed):
    rng = np.random.default_rng(seed)
    o = rng.uniform(-0.4, 0.4, (n, 3)).astype(np.float32) + np.array([0, 0, 3], np.float32)
    target = rng.uniform(-0.5, 0.5, (n, 3)).astype(np.float32)
    return o, (target - o).astype(np.float32)


def central_difference(f, x, eps):
    x = np.asarray(x, np.float64)
    g = np.zeros_like(x)
    for i in np.ndindex(x.shape):
        e = np.zeros_like(x)
        e[i] = eps
        g[i] = (f((x + e).astype(np.float32)) - f((x - e).astype(np.float32))) / (2 * eps)
    return g


@pytest.mark.parametrize("wrt", ["origins", "directions", "vertices"])
def test_gradients_match_finite_differences(mesh, wrt):
    """d(sum of t + 2u + 3v)/d(x) by jax.grad against central differences (eps 1e-3, float32):
    agreement to 2e-2 relative to the gradient's largest entry."""
    V, F, bvh = mesh
    o, d = rays(8, 11)
    prim = np.asarray(closest_hit(bvh, o, d).prim)
    assert (prim >= 0).all()

    def loss(x):
        args = {"origins": o, "directions": d, "vertices": V}
        args[wrt] = x
        # Visibility is fixed at the reference hit: the loss is smooth in x around it.
        t, u, v = hit_geometry(args["vertices"], F, prim, args["origins"], args["directions"])
        return jnp.sum(t + 2 * u + 3 * v)

    x0 = {"origins": o, "directions": d, "vertices": V}[wrt]
    g = np.asarray(jax.grad(loss)(jnp.asarray(x0)))
    fd = central_difference(lambda x: float(loss(x)), x0, 1e-3)
    scale = np.abs(fd).max()
    assert scale > 0
    np.testing.assert_allclose(g, fd, atol=2e-2 * scale)


def test_closest_hit_gradient_flows_through_vertices_argument(mesh):
    """jax.grad of closest_hit's t w.r.t. the `vertices` override, under jit, equals the gradient
    of the plain re-intersection (the traversal itself contributes nothing)."""
    V, F, bvh = mesh
    o, d = rays(16, 12)

    @jax.jit
    def loss(verts):
        return jnp.sum(closest_hit(bvh, o, d, vertices=verts).t)

    g = jax.grad(loss)(jnp.asarray(V))
    prim = closest_hit(bvh, o, d).prim
    g_ref = jax.jit(jax.grad(lambda verts: jnp.sum(hit_geometry(verts, F, prim, o, d)[0])))(jnp.asarray(V))
    np.testing.assert_allclose(np.asarray(g), np.asarray(g_ref), rtol=1e-6, atol=1e-6)
    assert np.abs(np.asarray(g)).sum() > 0
    # And w.r.t. ray origins/directions, via jacobian of t.
    jac = jax.jit(jax.jacobian(lambda oo: closest_hit(bvh, oo, d).t))(jnp.asarray(o))
    assert jac.shape == (16, 16, 3) and np.isfinite(np.asarray(jac)).all()


def test_gradients_are_zero_not_nan_on_misses(mesh):
    V, F, bvh = mesh
    o = np.array([[0, 0, 3], [0, 0, 3]], np.float32)
    d = np.array([[0, 0, -1], [0, 1, 0]], np.float32)  # one hit, one miss
    g = jax.grad(
        lambda verts: jnp.sum(jnp.where(jnp.isfinite(t := closest_hit(bvh, o, d, vertices=verts).t), t, 0))
    )(jnp.asarray(V))
    assert np.isfinite(np.asarray(g)).all()


def solve_all_triangles(V, F, o, d):
    """Independent differentiable reference: every ray against every triangle by solving
    o + t d = p0 + u (p1 - p0) + v (p2 - p0) as a 3x3 linear system (not Möller–Trumbore, not
    `hit_geometry`), the nearest t > 0 inside the triangle chosen per ray. Returns (t, u, v, prim,
    margin): margin is the chosen hit's smallest barycentric coordinate (distance from an edge)."""
    tri = V[F]  # (F, 3, 3)
    p0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n_rays, n_faces = o.shape[0], F.shape[0]
    a = jnp.stack(
        [jnp.broadcast_to(-d[:, None], (n_rays, n_faces, 3)), jnp.broadcast_to(e1, (n_rays, n_faces, 3))], -1
    )
    a = jnp.concatenate([a, jnp.broadcast_to(e2[None, :, :, None], (n_rays, n_faces, 3, 1))], -1)
    tuv = jnp.linalg.solve(a, (o[:, None] - p0[None])[..., None])[..., 0]  # (rays, faces, 3)
    t, u, v = tuv[..., 0], tuv[..., 1], tuv[..., 2]
    inside = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    prim = jnp.argmin(jnp.where(inside, jax.lax.stop_gradient(t), jnp.inf), axis=1)
    pick = lambda x: jnp.take_along_axis(x, prim[:, None], 1)[:, 0]  # noqa: E731
    margin = jnp.minimum(jnp.minimum(pick(u), pick(v)), 1 - pick(u) - pick(v))
    hit = pick(inside)
    return pick(t), pick(u), pick(v), jnp.where(hit, prim, -1), jnp.where(hit, margin, -1.0)


@pytest.mark.parametrize("wrt", ["origins", "directions", "vertices"])
def test_closest_hit_gradients_match_an_independent_reference(mesh, wrt):
    """jax.grad of closest_hit's t, u and v (each on its own) w.r.t. origins, directions and
    vertices, against the gradients of the brute-force linear-solve reference above, on rays
    whose hit lies clear of every edge (so both pick the same triangle)."""
    V, F, bvh = mesh
    o, d = rays(24, 13)
    *_, prim_ref, margin = solve_all_triangles(*(jnp.asarray(a) for a in (V, F, o, d)))
    keep = np.asarray(margin) > 1e-3
    assert keep.sum() >= 16  # the fixture's rays: most hit the sphere well inside a face
    o, d = o[keep], d[keep]
    x = {"origins": o, "directions": d, "vertices": V}
    assert (np.asarray(closest_hit(bvh, o, d).prim) == np.asarray(prim_ref)[keep]).all()
    w = np.random.default_rng(3).uniform(0.5, 1.5, len(o)).astype(np.float32)

    for field in range(3):  # t, u, v

        def ours(value, field=field):
            args = dict(x, **{wrt: value})
            hit = closest_hit(bvh, args["origins"], args["directions"], vertices=args["vertices"])
            return jnp.sum(w * (hit.t, hit.u, hit.v)[field])

        def reference(value, field=field):
            args = dict(x, **{wrt: value})
            out = solve_all_triangles(args["vertices"], jnp.asarray(F), args["origins"], args["directions"])
            return jnp.sum(w * out[field])

        g = np.asarray(jax.grad(ours)(jnp.asarray(x[wrt])))
        g_ref = np.asarray(jax.grad(reference)(jnp.asarray(x[wrt])))
        scale = np.abs(g_ref).max()
        assert scale > 0
        np.testing.assert_allclose(g, g_ref, atol=1e-4 * scale, err_msg=f"d{'tuv'[field]}/d{wrt}")
