"""Derivatives through the foveated frame (the thesis's method, the default configuration): on a
CPU the slots handler stores each slot's path and the derivatives are those of a replay of them
(`fovjax.render.internal.replay_radiance`), so `jax.grad` and `jax.jvp` both go through the
frame, whose selection, fill and blur are differentiable JAX (or the native handlers with the JAX
side's derivatives).

Oracle: the frame is linear in Kd and in the light's colour (the sums, means, fill and blur are
linear in the radiance, the radiance in each), so central differences with any step are exact
up to float32 rounding of the loss (a weighted sum of ~3k pixels, each ~1): a step of 0.25
leaves them within 1e-4 relative. The forward-mode derivative along any direction is the
reverse-mode gradient's dot product with it. The compiled gradient traces each slot once (one
call of the slots handler, storing paths) and no ray beside it.
"""

from __future__ import annotations

import _extras
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fovjax
from fovjax.foveate import Foveation
from fovjax.render import RenderConfig, StereoRig, scene_arrays

STEP = 0.25
RTOL = 1e-4
W, H = 32, 24


@pytest.fixture(scope="module")
def frame():
    _extras.require("embreex")
    if not fovjax.native.status():
        pytest.fail(f"the native handlers are unavailable: {fovjax.native.status().reason}")
    from fovjax.foveate.internal import FrameOptions, foveated_stereo
    from fovjax.render.internal import bvh_for

    scene = fovjax.scenes.cornell_box(mirror_block=True)
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=W, eye_height=H)
    arrays, bvh = scene_arrays(scene), bvh_for(scene, None)
    foveation = Foveation(fovea_deg=5, periphery_deg=10, spp=1)
    # One reflection level (the mirror block's): deeper paths' replay is tests/test_render_replay.py's,
    # and each level adds to the three programs' compile.
    options = FrameOptions(
        spp=1, jitter=False, config=RenderConfig(max_depth=1), budget=2 * W * H, diagnostics=()
    )
    gaze = jnp.asarray([[0.4, 0.5], [0.6, 0.5]], jnp.float32)
    weights = np.random.default_rng(1).uniform(0, 1, (H, 2 * W, 3)).astype(np.float32)

    def image(kd, light):
        a = eqx.tree_at(lambda s: (s.kd, s.light_color), arrays, (kd, light))
        return foveated_stereo(
            a, bvh, rig, jnp.zeros(3), gaze, jax.random.key(0), foveation, options=options
        ).image

    def loss(kd, light):
        return jnp.sum(weights * image(kd, light))

    kd, light = jnp.asarray(arrays.kd), jnp.asarray(arrays.light_color)
    # One compiled program each, shared by the tests: the gradient, the loss, a JVP.
    grad = jax.jit(jax.grad(loss, argnums=(0, 1))).lower(kd, light).compile()
    jvp = jax.jit(lambda k, dk: jax.jvp(lambda x: loss(x, light), (k,), (dk,))).lower(kd, kd).compile()
    return kd, light, jax.jit(loss), grad, jvp


def test_grad_through_the_foveated_frame_is_the_finite_difference(frame):
    kd, light, f, grad, _ = frame
    g_kd, g_light = grad(kd, light)
    scale = float(jnp.max(jnp.abs(g_kd)))
    for m, c in [(0, 0), (1, 1), (2, 2), (4, 0)]:
        fd = (float(f(kd.at[m, c].add(STEP), light)) - float(f(kd.at[m, c].add(-STEP), light))) / (2 * STEP)
        assert abs(float(g_kd[m, c]) - fd) <= RTOL * scale, (m, c, float(g_kd[m, c]), fd)
    fd = (float(f(kd, light * (1 + STEP))) - float(f(kd, light * (1 - STEP)))) / (2 * STEP)
    assert abs(float(jnp.sum(g_light * light)) - fd) <= RTOL * abs(fd)
    assert scale > 0


def test_forward_mode_is_the_gradient_along_a_direction(frame):
    """The JVP's primal is the loss of the native frame; its tangent the gradient's projection."""
    kd, light, f, grad, jvp = frame
    direction = jnp.asarray(np.random.default_rng(2).normal(size=kd.shape), jnp.float32)
    g_kd, _ = grad(kd, light)
    value, along = jvp(kd, direction)
    projected = g_kd * direction
    assert abs(float(along) - float(jnp.sum(projected))) <= RTOL * float(jnp.sum(jnp.abs(projected)))
    assert np.isclose(float(value), float(f(kd, light)), rtol=1e-6, atol=0)  # the same frame, summed apart


def test_the_gradient_traces_each_slot_once(frame):
    *_, grad, _ = frame
    text = grad.as_text()
    assert text.count("fovjax_whitted_slots") == 1
    assert "fovjax_embree_whitted" not in text and "fovjax_embree_query" not in text
