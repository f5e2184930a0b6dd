"""Geometry level of detail (`fovjax.scene._lod`): decimation keeps what a renderer needs, every
level passes the trace oracle, the error is measured honestly, and the level choice follows the
acuity model.

Oracles: brute-force closest hits (tests/test_trace.py's pattern) on each decimated level; the
one-sided Hausdorff bound against a hand-computed distance; `select_lod` against thresholds worked
out by hand from the thesis model V(ω) = a·exp(−ω/b) + c.
"""

from __future__ import annotations

import math

import _extras
import jax
import numpy as np
import pytest

import fovjax
from fovjax.acuity import THESIS_MODEL, LinearMAR
from fovjax.scene import decimate, geometric_error, lod_levels, select_lod, surface_distance
from fovjax.scene._lod import _point_triangle_distance
from fovjax.trace import build_bvh, closest_hit, last_build_info


def _need_fast_simplification():
    """The `[lod]` extra, or a skip; a failure where CI installs every extra."""
    return _extras.require("fast_simplification")


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("FOVJAX_CACHE_DIR", str(tmp_path / "cache"))


def _grid_plane(n=24, bump=0.0):
    """A unit square in z = 0 as an n×n grid (2n² triangles), optionally a smooth bump; two
    materials (left and right half) and a per-vertex UV = (x, y)."""
    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1))
    z = bump * np.exp(-((x - 0.5) ** 2 + (y - 0.5) ** 2) / 0.05)
    v = np.stack([x, y, z], -1).reshape(-1, 3).astype(np.float32)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    f = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    centre_x = v[f].mean(axis=1)[:, 0]
    fm = (centre_x > 0.5).astype(np.int32)
    materials = fovjax.make_materials([{"name": "left", "kd": (1, 0, 0)}, {"name": "right", "kr": 0.5}])
    normals = np.tile(np.float32([0, 0, 1]), (len(v), 1))
    return fovjax.make_scene(
        v, f, face_material=fm, materials=materials, normals=normals, uvs=v[:, :2].copy(), name="plane"
    )


# --- decimate ---------------------------------------------------------------------------------


def test_ratio_one_returns_the_scene_unchanged():
    scene = fovjax.scenes.cornell_box()
    assert decimate(scene, 1.0) is scene
    assert decimate(scene, target_triangles=scene.num_triangles) is scene
    levels = lod_levels(scene, (1.0,))
    assert levels.scenes[0] is scene and levels.errors == (0.0,)


@pytest.mark.no_typecheck  # wrong types on purpose: the function's own check answers
@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"ratio": 0.0}, r"ratio must be in \(0, 1\], got 0.0"),
        ({"ratio": -0.5}, r"ratio must be in \(0, 1\], got -0.5"),
        ({"ratio": 1.5}, r"ratio must be in \(0, 1\], got 1.5"),
        ({"ratio": float("nan")}, r"ratio must be in \(0, 1\]"),
        ({"ratio": "half"}, r"ratio must be a number in \(0, 1\], got 'half'"),
        ({}, "exactly one of ratio and target_triangles"),
        ({"ratio": 0.5, "target_triangles": 4}, "exactly one of ratio and target_triangles"),
        ({"target_triangles": 0}, r"target_triangles must be in \[1, 32\]"),
        ({"target_triangles": 33}, r"target_triangles must be in \[1, 32\]"),
        ({"target_triangles": 2.5}, "target_triangles must be an integer, got 2.5"),
    ],
)
def test_bad_arguments_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        decimate("cornell_box", **kwargs)


@pytest.mark.no_typecheck  # wrong types on purpose: the function's own check answers
def test_unknown_scene_is_refused():
    with pytest.raises(ValueError, match=r"unknown scene 'sponza'.*'atrium', 'cornell_box', 'spheres'"):
        decimate("sponza", 0.5)
    with pytest.raises(ValueError, match="scene must be a Scene or a built-in scene's name, got int"):
        lod_levels(3)
    with pytest.raises(ValueError, match="strictly decreasing"):
        lod_levels("cornell_box", (0.5, 1.0))
    with pytest.raises(ValueError, match=r"ratio must be in \(0, 1\], got 2"):
        lod_levels("cornell_box", (2, 1.0))


