"""Gradients of an image loss against central finite differences.

`jax.grad` (through `eqx.filter_grad`) of a weighted sum of a rendered image, with respect to
material colours (Kd, Ks, Kr, Ns), the light's colour and position, the camera position and
vertex positions. Visibility (which triangle a ray hits, whether a shadow ray is blocked) is not
differentiated; the BVH is built once, so the renderer with perturbed arrays is a smooth function
of them as long as no shadow edge or silhouette moves across a sample, and the views are chosen
so: the sphere's front seen from ahead (its reflections see only the sky), and open floor lit
without shadows. The finite differences use the same compiled program as test_render.py.

Tolerances are what float32 supports for each kind of parameter (measured with this file's
`check` on this scene; relative to the larger of |finite difference| and 1% of the leaf's largest
gradient, so that a near-zero component is judged on the leaf's scale):
- linear in the parameter (colours, Kd/Ks/Kr, the light's colour, the environment map's texels):
  central differences are exact up to rounding; they agreed to <= 5e-6: rtol 1e-5.
- smooth non-linear (Ns, the light's position): Richardson-extrapolated central differences
  agreed to <= 5e-5: rtol 1e-4.
- geometry (vertex positions): the step must stay below the secondary-ray offset (2.8e-4 here),
  and the loss's float32 rounding over that step leaves ~3e-3: rtol 1e-2.
- the camera's rotation entries (steps of 1e-3): agreed to <= 1.1e-4: rtol 1e-3.
- the camera's position: moving it slides every sample over the floor texture's bilinear kinks,
  so differences are only piecewise smooth; they agreed to <= 8.2e-3: rtol 2e-2.
Each difference divides by the step float32 actually took, not the nominal one.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_render_reference import FLOOR, SIZE, SPHERE, oracle_scene

import fovjax
from fovjax.render import RenderConfig, render, render_image, scene_arrays
from fovjax.trace import build_bvh

CONFIG = RenderConfig(max_depth=1)
BACKGROUND = np.array(fovjax.render.THESIS_BACKGROUND, np.float32).reshape(1, 1, 3)
WEIGHTS = np.random.default_rng(3).uniform(0.0, 1.0, (SIZE, SIZE, 3)).astype(np.float32)


def loss(params, bvh):
    arrays, camera = params
    return jnp.sum(WEIGHTS * render_image(arrays, bvh, camera, config=CONFIG))


# The gradient's program compiles with XLA's default (fusion) emitters, as a user's own jit of
# a gradient does: with the loop emitters the suite compiles with (conftest) at LLVM's lowest
# optimisation level, the floor's Kd gradient came out 9e-5 (relative) off its finite
# difference, well past float32 rounding, while the finite differences agreed with every other
# setting's; with either setting alone the gradient is right. That combination is the suite's
# alone.
_grad = eqx.filter_grad(loss)
GRAD = jax.jit(lambda params, bvh: _grad(params, bvh), compiler_options={"xla_cpu_use_fusion_emitters": True})


@pytest.fixture(scope="module")
def setup():
    scene = oracle_scene()
    bvh = build_bvh(scene, cache=False)
    arrays = scene_arrays(scene, envmap=BACKGROUND)
    return scene, bvh, arrays, GRAD


def forward(arrays, camera, bvh):
    image = render(arrays, camera, config=CONFIG, bvh=bvh).image
    return float(np.sum(WEIGHTS.astype(np.float64) * image))


def replace_entry(params, where, index, value):
    """params with leaf `where(params)[index]` set to value."""
    leaf = np.array(where(params), copy=True)
    leaf[index] = value
    return eqx.tree_at(where, params, leaf)


LINEAR, SMOOTH, ROTATION, GEOMETRY, CAMERA = 1e-5, 1e-4, 1e-3, 1e-2, 2e-2


def central_difference(params, bvh, where, index, eps):
    x0 = np.float32(np.asarray(where(params))[index])
    plus, minus = np.float32(x0 + np.float32(eps)), np.float32(x0 - np.float32(eps))
    f_plus = forward(*replace_entry(params, where, index, plus), bvh)
    f_minus = forward(*replace_entry(params, where, index, minus), bvh)
    return (f_plus - f_minus) / (float(plus) - float(minus))  # the step float32 took


def check(params, gradient, bvh, where, index, eps, rtol, richardson=False):
    fd = central_difference(params, bvh, where, index, eps)
    if richardson:  # cancel the O(eps²) term: (4·D(eps/2) − D(eps)) / 3
        fd = (4 * central_difference(params, bvh, where, index, eps / 2) - fd) / 3
    leaf = np.abs(np.asarray(where(gradient)))
    g = float(np.asarray(where(gradient))[index])
    scale = max(abs(fd), 1e-2 * float(leaf.max()))
    assert abs(g - fd) <= rtol * scale, (index, g, fd, abs(g - fd) / scale)
    return g


def sphere_view():
    return fovjax.Camera.look_at((0.0, 1.0, 6.0), (0.0, 1.0, 0.0), vfov_deg=30.0, width=SIZE, height=SIZE)


def floor_view():
    # x = 5.3, not 5.5: a pixel centre on the texture's texel centre (u = 1.375) would sit on a
    # kink of the bilinear lookup, where one-sided derivatives differ
    return fovjax.Camera.look_at((5.3, 5.0, 10.0), (5.3, 0.0, 7.0), vfov_deg=35.0, width=SIZE, height=SIZE)


def test_gradients_of_materials_light_colour_and_sphere_vertex(setup):
    scene, bvh, arrays, grad = setup
    params = (arrays, sphere_view())
    gradient = grad(params, bvh)
    assert all(np.isfinite(np.asarray(x)).all() for x in jax.tree.leaves(eqx.filter(gradient, eqx.is_array)))
    a = lambda name: lambda p: getattr(p[0], name)  # noqa: E731
    checked = []
    for name, row in [("kd", SPHERE), ("ks", SPHERE), ("kr", SPHERE), ("kd", FLOOR), ("kr", FLOOR)]:
        for channel in range(3):
            checked.append(check(params, gradient, bvh, a(name), (row, channel), 1e-2, LINEAR))
    checked.append(check(params, gradient, bvh, a("ns"), SPHERE, 0.5, SMOOTH, richardson=True))
    for channel in range(3):
        checked.append(check(params, gradient, bvh, a("light_color"), (0, channel), 1e-2, LINEAR))
        # The sky (a 1×1 environment map) seen past the sphere and in its reflection.
        checked.append(check(params, gradient, bvh, a("environment"), (0, 0, channel), 1e-2, LINEAR))
    # the sphere's front pole (0, 1, 1): an interior vertex of the view. The BVH keeps the
    # original surface, so steps must stay below the secondary-ray offset (2.8e-4 here), or
    # shadow rays from the moved surface would start behind the original one.
    pole = int(np.argmin(np.linalg.norm(np.asarray(scene.vertices) - (0.0, 1.0, 1.0), axis=1)))
    for axis in range(3):
        checked.append(check(params, gradient, bvh, a("vertices"), (pole, axis), 1e-4, GEOMETRY))
    assert np.count_nonzero(np.abs(checked) > 1e-3) >= len(checked) - 2  # not a pile of zeros


def test_gradients_of_camera_light_position_and_floor_vertex(setup):
    scene, bvh, arrays, grad = setup
    kr = np.array(arrays.kr, copy=True)
    kr[FLOOR] = 0.0  # open floor without reflections: no edge anywhere in view
    params = (dataclasses.replace(arrays, kr=kr), floor_view())
    gradient = grad(params, bvh)
    checked = []
    for axis in range(3):
        checked.append(check(params, gradient, bvh, lambda p: p[1].position, axis, 5e-3, CAMERA))
        checked.append(
            check(
                params, gradient, bvh, lambda p: p[0].light_position, (0, axis), 1e-2, SMOOTH, richardson=True
            )
        )
    corner = int(np.argmin(np.linalg.norm(np.asarray(scene.vertices) - (10.0, 0.0, 10.0), axis=1)))
    checked.append(check(params, gradient, bvh, lambda p: p[0].vertices, (corner, 1), 1e-4, GEOMETRY))
    # The camera's orientation, entry by entry (the renderer maps pixel directions through the
    # matrix as given, so every entry is a smooth input; open floor: no silhouette to cross).
    for index in [(0, 0), (1, 2), (2, 1)]:
        checked.append(check(params, gradient, bvh, lambda p: p[1].rotation, index, 1e-3, ROTATION))
    assert np.count_nonzero(np.abs(checked) > 1e-3) == len(checked)
