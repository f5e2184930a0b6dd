"""Texture level of detail and samples per pixel per region (`Fidelity.texture_lod`,
`Fidelity.spp`): box-filtered mip pyramids checked by hand, a checkerboard at a coarser level
gives its average exactly where the region asks for it and nowhere else, the ray-cone level
of a head-on plane by hand; a region's samples per pixel drop exactly the sub-samples beyond
its count, the budget shrinks with it; the defaults are today's frames bit for bit; bad values
fail clearly before any compile."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fovjax
from fovjax.foveate import Fidelity, Foveation, render_foveated
from fovjax.foveate import _api as fov_api
from fovjax.foveate.internal import subsample_rank
from fovjax.render import RenderConfig, StereoRig
from fovjax.render._mips import lod_uv, mip_level
from fovjax.render.internal import mip_lookup, mip_shapes, texture_mips
from fovjax.scene import DIRECTIONAL_LIGHT

EYE_W, EYE_H = 48, 32
GAZE = ((0.5, 0.5), (0.5, 0.5))
FULL = Fidelity()
HALF = 4.0  # the plane spans [-4, 4]^2 at z = 0
REPEATS = 4  # texture repeats across it
N = 8  # checker texels per repeat


# ---- mip pyramids ------------------------------------------------------------------------


def test_mip_pyramid_is_the_box_filter():
    t = np.arange(4 * 4 * 3, dtype=np.float32).reshape(4, 4, 3)
    assert mip_shapes(4, 4) == ((4, 4), (2, 2), (1, 1))
    m = texture_mips(t)
    assert m.shape == (16 + 4 + 1, 3)
    np.testing.assert_array_equal(m[:16], t.reshape(-1, 3))
    level1 = t.reshape(2, 2, 2, 2, 3).mean(axis=(1, 3)).reshape(-1, 3)
    np.testing.assert_allclose(m[16:20], level1, rtol=1e-6)
    np.testing.assert_allclose(m[20], t.reshape(-1, 3).mean(0), rtol=1e-6)


def test_mip_pyramid_of_odd_sizes():
    """3 x 5 -> 1 x 2 -> 1 x 1: each level-0 texel in the level texel holding its centre."""
    t = np.random.default_rng(0).random((3, 5, 3)).astype(np.float32)
    assert mip_shapes(3, 5) == ((3, 5), (1, 2), (1, 1))
    m = texture_mips(t)
    # columns 0, 1 (centres 0.1, 0.3) -> left; 2 (0.5) -> right; 3, 4 -> right
    np.testing.assert_allclose(m[15], t[:, :2].reshape(-1, 3).mean(0), rtol=1e-6)
    np.testing.assert_allclose(m[16], t[:, 2:].reshape(-1, 3).mean(0), rtol=1e-6)
    np.testing.assert_allclose(m[17], t.reshape(-1, 3).mean(0), rtol=1e-6)


def test_mip_lookup_levels():
    t = np.random.default_rng(1).random((8, 8, 3)).astype(np.float32)
    m = jnp.asarray(texture_mips(t))
    uv = jnp.array([[0.3, 0.7], [0.0625, 0.0625], [0.9, 0.1]], jnp.float32)
    # level 0 is bilinear_wrap exactly
    level0 = mip_lookup(m, t.shape, jnp.zeros(3), uv)
    np.testing.assert_array_equal(level0, fovjax.render.internal.bilinear_wrap(jnp.asarray(t), uv))
    # at the centre of a level-1 texel, level 1 is that texel (a 2x2 mean)
    centre = jnp.array([[0.375, 0.625]], jnp.float32)  # level-1 texel (row 2, col 1)
    np.testing.assert_allclose(
        mip_lookup(m, t.shape, jnp.ones(1), centre)[0], t[4:6, 2:4].mean((0, 1)), rtol=1e-6
    )
    # halfway between levels: the mean of the two levels' lookups
    half = mip_lookup(m, t.shape, jnp.full(3, 0.5), uv)
    one = mip_lookup(m, t.shape, jnp.ones(3), uv)
    np.testing.assert_allclose(half, 0.5 * (level0 + one), rtol=1e-6)
    # the top level (1 x 1) is the mean, wherever
    np.testing.assert_allclose(
        mip_lookup(m, t.shape, jnp.full(3, 3.0), uv), np.broadcast_to(t.mean((0, 1)), (3, 3)), rtol=1e-5
    )


# ---- the textured plane ------------------------------------------------------------------


@pytest.fixture(scope="module")
def plane():
    """A checkerboard plane facing +z, lit head-on by a white directional light with Kd 1 and
    nothing else: a traced sample's colour is its texture lookup (n·l = 1)."""
    v = np.array([[-HALF, -HALF, 0], [HALF, -HALF, 0], [HALF, HALF, 0], [-HALF, HALF, 0]], np.float32)
    uvs = (v[:, :2] + HALF) / (2 * HALF) * REPEATS
    checker = ((np.arange(N)[:, None] + np.arange(N)[None, :]) % 2).astype(np.float32)
    texture = np.stack([checker, 1 - checker, 0.25 + 0.5 * checker], -1)
    scene = fovjax.make_scene(
        v,
        np.array([[0, 1, 2], [0, 2, 3]]),
        materials=fovjax.make_materials([{"kd": (1.0, 1.0, 1.0), "texture": 0}]),
        lights=fovjax.make_lights([(0.0, 0.0, 1.0)], [(1.0, 1.0, 1.0)], kind=[DIRECTIONAL_LIGHT]),
        uvs=uvs,
        textures=(texture,),
        ambient=(0.0, 0.0, 0.0),
        name="checker-plane",
    )
    rig = StereoRig.look_at(
        (0.0, 0.0, 3.0), (0.0, 0.0, 0.0), eye_width=EYE_W, eye_height=EYE_H, toe_out_deg=0.0
    )
    return scene, rig, texture