def test_decimation_keeps_materials_normals_and_uvs_valid():
    _need_fast_simplification()
    scene = _grid_plane(bump=0.15)
    level = decimate(scene, 0.25)
    assert 0 < level.num_triangles < scene.num_triangles
    assert level.materials is scene.materials and level.lights is scene.lights
    fm = np.asarray(level.face_material)
    assert fm.min() >= 0 and fm.max() < len(scene.materials)
    # Per-material decimation: each material's triangles stay on its own half of the square.
    centre_x = level.triangles().mean(axis=1)[:, 0]
    assert (centre_x[fm == 0] <= 0.5 + 1e-6).all() and (centre_x[fm == 1] >= 0.5 - 1e-6).all()
    # Both materials lose triangles (not all that were asked: their borders are kept).
    before = np.bincount(np.asarray(scene.face_material))
    after = np.bincount(fm, minlength=2)
    assert (0 < after).all() and (after < 0.6 * before).all(), (before, after)
    # Normals carried over: unit, the plane's (all +z); UVs: those of a nearby original vertex,
    # so within a grid cell's diagonal of the vertex's own (x, y).
    n = np.asarray(level.normals)
    np.testing.assert_allclose(n, np.tile([0, 0, 1], (len(n), 1)), atol=1e-6)
    uv, xy = np.asarray(level.uvs), np.asarray(level.vertices)[:, :2]
    assert level.uvs.shape == (len(level.vertices), 2)
    assert np.abs(uv - xy).max() <= 2 * math.sqrt(2) / 24


def test_flat_shaded_box_keeps_each_faces_normal():
    """Duplicated corner vertices (one per face) carry different normals; a decimated vertex takes
    the one agreeing with its own faces, not whichever copy is first."""
    _need_fast_simplification()
    scene = fovjax.scenes.cornell_box()
    for border in (True, False):
        level = decimate(scene, 0.5, preserve_border=border)
        assert level.num_triangles < scene.num_triangles
        v, f, n = np.asarray(level.vertices), np.asarray(level.faces), np.asarray(level.normals)
        geo = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        geo /= np.linalg.norm(geo, axis=1, keepdims=True)
        # Each corner's carried normal is parallel (either side) to its face's own normal, on
        # every triangle lying in a wall (32 triangles to 16 also cuts some corners diagonally,
        # triangles with no original normal to take: `geometric_error` reports those).
        on_wall = np.abs(geo).max(axis=1) > 0.999
        assert on_wall.sum() >= 4
        for c in range(3):
            assert (np.abs(np.einsum("ij,ij->i", n[f[on_wall, c]], geo[on_wall])) > 0.99).all()


def test_separate_quads_sharing_corners_decimate_and_keep_their_shape():
    """The Cornell box's quads (and the atrium's boxes, six separate face grids each) share
    corners only by position; welded for the decimator, a box's edges are creases, not borders
    to keep, so it decimates with `preserve_border` on and keeps its shape exactly."""
    _need_fast_simplification()
    from fovjax.scene import _geometry as g
    from fovjax.scene._scene import make_materials

    mb = g.MeshBuilder()
    g.add_box(mb, (0.0, 0.0, 0.0), (2.0, 1.0, 0.5), (16, 8, 4), 0)
    v, f, n, fm = mb.build()
    box = fovjax.make_scene(v, f, face_material=fm, materials=make_materials([{"name": "stone"}]), normals=n)
    level = decimate(box, 0.1)
    assert level.num_triangles <= 0.1 * box.num_triangles + 1
    assert geometric_error(box, level) < 1e-5
    assert _brute_force_distance(level.vertices, box).max() < 1e-5  # and no point off the box
    # the level is still a closed box: its surface area is the box's
    area = 0.5 * np.linalg.norm(
        np.cross(*(level.triangles()[:, 1:] - level.triangles()[:, :1]).transpose(1, 0, 2)), axis=1
    )
    np.testing.assert_allclose(area.sum(), 2 * (2 * 1 + 1 * 0.5 + 0.5 * 2), rtol=1e-5)


