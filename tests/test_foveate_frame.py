"""The foveated stereo frame end to end: compaction traces exactly the generated rays, a fovea
covering the screen is the full render, hand-countable ray counts, no recompiles."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fovjax
from fovjax.foveate import Constant, Foveation, render_foveated
from fovjax.foveate import _api as fov_api
from fovjax.render import RenderConfig, StereoRig, render_stereo

EYE_W, EYE_H = 96, 64
CONFIG = RenderConfig(max_depth=1)  # one reflection bounce keeps the compile short


@pytest.fixture(scope="module")
def atrium_small():
    scene = fovjax.scenes.atrium(triangles=20_000)
    pose = fovjax.scenes.default_camera(scene)
    return scene, StereoRig.from_pose(pose, eye_width=EYE_W, eye_height=EYE_H)


def test_traces_exactly_the_selected_samples_and_no_recompile(atrium_small):
    scene, rig = atrium_small
    f = Foveation.thesis(0, spp=4)
    first = render_foveated(
        scene, rig, gaze=((0.5, 0.5), (0.5, 0.5)), foveation=f, key=jax.random.key(0), config=CONFIG
    )
    traces = fov_api.TRACE_COUNTS["foveated"]
    s = first.foveation
    assert s.dropped == 0
    assert first.stats.primary_rays == s.mandatory + s.optional == int(first.sample_mask.sum())
    assert sum(s.primary_by_region) == first.stats.primary_rays
    assert s.padding == s.budget - first.stats.primary_rays
    assert first.stats.primary_rays < 0.5 * 2 * 4 * EYE_W * EYE_H
    # Every region is present and the fovea is fully sampled.
    fovea = first.regions == 0
    assert fovea.any() and (first.sample_mask.transpose(1, 0, 2, 3)[:, fovea]).all()
    assert np.isfinite(first.image).all() and first.image.shape == (EYE_H, 2 * EYE_W, 3)
    # A new gaze, head pose and key reuse the compiled program.
    second = render_foveated(
        scene,
        rig,
        gaze=(0.2, 0.8, 0.3, 0.7),
        foveation=f,
        head_pose=(10, -5, 2),
        key=jax.random.key(1),
        config=CONFIG,
    )
    assert fov_api.TRACE_COUNTS["foveated"] == traces
    assert second.stats.compile_seconds == 0.0
    assert (second.regions != first.regions).any()


def test_full_fovea_reproduces_the_full_render(atrium_small):
    scene, rig = atrium_small
    key = jax.random.key(3)
    everything = Foveation(fovea_deg=180.0, periphery_deg=180.0, spp=4)
    fov = render_foveated(scene, rig, foveation=everything, key=key, config=CONFIG)
    full = render_stereo(scene, rig, spp=4, key=key, config=CONFIG)
    assert fov.stats.primary_rays == full.stats.primary_rays == 2 * 4 * EYE_W * EYE_H
    assert fov.stats.shadow_rays == full.stats.shadow_rays
    assert fov.stats.reflection_rays == full.stats.reflection_rays
    # Same rays, same shading; the two programs are compiled separately, so allow float32
    # rounding of the shading arithmetic (a few ulps), nothing more.
    np.testing.assert_allclose(fov.image, full.image, rtol=1e-5, atol=1e-6)


def test_ray_counts_on_a_wall_are_hand_countable():
    """A lit wall filling the view, nothing reflective: every traced primary ray hits, spawns
    exactly one shadow ray (the light is in front) and no reflection."""
    v = np.array([[-50, -50, -5], [50, -50, -5], [50, 50, -5], [-50, 50, -5]], np.float32)
    scene = fovjax.make_scene(
        v,
        [[0, 1, 2], [0, 2, 3]],
        materials=fovjax.make_materials([{"kd": (0.7, 0.7, 0.7)}]),
        lights=fovjax.make_lights([[0, 0, 2]], [[1, 1, 1]]),
        name="wall",
    )
    rig = StereoRig.look_at((0, 0, 0), (0, 0, -1), eye_width=48, eye_height=32)
    f = Foveation.thesis(0, spp=1)
    frame = render_foveated(scene, rig, foveation=f, key=jax.random.key(4), config=CONFIG)
    n = int(frame.sample_mask.sum())
    assert frame.stats.primary_rays == n
    assert frame.stats.shadow_rays == n
    assert frame.stats.reflection_rays == 0
    # The count itself, from the definition: every fovea pixel, every block top-left, and
    # the probabilistic extras the key selected.
    assert n == frame.foveation.mandatory + frame.foveation.optional


def test_bad_gaze_is_rejected_before_rendering(atrium_small):
    scene, rig = atrium_small
    with pytest.raises(ValueError, match="NaN"):
        render_foveated(scene, rig, gaze=((np.nan, 0.5), (0.5, 0.5)), config=CONFIG)
    with pytest.raises(ValueError, match="off-screen"):
        render_foveated(scene, rig, gaze=((0.5, 0.5), (0.5, -0.1)), config=CONFIG)


class _Tabulated(eqx.Module):
    """An acuity curve given as a table (array leaves, not scalar parameters)."""

    omega: jax.Array
    p: jax.Array

    def __call__(self, omega):
        return jnp.interp(omega, self.omega, self.p)


def test_budget_of_an_array_valued_acuity_model(atrium_small):
    # The static budget is cached by the acuity's parameters; a table must key it like scalars do.
    _, rig = atrium_small
    head = (0.0, 0.0, 0.0)
    flat = _Tabulated(jnp.array([0.0, 90.0]), jnp.array([0.25, 0.25]))
    steep = _Tabulated(jnp.array([0.0, 90.0]), jnp.array([1.0, 0.0]))
    budget = {
        name: fov_api._budget_for(rig, head, Foveation(fovea_deg=5, periphery_deg=10, acuity=acuity))
        for name, acuity in [("flat", flat), ("steep", steep), ("constant", Constant(0.25))]
    }
    assert budget["flat"] == budget["constant"]  # same P(ω) everywhere, same plan
    assert budget["steep"] != budget["flat"]  # a different table is not served from the cache