# A texture level of detail runs in the JAX integrator (the native one has no mip lookups), and
# these tests compare its frames bit for bit with the plain frame's: both in the JAX integrator
# (with "auto" the plain frame would run the native loop, which rounds its own way).
PLANE_CONFIG = RenderConfig(max_depth=0, integrator="jax")


def _plane_frame(plane, fidelity=None, gaze=GAZE, **kwargs):
    scene, rig, _ = plane
    f = Foveation.thesis(0, fidelity=fidelity, **kwargs)
    return render_foveated(scene, rig, gaze=gaze, foveation=f, config=PLANE_CONFIG)


def _side_by_side(regions):
    return np.concatenate([regions[0], regions[1]], axis=1)


@pytest.fixture(scope="module")
def plane_plain(plane):
    return _plane_frame(plane)


def test_texture_lod_default_is_bit_identical(plane, plane_plain):
    frame = _plane_frame(plane, fidelity=(FULL, FULL, FULL))
    assert np.array_equal(frame.image, plane_plain.image)
    assert plane_plain.image.std() > 0.1  # the checker is resolved at level 0


def test_checker_at_level_one_is_its_average_where_the_region_asks(plane, plane_plain):
    """An 8 x 8 checker of one-texel squares: every level-1 texel is a 2x2 mean, the same
    everywhere, so the periphery and outside samples are exactly the checker's average and
    the fovea is untouched."""
    _, _, texture = plane
    frame = _plane_frame(plane, fidelity=(FULL, Fidelity(texture_lod=1), Fidelity(texture_lod=1)))
    regions = _side_by_side(frame.regions)
    fovea = regions == 0
    assert fovea.any()
    assert np.array_equal(frame.image[fovea], plane_plain.image[fovea])
    prefill = np.asarray(frame.outputs.prefill)
    traced = frame.sample_mask.any(axis=1)
    mean = texture.reshape(-1, 3).mean(0)  # (0.5, 0.5, 0.5)
    for r in (1, 2):
        picked = (frame.regions == r) & traced
        assert picked.any()
        np.testing.assert_allclose(prefill[picked], np.broadcast_to(mean, prefill[picked].shape), atol=1e-6)
    # only the outside coarser: the periphery's samples are the plain frame's
    outside_only = _plane_frame(plane, fidelity=(FULL, FULL, Fidelity(texture_lod=1)))
    plain_prefill = np.asarray(plane_plain.outputs.prefill)
    inside = (outside_only.regions < 2) & traced
    assert np.array_equal(np.asarray(outside_only.outputs.prefill)[inside], plain_prefill[inside])