def _fan():
    """A 4 x 1 rectangle in z = 0 with six vertices along its top edge, every triangle joined to
    corner (0, 0): a fan of slivers across the whole rectangle, what border-preserving decimation
    leaves; plus a bent quad whose two triangles are not coplanar."""
    ring = np.array([(0.0, 0.0), (4.0, 0.0)] + [(x, 1.0) for x in np.linspace(4, 0, 6)])
    v = np.concatenate([np.c_[ring, np.zeros(len(ring))], [[10, 0, 0], [11, 0, 0], [11, 1, 0.5], [10, 1, 0]]])
    k = len(ring)
    f = [(0, i, i + 1) for i in range(1, k - 1)] + [(k, k + 1, k + 2), (k, k + 2, k + 3)]
    return v, np.array(f)


def _box_area_sum(v, f):
    tri = v[f]
    d = tri.max(axis=1) - tri.min(axis=1)
    return (2 * (d[:, 0] * d[:, 1] + d[:, 1] * d[:, 2] + d[:, 2] * d[:, 0])).sum()


def test_coplanar_flips_keep_the_surface_and_shrink_the_boxes():
    from fovjax.scene._lod import flip_coplanar

    v, f = _fan()
    out = flip_coplanar(v, f, tol=1e-9)
    assert out.shape == f.shape
    assert _box_area_sum(v, out) < 0.8 * _box_area_sum(v, f)  # smaller boxes than the fan's
    # Delaunay: at every inner edge of the rectangle the two angles facing it sum to at most pi
    flat = out[:-2]
    for i, j in ((0, 1), (1, 2), (2, 0)):
        for t1 in range(len(flat)):
            a, b = flat[t1, i], flat[t1, j]
            for t2 in range(len(flat)):
                if t2 != t1 and {a, b} <= set(flat[t2]):
                    c = next(x for x in flat[t1] if x not in (a, b))
                    d = next(x for x in flat[t2] if x not in (a, b))
                    ang = [
                        np.arccos(
                            np.dot(v[a] - v[e], v[b] - v[e])
                            / np.linalg.norm(v[a] - v[e])
                            / np.linalg.norm(v[b] - v[e])
                        )
                        for e in (c, d)
                    ]
                    assert sum(ang) <= np.pi + 1e-9
    tri, before = v[out], v[f]
    n_out = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n_in = np.cross(before[:, 1] - before[:, 0], before[:, 2] - before[:, 0])
    # same surface: same total area, every triangle still facing +z (no fold-over), no needles
    np.testing.assert_allclose(
        0.5 * np.linalg.norm(n_out, axis=1).sum(), 0.5 * np.linalg.norm(n_in, axis=1).sum()
    )
    flat = out[:-2]
    assert (n_out[: len(flat), 2] > 0).all() and set(flat.reshape(-1)) == set(range(8))
    rng = np.random.default_rng(0)
    w = rng.dirichlet(np.ones(3), 200)
    # every point of the new triangulation lies in the rectangle (with the same total area: it
    # is the rectangle)
    p = np.einsum("nk,tkc->tnc", w, v[flat]).reshape(-1, 3)
    assert (p[:, 0] >= -1e-9).all() and (p[:, 0] <= 4 + 1e-9).all() and (np.abs(p[:, 2]) < 1e-12).all()
    assert (p[:, 1] >= -1e-9).all() and (p[:, 1] <= 1 + 1e-9).all()
    np.testing.assert_array_equal(out[-2:], f[-2:])  # the bent quad keeps its diagonal


def test_flips_make_coarse_levels_cheaper_for_a_bvh(monkeypatch):
    """On the small atrium the decimated level with flips has a smaller total triangle box area
    than the same decimation without, at the same error bound class and triangle count."""
    _need_fast_simplification()
    from fovjax.scene import _lod

    scene = fovjax.scenes.atrium(triangles=8000)
    flipped = decimate(scene, 0.25)
    monkeypatch.setattr(_lod, "FLIP_ROUNDS", 0)
    plain = decimate(scene, 0.25)
    assert flipped.num_triangles == plain.num_triangles
    area = [_box_area_sum(np.asarray(s.vertices, np.float64), np.asarray(s.faces)) for s in (flipped, plain)]
    assert area[0] < area[1]


