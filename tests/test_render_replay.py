"""Gradients from stored paths (fovjax/render/_replay.py) against the JAX integrator's, their
oracle.

On a CPU the native integrator's forward stores each ray's path (the face hit at every depth
level, the lights its shadow rays reached) and the derivatives are those of a JAX replay of the
shading along those paths. The scene: the Cornell box with a mirror block and half-mirror walls
facing each other (paths to depth 5), one point light and the blocks' shadows. Every float
leaf's gradient of a weighted image sum is compared with the JAX integrator's (which traces its
own rays and differentiates its own shading): the two compute one closed form at the same hits,
in two programs, so they agree to float32 rounding of sums over the image (rtol 1e-5 of each
leaf's largest gradient; for the specular exponents' own gradient, (n·h)^Ns ln(n·h), 8 ulp of
the largest Ns more, as the native tests allow for the specular: the exponent scales the rounding
of log2(n·h)). The compiled gradient program traces no ray (no query, no loop): one
call of the native integrator, with paths.
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
GRADIENT_RTOL = 1e-5
SPECULAR_ULPS = 8


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
    return arrays, bvh, rig, weights


def _loss(config, bvh, rig, weights):
    def loss(arrays):
        return jnp.sum(weights * render_stereo_image(arrays, bvh, rig, (0.0, 0.0, 0.0), config=config))

    return loss


def test_paths_reach_every_depth(box):
    """The scene exercises the replay: some path is still traced at the last level."""
    from fovjax.render._native import native_whitted, whitted_operands
    from fovjax.render.internal import scene_scale

    arrays, bvh, rig, _ = box
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


def test_gradients_from_stored_paths_are_the_jax_integrators(box):
    arrays, bvh, rig, weights = box
    grads = {}
    for integrator in ("auto", "jax"):
        config = RenderConfig(max_depth=DEPTH, integrator=integrator)
        grads[integrator] = eqx.filter_jit(eqx.filter_grad(_loss(config, bvh, rig, weights)))(arrays)
    checked = 0
    max_ns = float(np.max(np.asarray(arrays.ns)))
    leaves = jax.tree_util.tree_leaves_with_path(grads["auto"])
    for (path, mine), oracle in zip(leaves, jax.tree_util.tree_leaves(grads["jax"]), strict=True):
        mine, oracle = np.asarray(mine), np.asarray(oracle)
        if mine.dtype.kind != "f" or not np.any(oracle):
            continue
        name = jax.tree_util.keystr(path)
        rtol = GRADIENT_RTOL
        if name == ".ns":
            rtol += SPECULAR_ULPS * float(np.finfo(np.float32).eps) * max_ns
        np.testing.assert_allclose(mine, oracle, rtol=0, atol=rtol * np.max(np.abs(oracle)), err_msg=name)
        checked += 1
    assert checked >= 8  # vertices, normals, ka, kd, ks, ke, kr, ns, light position and colour


def test_the_gradient_traces_no_ray(box):
    """The compiled CPU gradient: one call of the native integrator (the forward, storing its
    paths), no ray query, and no loop but XLA's scatters (the transposes of the material and
    vertex gathers)."""
    arrays, bvh, rig, weights = box
    loss = _loss(RenderConfig(max_depth=DEPTH), bvh, rig, weights)
    grad = jax.jit(jax.grad(lambda kd: loss(eqx.tree_at(lambda s: s.kd, arrays, kd))))
    text = grad.lower(arrays.kd).compile().as_text()
    assert text.count("fovjax_embree_whitted") == 1
    assert "fovjax_embree_query" not in text
    loops = [line for line in text.splitlines() if " while(" in line]
    assert all("scatter" in line for line in loops), [line[:200] for line in loops if "scatter" not in line]


def test_the_forward_is_the_native_image(box):
    """The primal a derivative returns is the native integrator's image, bit for bit."""
    arrays, bvh, rig, _ = box
    config = RenderConfig(max_depth=DEPTH)

    def image(kd):
        return render_stereo_image(
            eqx.tree_at(lambda s: s.kd, arrays, kd), bvh, rig, (0.0, 0.0, 0.0), config=config
        )

    primal, tangent = jax.jit(lambda kd: jax.jvp(image, (kd,), (jnp.ones_like(kd),)))(arrays.kd)
    assert np.array_equal(np.asarray(primal), np.asarray(jax.jit(image)(arrays.kd)))
    assert np.asarray(tangent).std() > 0