def test_ray_cone_level_by_hand():
    """Head-on hit of the plane (UV area / world area = 1/4 per triangle, 8 x 8 texels: 16
    texels per m², Δ = ½·log2 16 = 2) at t = 2 with a cone of 0.125 rad: width 0.25 m,
    λ = 2 + log2 0.25 = 0 (one texel per footprint); twice the distance: λ = 1."""
    v = np.array([[-HALF, -HALF, 0], [HALF, -HALF, 0], [HALF, HALF, 0], [-HALF, HALF, 0]], np.float32)
    uvs = (v[:, :2] + HALF) / (2 * HALF) * REPEATS
    scene = fovjax.render.scene_arrays(
        fovjax.make_scene(v, np.array([[0, 1, 2], [0, 2, 3]]), uvs=uvs, name="p"), envmap=None
    )
    prim = jnp.array([0, 1])
    t = jnp.array([2.0, 4.0])
    d = jnp.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    n = jnp.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    lam = lod_uv(scene, prim, t, d, n, jnp.full(2, 0.125))
    level = mip_level((N, N, 3), jnp.zeros(2), jnp.ones(2, bool), lam)
    np.testing.assert_allclose(level, [0.0, 1.0], atol=1e-6)
    # grazing at 60° from the normal: the footprint stretches by 1/cos 60° = 2, one level up
    d60 = jnp.array([[0.0, np.sin(np.pi / 3), -np.cos(np.pi / 3)]] * 2, jnp.float32)
    lam60 = lod_uv(scene, prim, t, d60, n, jnp.full(2, 0.125))
    np.testing.assert_allclose(lam60 - lam, [1.0, 1.0], atol=1e-5)
    # fixed levels add; the pyramid clamps
    np.testing.assert_allclose(
        mip_level((N, N, 3), jnp.array([2.0, 9.0]), jnp.zeros(2, bool), lam), [2.0, 3.0]
    )


def test_auto_level_coarser_with_the_region_spacing(plane, plane_plain):
    """'auto' in every region: the fovea's cone (one pixel) stays at level 0 on this plane (a
    pixel covers under a texel there), so the fovea is the plain frame's; the outside's cone
    is 4 pixels wide, coarse enough to blur the checker: its samples move towards the mean."""
    auto = Fidelity(texture_lod="auto")
    frame = _plane_frame(plane, fidelity=(auto, auto, auto))
    fovea = _side_by_side(frame.regions) == 0
    assert np.array_equal(frame.image[fovea], plane_plain.image[fovea])
    traced = frame.sample_mask.any(axis=1) & (frame.regions == 2)
    plain = np.asarray(plane_plain.outputs.prefill)[traced]
    coarse = np.asarray(frame.outputs.prefill)[traced]
    assert np.abs(coarse - 0.5).mean() < np.abs(plain - 0.5).mean() - 0.01


# ---- samples per pixel per region --------------------------------------------------------


@pytest.fixture(scope="module")
def spheres():
    scene = fovjax.scenes.spheres(subdivisions=1, ground_cells=4)
    return scene, StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=EYE_W, eye_height=EYE_H)