def test_the_cache_key_follows_the_decimation(monkeypatch):
    from fovjax.scene import _lod

    scene = _grid_plane()
    key = _lod._cache_key(scene, 0.5, True)
    assert _lod._cache_key(scene, 0.5, True) == key
    for name, value in (
        ("FLIP_ROUNDS", 0),
        ("WELD", 1e-3),
        ("FLAT", 1e-3),
        ("MIN_SHARE", 0.1),
        ("FORMAT_VERSION", 99),
    ):
        with monkeypatch.context() as m:
            m.setattr(_lod, name, value)
            assert _lod._cache_key(scene, 0.5, True) != key, name


def _brute_force_distance(points, level):
    tri = level.triangles()
    out = []
    for p in np.asarray(points, np.float32):
        q = np.broadcast_to(p, (len(tri), 3))
        out.append(_point_triangle_distance(q, tri[:, 0], tri[:, 1], tri[:, 2]).min())
    return np.asarray(out)


def test_error_is_an_upper_bound_and_borders_are_kept():
    """Each vertex's `surface_distance` never under-reports (brute force over every triangle),
    and `geometric_error` is the exact maximum. A flat square stays flat and keeps its outline
    with the border kept; without it the corners erode, and the error shows that."""
    _need_fast_simplification()
    flat = _grid_plane()
    kept = decimate(flat, 0.1)
    assert kept.num_triangles < flat.num_triangles
    assert _brute_force_distance(flat.vertices, kept).max() < 1e-5  # every vertex still on it
    assert geometric_error(flat, kept) < 1e-5
    eroded = decimate(flat, 0.1, preserve_border=False)
    true = _brute_force_distance(flat.vertices, eroded)
    assert true.max() > 0.01
    np.testing.assert_allclose(geometric_error(flat, eroded), true.max(), rtol=1e-5)
    bumpy = _grid_plane(bump=0.3)
    for level in (decimate(bumpy, 0.5), decimate(bumpy, 0.1)):
        bound = surface_distance(bumpy.vertices, level.vertices, level.faces)
        true = _brute_force_distance(bumpy.vertices, level)
        assert (bound >= true - 1e-6).all()
        assert 0 < geometric_error(bumpy, level) <= 0.3 + 1e-6  # never more than the bump
        np.testing.assert_allclose(geometric_error(bumpy, level), true.max(), rtol=1e-5)


def test_surface_distance_matches_hand_computed_distances():
    """Points around a single triangle: distances to the face, an edge and a vertex."""
    v = np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    f = np.int32([[0, 1, 2]])
    points = np.float32([[0.2, 0.2, 0.5], [0.5, -1.0, 0.0], [2.0, 0.0, 0.0], [-1, -1, 1], [0.5, 0.5, 0.0]])
    expected = [0.5, 1.0, 1.0, math.sqrt(3), 0.0]
    np.testing.assert_allclose(surface_distance(points, v, f), expected, atol=1e-6)


# --- the chain of levels ----------------------------------------------------------------------


def test_levels_are_cached_and_the_second_call_loads_them():
    _need_fast_simplification()
    scene = _grid_plane(bump=0.2)
    first = lod_levels(scene, (1.0, 0.5, 0.2))
    second = lod_levels(scene, (1.0, 0.5, 0.2))
    assert not first.from_cache and second.from_cache
    assert first.triangles == second.triangles and first.errors == second.errors
    assert first.errors[0] == 0.0 and all(e >= 0 for e in first.errors)
    assert first.triangles[0] > first.triangles[1] > first.triangles[2]
    for a, b in zip(first.scenes, second.scenes, strict=True):
        assert a.content_hash == b.content_hash


@pytest.mark.parametrize("name", ["cornell_box", "atrium"])
def test_every_level_passes_the_trace_oracle(name):
    """Closest hits on each LOD level, through its own (cached) BVH, equal brute force."""
    _need_fast_simplification()
    from test_trace import assert_matches_brute_force

    # The Cornell box with the border let go (the atrium keeps it): both settings traced.
    scene = fovjax.scenes.BUILTIN[name]() if name != "atrium" else fovjax.scenes.atrium(triangles=8000)
    levels = lod_levels(scene, (1.0, 0.5, 0.2), preserve_border=name == "atrium")
    assert len(set(s.content_hash for s in levels.scenes)) == 3
    rng = np.random.default_rng(11)
    lo, hi = scene.bounds
    o = rng.uniform(lo, hi, (1500, 3)).astype(np.float32)
    d = rng.normal(size=(1500, 3)).astype(np.float32)
    for level in levels.scenes:
        bvh = build_bvh(level)
        assert not last_build_info()["from_cache"]
        assert build_bvh(level).num_triangles == level.num_triangles
        assert last_build_info()["from_cache"]  # each level's BVH is cached like the main one
        V, F = np.asarray(level.vertices), np.asarray(level.faces)
        assert_matches_brute_force(V, F, o, d, closest_hit(bvh, o, d))


