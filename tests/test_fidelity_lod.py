"""Geometry level of detail per region (`Fidelity.lod`): a merged BVH traces each ray against its
own level (brute force per level is the oracle), the default frame is today's bit for bit, a
coarse level in the outside region puts its hits on that level's triangles and leaves the fovea
alone, and bad values fail before any compile."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _frames import assert_same_radiance

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


def test_gradients_at_level_zero_match_the_plain_bvh(levels, merged):
    """The differentiable recompute of the hit (`hit_geometry`) works through a merged BVH: at
    level 0 the gradient w.r.t. the scene's vertices is the plain BVH's, and the other levels'
    vertices (their own copies) get none from level-0 rays."""
    bvh, _ = merged
    plain = build_bvh(levels.scenes[0], cache=False)
    o, d = _rays(300, 6)
    n0 = np.shape(plain.vertices)[0]

    def loss(v, b, **kw):
        t = closest_hit(b, o, d, vertices=v, **kw).t
        return jnp.sum(jnp.where(jnp.isfinite(t), t, 0.0))

    g_plain = jax.grad(loss)(jnp.asarray(plain.vertices), plain)
    g_merged = jax.grad(loss)(jnp.asarray(bvh.vertices), bvh, level=0)
    assert np.abs(np.asarray(g_plain)).sum() > 0
    np.testing.assert_allclose(np.asarray(g_merged)[:n0], np.asarray(g_plain), rtol=1e-5, atol=1e-6)
    assert not np.asarray(g_merged)[n0:].any()


def test_level_argument_errors(levels, merged):
    bvh, _ = merged
    o, d = _rays(8, 4)
    with pytest.raises(ValueError, match="merged BVH"):
        closest_hit(build_bvh(levels.scenes[0], cache=False), o, d, level=0)
    # level= is no error on a native backend: Embree traces the level's own tree.
    np.testing.assert_array_equal(
        np.asarray(occluded(bvh, o, d, backend="embree", level=1)),
        np.asarray(occluded(bvh, o, d, backend="jax", level=1)),
    )
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


# ---- the foveated frame ------------------------------------------------------------------------

from fovjax.foveate import Fidelity, Foveation, render_foveated  # noqa: E402
from fovjax.foveate import _lod as fov_lod  # noqa: E402
from fovjax.render import TRACE_COUNTS, RenderConfig, StereoRig, stereo_sample_rays  # noqa: E402
from fovjax.scene import make_materials, make_scene  # noqa: E402

CONFIG = RenderConfig(max_depth=2)
FULL = Fidelity()
GAZE = ((0.5, 0.5), (0.5, 0.5))


@pytest.fixture(scope="module")
def spheres_rig(levels):
    scene = levels.scenes[0]
    return scene, StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=48, eye_height=32)


def _render(scene, rig, levels, fidelity=None, gaze=GAZE, config=CONFIG, **kwargs):
    f = Foveation.thesis(0, fidelity=fidelity, **kwargs)
    return render_foveated(
        scene, rig, gaze=gaze, foveation=f, key=jax.random.key(3), config=config, lod_levels=levels
    )


def _counts(frame):
    s = frame.stats
    return (s.primary_rays, s.shadow_rays, s.reflection_rays)


def _fovea(frame):
    return np.concatenate([frame.regions[0], frame.regions[1]], axis=1) == 0


@pytest.fixture(scope="module")
def plain(spheres_rig, levels):
    return _render(*spheres_rig, levels)


def test_default_lod_is_bit_identical(spheres_rig, levels, plain):
    for lod in (None, 0):
        frame = _render(*spheres_rig, levels, fidelity=(Fidelity(lod=lod),) * 3)
        assert np.array_equal(frame.image, plain.image)
        assert _counts(frame) == _counts(plain)


def test_level_zero_through_the_merged_bvh_is_the_same_frame(spheres_rig, levels, plain, monkeypatch):
    """The merged scene, BVH and per-ray levels themselves change nothing at level 0: every
    region forced to level 0 of all four merged levels, in a fresh compile (another program: the
    same to float32 rounding)."""
    used = []

    def zeros(foveation, tables, bvh, cameras):
        used.append(1)
        return jnp.zeros(3, jnp.int32)

    monkeypatch.setattr(fov_lod, "region_levels", zeros)
    fovjax.render.clear_compile_cache()
    try:
        frame = _render(*spheres_rig, levels, fidelity=(Fidelity(lod="auto"),) * 3)
    finally:
        fovjax.render.clear_compile_cache()
    assert used
    assert_same_radiance(frame.image, plain.image)
    assert _counts(frame) == _counts(plain)


def test_coarse_outside_leaves_the_fovea_alone(spheres_rig, levels, plain):
    frame = _render(*spheres_rig, levels, fidelity=(FULL, FULL, Fidelity(lod=3)))
    fovea = _fovea(plain)
    assert fovea.any()
    assert_same_radiance(frame.image[fovea], plain.image[fovea])
    outside = np.concatenate([plain.regions[0], plain.regions[1]], axis=1) == 2
    assert np.abs(frame.image - plain.image)[outside].mean() > 1e-3  # level 3 visibly differs
    assert frame.stats.primary_rays == plain.stats.primary_rays


def test_fovea_tile_packets_straddling_levels(spheres_rig, levels):
    """With the fovea traced as an 8x8-packet image tile, the tile's corners reach the outside
    region (level 3) while its centre is level 0: packets mixing the two are traced ray by ray,
    and the fovea stays the plain tiled frame's (to float32 rounding: another program)."""
    primary = RenderConfig(max_depth=0)  # the packets' levels are the primary rays' (a shorter compile)
    tiled = _render(*spheres_rig, levels, fovea_tile_deg=5.0, config=primary)
    frame = _render(
        *spheres_rig, levels, fidelity=(FULL, FULL, Fidelity(lod=3)), fovea_tile_deg=5.0, config=primary
    )
    fovea = _fovea(tiled)
    assert_same_radiance(frame.image[fovea], tiled.image[fovea])
    assert np.abs(frame.image - tiled.image).max() > 1e-3