# Per-region spp changes which primary samples are traced: no reflections needed, and a frame
# program without them compiles in about three quarters of the time.
SPP_CONFIG = RenderConfig(max_depth=0)


def _spp_frame(spheres, fidelity=None, gaze=GAZE, **kwargs):
    scene, rig = spheres
    kwargs.setdefault("spp", 4)
    f = Foveation.thesis(0, fidelity=fidelity, **kwargs)
    return render_foveated(scene, rig, gaze=gaze, foveation=f, key=jax.random.key(5), config=SPP_CONFIG)


@pytest.fixture(scope="module")
def spp_plain(spheres):
    return _spp_frame(spheres)


def _allowed(regions, per_region, spp=4):
    rank = subsample_rank(spp)
    return rank[None, :, None, None] < np.asarray(per_region)[regions][:, None]


def test_subsample_order_is_spread():
    assert list(np.argsort(subsample_rank(4))) == [0, 3, 1, 2]  # a diagonal pair first
    assert sorted(subsample_rank(9)) == list(range(9))
    assert list(subsample_rank(1)) == [0]


def test_spp_default_is_bit_identical(spheres, spp_plain):
    for fidelity in ((FULL,) * 3, (Fidelity(spp=4),) * 3):
        frame = _spp_frame(spheres, fidelity=fidelity)
        assert np.array_equal(frame.image, spp_plain.image)
        assert frame.stats.rays == spp_plain.stats.rays
        assert frame.foveation == spp_plain.foveation


@pytest.mark.parametrize("rule", ["either", "thesis-measured"])
def test_spp_per_region_traces_exactly_the_kept_subsamples(spheres, rule):
    plain = _spp_frame(spheres, rule=rule)
    per_region = (4, 1, 2)
    frame = _spp_frame(spheres, fidelity=(FULL, Fidelity(spp=1), Fidelity(spp=2)), rule=rule)
    expected = plain.sample_mask & _allowed(plain.regions, per_region)
    assert np.array_equal(frame.sample_mask, expected)
    by_region = [int(expected.sum(axis=1)[plain.regions == r].sum()) for r in range(3)]
    assert frame.foveation.primary_by_region == tuple(by_region)
    assert frame.stats.primary_rays == sum(by_region)
    assert by_region[0] == plain.foveation.primary_by_region[0]  # fovea untouched
    assert by_region[1] < plain.foveation.primary_by_region[1]
    if rule == "either":
        assert by_region[2] < plain.foveation.primary_by_region[2]
    else:  # "thesis-measured" traces one sample per outside pixel already: spp 2 changes nothing
        assert by_region[2] == plain.foveation.primary_by_region[2]
    fovea = _side_by_side(plain.regions) == 0
    assert np.array_equal(frame.image[fovea], plain.image[fovea])
    assert frame.foveation.dropped == 0


def test_spp_budget_shrinks(spheres, spp_plain):
    """The static budget (planned on the host, before any compile) counts only the samples each
    region's spp may take; one frame checks that the smaller budget drops nothing."""
    _, rig = spheres
    level = np.zeros(3, np.float32)

    def budget(fidelity=None, **kwargs):
        return fov_api._budget_for(rig, level, Foveation.thesis(0, fidelity=fidelity, spp=4, **kwargs))

    assert budget((Fidelity(spp=1),) * 3) == 2 * EYE_W * EYE_H  # every sample a region may take
    assert spp_plain.foveation.budget == budget() == 2 * 4 * EYE_W * EYE_H
    capped = {"max_periphery_deg": 10.0}
    fewer = _spp_frame(spheres, fidelity=(FULL, Fidelity(spp=1), Fidelity(spp=1)), **capped)
    assert fewer.foveation.budget == budget((FULL, Fidelity(spp=1), Fidelity(spp=1)), **capped)
    assert fewer.foveation.budget < budget(**capped)
    assert fewer.foveation.dropped == 0