# --- choosing a level -------------------------------------------------------------------------


def test_select_lod_by_hand():
    """Thesis model at ω = 0: V = a + c = 0.91756, MAR = 1.0898′. Errors subtending 0.5′, 1′, 2′
    and 8′ at distance 1: the coarsest at or under 1.0898′ is level 1 (1′). At 20° V = 0.0182,
    MAR = 54.9′: level 3 (8′). With a 1 pixel-per-degree display (60′ pixels) even the fovea gets
    the coarsest level, the pixel being coarser than the eye."""
    arcmin = np.radians(1 / 60)
    errors = [np.tan(x * arcmin) for x in (0.0, 0.5, 1.0, 2.0, 8.0)]
    ecc = np.float32([0.0, 20.0])
    np.testing.assert_array_equal(select_lod(errors, ecc, 1.0, THESIS_MODEL, 60.0), [2, 4])
    np.testing.assert_array_equal(select_lod(errors, ecc, 1.0, THESIS_MODEL, 1.0), [4, 4])
    # Twice as far, each error subtends half the angle: one level coarser at the fovea.
    np.testing.assert_array_equal(select_lod(errors, 0.0, 2.0, THESIS_MODEL, 60.0), 3)


def test_select_lod_is_monotone_in_eccentricity_and_jits():
    errors = (0.0, 0.001, 0.004, 0.02, 0.1)
    ecc = np.linspace(0, 60, 121, dtype=np.float32)
    for model in (THESIS_MODEL, LinearMAR()):
        levels = np.asarray(select_lod(errors, ecc, 3.0, model, 20.0))
        assert (np.diff(levels) >= 0).all(), levels
        assert levels[0] < levels[-1]
    jitted = jax.jit(lambda e, d: select_lod(errors, e, d, THESIS_MODEL, 20.0))
    np.testing.assert_array_equal(jitted(ecc, 3.0), select_lod(errors, ecc, 3.0, THESIS_MODEL, 20.0))


@pytest.mark.no_typecheck  # wrong types on purpose: the function's own check answers
@pytest.mark.parametrize(
    "args, match",
    [
        (([], 0.0, 1.0, THESIS_MODEL, 20.0), "errors must be a non-empty 1-D sequence"),
        (([0.0, -1.0], 0.0, 1.0, THESIS_MODEL, 20.0), "errors must be a non-empty 1-D sequence"),
        (([0.0, np.nan], 0.0, 1.0, THESIS_MODEL, 20.0), "errors must be a non-empty 1-D sequence"),
        (([0.0], 0.0, 1.0, THESIS_MODEL, 0.0), "pixels_per_degree must be a positive number, got 0.0"),
        (([0.0], 0.0, 1.0, "thesis", 20.0), "acuity must be an acuity model V\\(omega\\), got str"),
    ],
)
def test_select_lod_bad_arguments(args, match):
    with pytest.raises(ValueError, match=match):
        select_lod(*args)


def test_a_corrupt_cache_file_is_rebuilt(tmp_path):
    _need_fast_simplification()
    scene = _grid_plane(bump=0.2)
    first = lod_levels(scene, (1.0, 0.3), cache_dir=tmp_path)
    (cached,) = list(tmp_path.glob("*.npz"))
    cached.write_bytes(b"not an npz")
    again = lod_levels(scene, (1.0, 0.3), cache_dir=tmp_path)
    assert not again.from_cache and again.errors == first.errors
    assert again.scenes[1].content_hash == first.scenes[1].content_hash
    assert lod_levels(scene, (1.0, 0.3), cache_dir=tmp_path).from_cache  # rewritten
