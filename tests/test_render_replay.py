"""Gradients from stored paths (fovjax/render/_replay.py), deep paths.

On a CPU the native integrator's forward stores each ray's path (the face hit at every depth
level, the lights its shadow rays reached) and the derivatives are those of a JAX replay of the
shading along those paths. tests/test_render_native.py compares them with the JAX integrator's
at one reflection level on a scene with every shading feature; here the paths go to depth 5: the
Cornell box with a mirror block and half-mirror walls facing each other, one point light and the
blocks' shadows. Oracle: the image is linear in Kd, Ks, Ka and the light's colour, so central
differences of the native forward with any step are exact up to float32 rounding of the loss (a
weighted sum of ~1.5k pixels): a step of 0.25 leaves them within 1e-4 of the gradient's largest
component. A replay one level short, or one that ignores the stored visibility, fails it. The
compiled gradient traces no ray beside its forward (one call of the native integrator, no query),
and its primal is the native image.
"""

from __future__ import annotations

import _extras
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fovjax
from fovjax.render import RenderConfig, StereoRig, render_stereo_image, scene_arrays

DEPTH = 5
STEP = 0.25
RTOL = 1e-4
LINEAR = ("kd", "ks", "ka", "light_color")


@pytest.fixture(scope="module")
def box():
    _extras.require("embreex")
    if not fovjax.native.status():
        pytest.fail(f"the native handlers are unavailable: {fovjax.native.status().reason}")
    scene = fovjax.scenes.cornell_box(mirror_block=True)
    bvh = fovjax.trace.build_bvh(scene, cache=False)
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=32, eye_height=24)
    arrays = scene_arrays(scene)
    kr = np.asarray(arrays.kr)
    diffuse = (kr == 0).all(axis=1) & (np.asarray(arrays.ke) == 0).all(axis=1)  # walls, the short block
    assert diffuse.sum() >= 3
    kr = np.where(diffuse[:, None], 0.5, kr).astype(np.float32)
    arrays = eqx.tree_at(lambda s: s.kr, arrays, jnp.asarray(kr))
    weights = np.random.default_rng(0).uniform(0, 1, (24, 64, 3)).astype(np.float32)
    config = RenderConfig(max_depth=DEPTH)
    params = {name: jnp.asarray(getattr(arrays, name)) for name in LINEAR}

    def image(params):
        scene = eqx.tree_at(lambda s: [getattr(s, n) for n in LINEAR], arrays, [params[n] for n in LINEAR])
        return render_stereo_image(scene, bvh, rig, (0.0, 0.0, 0.0), config=config)

    def loss(params):
        return jnp.sum(weights * image(params))

    # One compiled program each, shared by the tests.
    grad = jax.jit(jax.grad(loss)).lower(params).compile()
    return arrays, bvh, image, jax.jit(loss), grad, params


def test_paths_reach_every_depth(box):
    """The scene exercises the replay: some path is still traced at the last level, and some
    shadow rays are blocked."""
    from fovjax.render._native import native_whitted, whitted_operands
    from fovjax.render.internal import scene_scale

    arrays, bvh, *_ = box
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(fovjax.scenes.cornell_box()), eye_width=32, eye_height=24
    )
    rays = fovjax.render.stereo_sample_rays(rig, None, 1, None)
    o, d = rays.origins.reshape(-1, 3), rays.directions.reshape(-1, 3)
    d = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
    offset = RenderConfig().ray_offset * scene_scale(arrays)
    _, _, prim, visible = native_whitted(
        whitted_operands(arrays, bvh),
        o,
        d,
        jnp.ones(o.shape[0], bool),
        offset,
        max_depth=DEPTH,
        recompute=True,
        packets=False,
        store_paths=True,
    )
    prim, visible = np.asarray(prim), np.asarray(visible)
    assert prim.shape == (DEPTH + 1, o.shape[0])
    assert (prim[DEPTH] >= 0).any(), "no path reaches the last level"
    assert (prim[0] >= -1).all()  # every camera ray traced at the first level
    assert ((prim[0] >= 0) & (visible[0] == 0)).any() and (visible[0] == 1).any()  # shadow and light


def test_gradients_from_stored_paths_are_the_finite_differences(box):
    *_, f, grad, params = box
    g = grad(params)
    for name in LINEAR:
        scale = float(jnp.max(jnp.abs(g[name])))
        assert scale > 0, name
        rows = np.argsort(-np.abs(np.asarray(g[name])).max(axis=1))[:2]  # the two that matter most
        for row in rows:
            for c in range(3):
                up = {**params, name: params[name].at[row, c].add(STEP)}
                down = {**params, name: params[name].at[row, c].add(-STEP)}
                fd = (float(f(up)) - float(f(down))) / (2 * STEP)
                assert abs(float(g[name][row, c]) - fd) <= RTOL * scale, (
                    name,
                    row,
                    c,
                    float(g[name][row, c]),
                    fd,
                )


def test_the_gradient_traces_no_ray(box):
    """The compiled CPU gradient: one call of the native integrator (the forward, storing its
    paths; not the camera frame handler's plain forward too), no ray query, and no loop but
    XLA's scatters (the transposes of the gathers)."""
    *_, grad, _ = box
    text = grad.as_text()
    assert text.count("fovjax_embree_whitted") == 1
    assert "fovjax_embree_query" not in text
    assert "fovjax_camera_frame" not in text  # the frame's primal, unused by `jax.grad`, dropped
    loops = [line for line in text.splitlines() if " while(" in line]
    assert all("scatter" in line for line in loops), [line[:200] for line in loops if "scatter" not in line]


def test_the_forward_is_the_native_image(box):
    """The primal a derivative returns is the native integrator's image: bit for bit the image
    of the frame's rays made in JAX (`_frame_of_rays`, the camera frame's reference), and the
    plain call's (the camera frame handler, its rays rounded its own way) to float rounding."""
    from _frames import assert_native_radiance

    from fovjax.render._frame import _frame_of_rays

    arrays, bvh, image, _, _, params = box
    direction = jax.tree.map(jnp.ones_like, params)
    primal, tangent = jax.jit(lambda p: jax.jvp(image, (p,), (direction,)))(params)
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(fovjax.scenes.cornell_box()), eye_width=32, eye_height=24
    )
    config = RenderConfig(max_depth=DEPTH)

    def of_rays(p):
        scene = eqx.tree_at(lambda s: [getattr(s, n) for n in LINEAR], arrays, [p[n] for n in LINEAR])
        return _frame_of_rays(scene, bvh, rig.eye_cameras(jnp.zeros(3)), None, spp=1, config=config)[0]

    assert np.array_equal(np.asarray(primal), np.asarray(jax.jit(of_rays)(params)))
    assert_native_radiance(primal, jax.jit(image)(params), arrays)
    assert np.asarray(tangent).std() > 0
