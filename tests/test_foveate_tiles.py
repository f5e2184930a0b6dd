"""Coherent image tiles of a foveated frame (`Foveation.fovea_tile_deg`, `grid_tile`): the fovea
tile and the pixel grid traced as images in packets give the frame the sparse sample list gives
(the oracle), with the same samples traced, and compile once for any gaze."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fovjax
from fovjax.foveate import Foveation, render_foveated
from fovjax.foveate import _api as fov_api
from fovjax.render import RenderConfig, StereoRig

EYE_W, EYE_H = 96, 64
CONFIG = RenderConfig(max_depth=1)


@pytest.fixture(scope="module")
def atrium_small():
    scene = fovjax.scenes.atrium(triangles=20_000)
    pose = fovjax.scenes.default_camera(scene)
    return scene, StereoRig.from_pose(pose, eye_width=EYE_W, eye_height=EYE_H)


def _same_frame(tiled, listed):
    """Same samples traced, same primary rays and statistics; the same image up to float32
    rounding (the programs are compiled separately, and make their rays apart; see the
    full-fovea test in test_foveate_frame.py for why highlights may differ by ~Ns ulps)."""
    assert (tiled.sample_mask == listed.sample_mask).all()
    assert (tiled.regions == listed.regions).all()
    assert tiled.stats.primary_rays == listed.stats.primary_rays == int(listed.sample_mask.sum())
    assert tiled.foveation == listed.foveation
    # Secondary rays follow the shading; a ray grazing an edge may go either way after a
    # rounding difference, so the counts agree to a few rays.
    for name in ("shadow_rays", "reflection_rays"):
        a, b = getattr(tiled.stats, name), getattr(listed.stats, name)
        assert abs(a - b) <= max(2, b // 1000), (name, a, b)
    # On a CPU the listed samples' rays are made by the native slots handler, whose directions
    # round apart from XLA's (XLA:CPU's rsqrt is an estimate refined once, not correctly
    # rounded): a specular highlight may then differ by more than a few ulps. The agreement of
    # two programs that round apart (tests/test_render_native.py).
    diff = np.abs(tiled.image - listed.image).max(-1)
    assert np.mean(diff <= 1e-4) >= 0.99 and diff.mean() < 1e-3, np.sort(diff.ravel())[-10:]
    close = np.isclose(tiled.image, listed.image, rtol=1e-5, atol=1e-6)
    assert close.mean() > 0.99, close.mean()


BOTH = {"fovea_tile_deg": 10.0, "grid_tile": True}


@pytest.mark.parametrize(
    "spp, tiles", [(1, BOTH), (4, BOTH), (1, {"fovea_tile_deg": 10.0}), (1, {"grid_tile": True})]
)
def test_tiled_frame_equals_the_sample_list_frame(atrium_small, spp, tiles):
    """Both tiles, the fovea tile alone, the pixel grid alone."""
    scene, rig = atrium_small
    listed_f = Foveation.thesis((10.0, 20.0), spp=spp)
    tiled_f = Foveation.thesis((10.0, 20.0), spp=spp, **tiles)
    budget = fov_api._budget_for(rig, np.zeros(3, np.float32), tiled_f)
    tile = fov_api.fovea_tile(rig, tiled_f, budget)
    if "fovea_tile_deg" in tiles:
        assert tile is not None and tile[0] >= 8 and tile[1] >= 8  # the tile path really runs
    else:
        assert tile is None
    # An off-centre gaze, then one at a corner (the tile is moved inside the image): one
    # compiled program.
    for i, gaze in enumerate((((0.32, 0.38), (0.28, 0.38)), ((0.02, 0.97), (0.99, 0.01)))):
        key = jax.random.key(7 + i)
        listed = render_foveated(scene, rig, gaze=gaze, foveation=listed_f, key=key, config=CONFIG)
        traces = fov_api.TRACE_COUNTS["foveated"]
        tiled = render_foveated(scene, rig, gaze=gaze, foveation=tiled_f, key=key, config=CONFIG)
        if i:
            assert tiled.stats.compile_seconds == 0.0
            assert fov_api.TRACE_COUNTS["foveated"] == traces
        _same_frame(tiled, listed)


def test_a_capped_budget_traces_no_tile():
    """Tiles need a budget of every sample (their samples are never dropped)."""
    rig = StereoRig.look_at((0, 0, 0), (0, 0, -1), eye_width=48, eye_height=32)
    f = Foveation.thesis(0, fovea_tile_deg=5.0, grid_tile=True, max_periphery_deg=20.0)
    budget = fov_api._budget_for(rig, np.zeros(3, np.float32), f)
    assert budget < 2 * 48 * 32
    assert fov_api.fovea_tile(rig, f, budget) is None
    with pytest.raises(ValueError, match="fovea_tile_deg"):
        Foveation(fovea_tile_deg=0.0)


def test_a_nan_sample_in_a_tile_is_counted_and_painted():
    """Bad samples (NaN radiance) traced in the tiles are counted and painted as in the list."""
    v = np.array([[-50, -50, -5], [50, -50, -5], [50, 50, -5], [-50, 50, -5]], np.float32)
    scene = fovjax.make_scene(
        v,
        [[0, 1, 2], [0, 2, 3]],
        face_material=[0, 1],
        materials=fovjax.make_materials([{"kd": (0.7, 0.7, 0.7)}, {"kd": (0.5, 0.5, 0.5)}]),
        lights=fovjax.make_lights([[0, 0, 2]], [[1, 1, 1]]),
        name="wall2",
    )
    rig = StereoRig.look_at((0, 0, 0), (0, 0, -1), eye_width=48, eye_height=32)
    arrays = fovjax.render.scene_arrays(scene)
    arrays = eqx.tree_at(lambda a: a.kd, arrays, jnp.asarray(arrays.kd).at[1].set(jnp.nan))
    bvh = fovjax.trace.build_bvh(scene)
    key = jax.random.key(5)
    gaze = ((0.55, 0.5), (0.55, 0.5))  # the fovea tile straddles both materials
    config = RenderConfig(max_depth=0)  # a diffuse wall: no reflections to trace (a shorter compile)
    listed = render_foveated(
        arrays, rig, gaze=gaze, foveation=Foveation.thesis((20.0, 40.0)), key=key, config=config, bvh=bvh
    )
    tiled_f = Foveation.thesis((20.0, 40.0), fovea_tile_deg=20.0, grid_tile=True)
    tiled = render_foveated(arrays, rig, gaze=gaze, foveation=tiled_f, key=key, config=config, bvh=bvh)
    assert 0 < tiled.stats.bad_pixels == listed.stats.bad_pixels
    assert tiled.stats.bad_samples == listed.stats.bad_samples
    magenta = np.asarray(config.bad_color, np.float32)
    painted = [np.all(np.asarray(f.outputs.prefill) == magenta, axis=-1) for f in (tiled, listed)]
    assert painted[0].sum() == tiled.stats.bad_pixels
    np.testing.assert_array_equal(painted[0], painted[1])
    np.testing.assert_allclose(tiled.outputs.prefill, listed.outputs.prefill, rtol=1e-5, atol=1e-6)
