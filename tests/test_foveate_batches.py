"""Depth batches of the chunked integrator (`RenderConfig.depth_batch_size`): slots taken through
every depth level a batch at a time (a reflection queue of one batch) give what one batch of
every slot gives (the oracle), and a foveated frame in several batches is still the full render
at a full-screen fovea, also with image tiles."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fovjax
from fovjax.foveate import Foveation, render_foveated
from fovjax.render import RenderConfig, StereoRig, render_stereo, scene_arrays
from fovjax.render._integrator import _batch, _chunks
from fovjax.render.internal import radiance_in_chunks
from fovjax.trace import build_bvh

EYE_W, EYE_H = 96, 64


@pytest.fixture(scope="module")
def atrium_small():
    scene = fovjax.scenes.atrium(triangles=20_000)
    pose = fovjax.scenes.default_camera(scene)
    return scene, StereoRig.from_pose(pose, eye_width=EYE_W, eye_height=EYE_H)


def _close(a, b):
    """Equal up to float32 rounding of separately compiled shading (see the full-fovea test in
    test_foveate_frame.py: highlights may differ by ~Ns ulps)."""
    np.testing.assert_allclose(a, b, rtol=1e-3, atol=1e-5)
    assert np.isclose(a, b, rtol=1e-5, atol=1e-6).mean() > 0.99


def test_batches_give_the_one_batch_radiance(atrium_small):
    scene, _ = atrium_small
    bvh = build_bvh(scene)
    arrays = scene_arrays(scene)
    cam = fovjax.Camera.from_pose(fovjax.scenes.default_camera(scene), width=48, height=48)
    o, d, _ = cam.sample_rays(1, None)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)  # 2304 rays
    n_slots = 2500
    po = jnp.zeros((n_slots, 3)).at[: o.shape[0]].set(o)
    pd = jnp.ones((n_slots, 3)).at[: d.shape[0]].set(d)
    base = dict(max_depth=2, chunk_size=256, queue_chunk_size=64, first_bounce_chunk_size=128)
    one = RenderConfig(**base, depth_batch_size=None)
    many = RenderConfig(**base, depth_batch_size=700)  # 3 chunks of 256 a batch
    assert _batch(_chunks(n_slots, many), many).count == 3 and _batch(_chunks(n_slots, one), one).count == 10

    def rays_at(first, size):
        return tuple(jax.lax.dynamic_slice_in_dim(x, first, size) for x in (po, pd))

    # One program per config; the live count is traced (compiled once for the three counts).
    run = {
        config: jax.jit(
            lambda n, c=config: radiance_in_chunks(arrays, bvh, rays_at, n, n_slots=n_slots, config=c)
        )
        for config in (many, one)
    }
    for n_live in (2304, 1000, 0):  # 4 batches (the last partial), 2 batches, none
        a, b = run[many](jnp.int32(n_live)), run[one](jnp.int32(n_live))
        assert int(a.primary) == int(b.primary) == n_live
        assert int(a.reflection) == int(b.reflection) and int(a.shadow) == int(b.shadow)
        if n_live == 2304:
            assert int(a.reflection) > 0 and int(a.shadow) > 0  # the levels really run
        if n_live:
            _close(np.asarray(a.total[:n_live]), np.asarray(b.total[:n_live]))


def test_full_fovea_in_batches_is_the_full_render(atrium_small):
    scene, rig = atrium_small
    key = jax.random.key(3)
    config = RenderConfig(max_depth=1, chunk_size=4096, depth_batch_size=8192)  # 6 batches
    everything = Foveation(fovea_deg=180.0, periphery_deg=180.0, spp=4)
    fov = render_foveated(scene, rig, foveation=everything, key=key, config=config)
    full = render_stereo(scene, rig, spp=4, key=key, config=RenderConfig(max_depth=1))
    assert fov.stats.primary_rays == full.stats.primary_rays == 2 * 4 * EYE_W * EYE_H
    assert fov.stats.shadow_rays == full.stats.shadow_rays
    assert fov.stats.reflection_rays == full.stats.reflection_rays
    _close(fov.image, full.image)


def test_tiles_and_batches_give_the_one_batch_frame(atrium_small):
    scene, rig = atrium_small
    gaze, key = ((0.32, 0.38), (0.28, 0.38)), jax.random.key(7)
    tiled = Foveation.thesis((10.0, 20.0), spp=4, fovea_tile_deg=10.0, grid_tile=True)
    # One reflection level: the tiles' reflections join the first batch's queue (deeper levels
    # in batches: test_batches_give_the_one_batch_radiance).
    unbatched = RenderConfig(max_depth=1, depth_batch_size=None)
    one = render_foveated(scene, rig, gaze=gaze, foveation=tiled, key=key, config=unbatched)
    # Batches of 2048 slots (chunks of 1024): the tiles' reflections go with the first.
    config = RenderConfig(max_depth=1, chunk_size=1024, depth_batch_size=2048)
    many = render_foveated(scene, rig, gaze=gaze, foveation=tiled, key=key, config=config)
    assert many.stats.primary_rays == one.stats.primary_rays
    listed = many.stats.primary_rays - int(many.foveation.primary_by_region[0])
    assert listed > 2048  # more than one batch of slots besides the tiles
    for name in ("shadow_rays", "reflection_rays"):
        a, b = getattr(many.stats, name), getattr(one.stats, name)
        assert abs(a - b) <= 2, (name, a, b)
    assert (many.sample_mask == one.sample_mask).all()
    _close(many.image, one.image)


@pytest.mark.parametrize("bad", [0, -4096])
def test_a_bad_depth_batch_size_is_rejected(bad):
    with pytest.raises(ValueError, match="depth_batch_size"):
        RenderConfig(depth_batch_size=bad)