def test_gaze_change_does_not_recompile(spheres_rig, levels):
    fidelity = (FULL, Fidelity(lod=1), Fidelity(lod="auto"))
    _render(*spheres_rig, levels, fidelity=fidelity)
    before = TRACE_COUNTS["foveated"]
    frame = _render(*spheres_rig, levels, fidelity=fidelity, gaze=((0.2, 0.3), (0.25, 0.3)))
    assert TRACE_COUNTS["foveated"] == before
    assert frame.stats.compile_seconds == 0.0


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    """An emissive red icosphere (1280 triangles) on the background, no lights, and its levels
    (1, 0.1): a pixel is red exactly where its ray hits, so the hit mask is read off the image."""
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    scene = make_scene(
        np.asarray(mesh.vertices, np.float32),
        np.asarray(mesh.faces, np.int32),
        materials=make_materials([{"kd": (0.0, 0.0, 0.0), "ke": (1.0, 0.0, 0.0)}]),
        ambient=(0.0, 0.0, 0.0),
    )
    ball_levels = lod_levels(scene, (1.0, 0.1), cache_dir=tmp_path_factory.mktemp("ball"))
    rig = StereoRig.look_at((0.0, 0.0, 3.2), (0.0, 0.0, 0.0), eye_width=128, eye_height=96)
    return scene, rig, ball_levels


def test_outside_hits_lie_on_the_coarse_level(ball):
    """Gaze on the ball's left edge: the outside region (its right part and silhouette) is traced
    against level 1, the fovea against the scene: each traced sample hits exactly where brute
    force against its region's level's triangles says, and level 1's silhouette differs from the
    scene's on some of them (the test can fail)."""
    scene, rig, ball_levels = ball
    config = RenderConfig(max_depth=0)
    gaze = ((0.22, 0.5), (0.22, 0.5))
    f = Foveation.thesis(0, fidelity=(FULL, FULL, Fidelity(lod=1)))
    frame = render_foveated(scene, rig, gaze=gaze, foveation=f, config=config, lod_levels=ball_levels)
    plain = render_foveated(scene, rig, gaze=gaze, foveation=Foveation.thesis(0), config=config)
    rays = stereo_sample_rays(rig, None, 1, None)
    o = np.asarray(rays.origins)[:, 0].reshape(-1, 3)
    d = np.asarray(rays.directions)[:, 0].reshape(-1, 3)
    traced = np.asarray(frame.sample_mask)[:, 0].reshape(-1)
    region = np.asarray(frame.regions).reshape(-1)
    red = np.asarray(frame.outputs.prefill)[..., 1].reshape(-1) < 0.01  # background has green 0.55
    red_plain = np.asarray(plain.outputs.prefill)[..., 1].reshape(-1) < 0.01
    for k, level in ((0, 0), (2, 1)):
        sel = traced & (region == k)
        assert sel.sum() > 100
        coarse = ball_levels.scenes[level]
        t_ref, _, _ = brute_force_closest_hit(coarse.vertices, coarse.faces, o[sel], d[sel])
        assert np.sum(red[sel] != np.isfinite(t_ref)) <= 1  # a ray through an edge may go either way
    sel = traced & (region == 2)
    fine, _, _ = brute_force_closest_hit(scene.vertices, scene.faces, o[sel], d[sel])
    coarse, _, _ = brute_force_closest_hit(
        ball_levels.scenes[1].vertices, ball_levels.scenes[1].faces, o[sel], d[sel]
    )
    assert np.sum(np.isfinite(fine) != np.isfinite(coarse)) >= 3
    fovea = (region == 0) & traced
    assert np.array_equal(red[fovea], red_plain[fovea])