def test_spp_with_image_tiles(spheres):
    """The fovea tile and the pixel grid trace the same samples under per-region spp."""
    fidelity = (FULL, Fidelity(spp=1), Fidelity(spp=1))
    listed = _spp_frame(spheres, fidelity=fidelity)
    tiled = _spp_frame(spheres, fidelity=fidelity, fovea_tile_deg=5.0, grid_tile=True)
    assert np.array_equal(tiled.sample_mask, listed.sample_mask)
    assert tiled.stats.primary_rays == listed.stats.primary_rays
    np.testing.assert_allclose(tiled.image, listed.image, atol=1e-4)


def test_spp_and_texture_lod_move_with_the_gaze_without_recompiling(spheres, plane):
    f = Foveation.thesis(0, spp=4, fidelity=(FULL, Fidelity(spp=1), Fidelity(spp=2, texture_lod="auto")))
    scene, rig = spheres
    render_foveated(scene, rig, gaze=GAZE, foveation=f, config=SPP_CONFIG)
    traces = fov_api.TRACE_COUNTS["foveated"]
    second = render_foveated(scene, rig, gaze=((0.2, 0.3), (0.25, 0.3)), foveation=f, config=SPP_CONFIG)
    assert fov_api.TRACE_COUNTS["foveated"] == traces
    assert second.stats.compile_seconds == 0.0
    lod = (FULL, Fidelity(texture_lod=2), Fidelity(texture_lod="auto"))
    _plane_frame(plane, fidelity=lod)
    traces = fov_api.TRACE_COUNTS["foveated"]
    again = _plane_frame(plane, fidelity=lod, gaze=((0.3, 0.6), (0.3, 0.6)))
    assert fov_api.TRACE_COUNTS["foveated"] == traces
    assert again.stats.compile_seconds == 0.0


# ---- bad values --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"texture_lod": -1}, r'texture_lod must be None, "auto" or an integer level >= 0, got -1'),
        ({"texture_lod": 1.5}, "texture_lod.*got 1.5"),
        ({"texture_lod": "coarse"}, "texture_lod.*got 'coarse'"),
        ({"texture_lod": True}, "texture_lod.*got True"),
        ({"spp": 0}, "spp must be None or an integer >= 1, got 0"),
        ({"spp": 2.0}, "spp must be None or an integer >= 1, got 2.0"),
        ({"spp": "4"}, "spp must be None or an integer >= 1, got '4'"),
    ],
)
def test_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Fidelity(**kwargs)


def test_spp_above_the_frames_fails_before_any_compile():
    before = dict(fov_api.TRACE_COUNTS)
    with pytest.raises(
        ValueError, match=r"fidelity \(outside\): spp 9 exceeds the frame's spp 4 \(expected 1..4\)"
    ):
        Foveation(spp=4, fidelity=(FULL, FULL, Fidelity(spp=9)))
    with pytest.raises(ValueError, match=r"fidelity \(periphery\): spp 2 exceeds the frame's spp 1"):
        Foveation(fidelity=(FULL, Fidelity(spp=2), FULL))
    assert dict(fov_api.TRACE_COUNTS) == before


def test_batch_frames_equal_render_foveated_with_texture_lod_and_spp(plane):
    """`fovjax.eval.render_foveated_batch` gives the scene its mip pyramids as
    `render_foveated` does: the same frame."""
    from fovjax.eval import render_foveated_batch

    scene, rig, _ = plane
    fidelity = (FULL, Fidelity(texture_lod=1), Fidelity(texture_lod="auto", spp=1))
    f = Foveation.thesis(0, spp=4, fidelity=fidelity)
    single = render_foveated(scene, rig, foveation=f, config=PLANE_CONFIG)
    batch = render_foveated_batch(scene, rig, foveation=f, config=PLANE_CONFIG)
    np.testing.assert_allclose(np.asarray(batch.images)[0], single.image, atol=1e-6)