def test_auto_distance_is_a_lower_bound(spheres_rig, levels):
    from fovjax.render.internal import bvh_for
    from fovjax.scene import surface_distance

    scene, _ = spheres_rig
    merged = merge_bvhs([bvh_for(scene, None)])
    tables = fov_lod.prepare_levels(
        scene, fovjax.render.scene_arrays(scene), bvh_for(scene, None), levels, 0, 1.0
    )[2]
    rng = np.random.default_rng(7)
    eyes = rng.uniform((-5, 0.2, -5), (5, 4, 5), (40, 3)).astype(np.float32)
    bound = np.array([float(fov_lod.nearest_distance(tables, merged, e)) for e in eyes])
    exact = surface_distance(eyes, scene.vertices, scene.faces)  # an upper bound of the exact distance
    assert (bound <= exact + 1e-5).all()
    assert np.median(bound / exact) > 0.5  # and not trivially 0


def test_auto_levels_by_hand(tmp_path):
    """errors (0, 1 cm, 1 m), the floor 2 m below the eyes (bounded from their midpoint: 1.97 m),
    10 pixels per degree (6'): level 1 subtends 17.5', level 2 26.9°. The thesis model's MAR is
    1.09' at 0°, 5.67' at 5° and 25.5' at 10°: fovea and periphery keep level 0 (17.5' > 6'),
    outside takes level 1."""
    floor = make_scene(
        np.array([[-50, 0, -50], [50, 0, -50], [50, 0, 50], [-50, 0, 50]], np.float32),
        np.array([[0, 2, 1], [0, 3, 2]], np.int32),
    )
    bvh = merge_bvhs([build_bvh(floor, cache=False)])
    tables = fov_lod.LODTables(
        boxes=fov_lod._group_boxes(build_bvh(floor, cache=False)),
        num_vertices=4,
        num_triangles=2,
        errors=(0.0, 0.01, 1.0),
        pixels_per_degree=10.0,
    )

    class Eye:
        def __init__(self, x):
            self.position = np.array([x, 2.0, 0.0], np.float32)

    f = Foveation.thesis(0, fidelity=(Fidelity(lod="auto"),) * 3)
    levels = np.asarray(fov_lod.region_levels(f, tables, bvh, (Eye(-0.03), Eye(0.03))))
    assert levels.tolist() == [0, 0, 1]


@pytest.mark.parametrize("lod", [-1, "coarse", True, 1.5])
def test_bad_lod_values(lod):
    with pytest.raises(ValueError, match="Fidelity.lod"):
        Fidelity(lod=lod)


def test_bad_levels_fail_before_compiling(spheres_rig, levels):
    scene, rig = spheres_rig
    before = TRACE_COUNTS["foveated"]
    with pytest.raises(ValueError, match=r"\(outside\): lod 4 is out of range: the scene has 4 levels"):
        _render(scene, rig, levels, fidelity=(FULL, FULL, Fidelity(lod=4)))
    with pytest.raises(ValueError, match="acuity model"):
        _render(
            scene,
            rig,
            levels,
            fidelity=(FULL, Fidelity(lod="auto"), FULL),
            acuity=fovjax.foveate.LinearFalloff(),
        )
    with pytest.raises(ValueError, match="needs a fovjax.Scene"):
        render_foveated(
            fovjax.render.scene_arrays(scene),
            rig,
            foveation=Foveation.thesis(0, fidelity=(FULL, FULL, Fidelity(lod=1))),
            config=CONFIG,
            bvh=fovjax.render.internal.bvh_for(scene, None),
            lod_levels=levels,
        )
    other = lod_levels(fovjax.scenes.cornell_box(), (1.0,))
    with pytest.raises(ValueError, match="another scene"):
        _render(scene, rig, other, fidelity=(FULL, FULL, Fidelity(lod=1)))
    assert TRACE_COUNTS["foveated"] == before


def test_levels_without_fast_simplification(spheres_rig, monkeypatch, tmp_path):
    """No cached levels and no decimator: the message names the extra to install."""
    import sys

    scene, rig = spheres_rig
    monkeypatch.setitem(sys.modules, "fast_simplification", None)
    monkeypatch.setenv("FOVJAX_CACHE_DIR", str(tmp_path))
    with pytest.raises(ImportError, match=r"fovjax\[lod\]"):
        _render(scene, rig, None, fidelity=(FULL, FULL, Fidelity(lod=1)))


def test_frame_program_without_levels_refuses_a_lod_fidelity(spheres_rig):
    scene, rig = spheres_rig
    from fovjax.foveate.internal import FrameOptions, foveated_stereo
    from fovjax.render import scene_arrays
    from fovjax.render.internal import bvh_for

    f = Foveation.thesis(0, fidelity=(FULL, FULL, Fidelity(lod=1)))
    with pytest.raises(ValueError, match="levels of detail"):
        foveated_stereo(
            scene_arrays(scene),
            bvh_for(scene, None),
            rig,
            np.zeros(3, np.float32),
            np.full((2, 2), 0.5, np.float32),
            jax.random.key(0),
            f,
            options=FrameOptions(spp=1, jitter=False, config=CONFIG, budget=2 * 48 * 32),
        )
