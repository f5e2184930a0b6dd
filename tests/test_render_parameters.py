"""`fovjax.render.differentiable`: the frame as a function of the parameters a user names.

Gradients of a weighted image sum with respect to the chosen parameters, against the
whole-scene `eqx.filter_grad` of tests/test_render_grad.py on the chosen leaves, which that file
checks against central finite differences of the same scene, views and weights (its docstring
gives the reason for each tolerance): one gradient two ways, here through `Parameters` put back
into the arrays with `eqx.tree_at` and rows picked by material name, there through every leaf of
the arrays.

The stereo frame's head pose (yaw, pitch, roll in degrees) is checked on a rig looking at the
oracle scene's open floor, with no silhouette in view: turning the head slides every sample over
the floor texture's bilinear kinks, as moving the camera does, so its differences are piecewise
smooth and take the camera position's tolerance.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_render_grad import CAMERA, CONFIG, WEIGHTS, floor_view, sphere_view
from test_render_reference import FLOOR, SPHERE, oracle_scene

import fovjax
from fovjax.render import (
    PARAMETER_NAMES,
    Differentiable,
    Parameters,
    StereoRig,
    differentiable,
    render_image,
    render_stereo_image,
    scene_arrays,
)
from fovjax.trace import build_bvh

BACKGROUND = np.array(fovjax.render.THESIS_BACKGROUND, np.float32).reshape(1, 1, 3)
NAMES = ("kd", "ks", "kr", "ns", "light_position", "light_color", "vertices", "camera_position")
MATERIAL_NAMES = ("kd", "ks", "kr", "ns")
# The stereo rig over the floor: both eyes see only floor (no toe-out, a narrow field of view).
EYE = 8


@pytest.fixture(scope="module")
def oracle():
    scene = oracle_scene()
    return scene, build_bvh(scene, cache=False)


def image(arrays, bvh, *, view):
    """The render function of the mono tests: the BVH comes as an argument of the call."""
    return render_image(arrays, bvh, view, config=CONFIG)


def make_frame(arrays, view, vertex_rows) -> Differentiable:
    """The parameters of the mono tests: the sphere's and the floor's material rows, the light,
    two vertices (the sphere's front pole, a floor corner) and the camera's position."""
    return differentiable(image, arrays, NAMES, view=view, materials=(SPHERE, FLOOR), vertices=vertex_rows)


def vertex_near(scene, point) -> int:
    return int(np.argmin(np.linalg.norm(np.asarray(scene.vertices) - point, axis=1)))


@pytest.fixture(scope="module")
def frames(oracle):
    """The sphere view and the open-floor view (the floor's mirror term off), as two
    `Differentiable`s of the same parameters, and what the tests need beside them."""
    scene, bvh = oracle
    arrays = scene_arrays(scene, envmap=BACKGROUND)
    rows = (vertex_near(scene, (0.0, 1.0, 1.0)), vertex_near(scene, (10.0, 0.0, 10.0)))
    kr = np.array(arrays.kr, copy=True)
    kr[FLOOR] = 0.0
    return {
        "sphere": make_frame(arrays, sphere_view(), rows),
        "floor": make_frame(dataclasses.replace(arrays, kr=kr), floor_view(), rows),
        "bvh": bvh,
        "rows": rows,
    }


def weighted_sum(params, frame, bvh):
    return jnp.sum(WEIGHTS * frame(params, bvh))


# One program for both views, and for new values of the parameters (the frame is made inside,
# from traced arrays and view), compiled with XLA's fusion emitters as test_render_grad.py
# compiles its gradient, for the reason given there. TRACES counts its traces.
TRACES: list = []


@functools.partial(
    jax.jit, static_argnames="vertex_rows", compiler_options={"xla_cpu_use_fusion_emitters": True}
)
def _gradient(params, arrays, view, bvh, vertex_rows):
    TRACES.append(vertex_rows)
    return jax.grad(weighted_sum)(params, make_frame(arrays, view, vertex_rows), bvh)


# The image and its derivative along a tangent (`jax.jvp`).
@functools.partial(jax.jit, static_argnames="vertex_rows")
def _image_and_tangent(params, tangent, arrays, view, bvh, vertex_rows):
    frame = make_frame(arrays, view, vertex_rows)
    return jax.jvp(lambda p: frame(p, bvh), (params,), (tangent,))


def grad_of(params, frame, bvh) -> Parameters:
    return _gradient(params, frame.arrays, frame.view, bvh, frame.vertex_rows)


def jvp_of(params, tangent, frame, bvh):
    return _image_and_tangent(params, tangent, frame.arrays, frame.view, bvh, frame.vertex_rows)


def with_entry(params: Parameters, name, index, value) -> Parameters:
    leaf = np.array(params[name], copy=True)
    leaf[index] = value
    return Parameters({**params.values, name: jnp.asarray(leaf)})


@pytest.fixture(scope="module")
def floor_rig(oracle):
    scene, bvh = oracle
    rig = StereoRig.look_at(
        (5.3, 5.0, 10.0), (5.3, 0.0, 7.0), eye_width=EYE, eye_height=EYE, fov_deg=30.0, toe_out_deg=0.0
    )
    arrays = scene_arrays(scene, envmap=BACKGROUND)
    kr = np.array(arrays.kr, copy=True)
    kr[FLOOR] = 0.0
    weights = np.random.default_rng(4).uniform(0.0, 1.0, (EYE, 2 * EYE, 3)).astype(np.float32)

    def stereo(arrays, *, head_pose):
        return render_stereo_image(arrays, bvh, rig, head_pose, config=CONFIG)

    arrays = dataclasses.replace(arrays, kr=kr)
    return differentiable(stereo, arrays, "head_pose", head_pose=(2.0, -3.0, 1.0)), weights


def test_head_pose_derivative_matches_central_differences(floor_rig):
    """Forward mode (`jax.jvp`) along each head angle, against central differences of the
    jvp's own primal."""
    frame, weights = floor_rig
    params = frame.parameters
    np.testing.assert_array_equal(np.asarray(params["head_pose"]), [2.0, -3.0, 1.0])
    jvp = jax.jit(lambda p, t: jax.jvp(frame, (p,), (t,)))
    zero = jax.tree.map(jnp.zeros_like, params)

    def weighted(image):
        return float(np.sum(weights.astype(np.float64) * np.asarray(image)))

    derivatives, differences = [], []
    for axis in range(3):  # steps of 0.02°: a fiftieth of an eye's pixel at 8 pixels over 30°
        tangent = with_entry(zero, "head_pose", axis, 1.0)
        derivatives.append(weighted(jvp(params, tangent)[1]))
        x0 = np.float32(params["head_pose"][axis])
        plus, minus = (with_entry(params, "head_pose", axis, x0 + np.float32(s * 2e-2)) for s in (1, -1))
        step = float(plus["head_pose"][axis]) - float(minus["head_pose"][axis])
        differences.append((weighted(jvp(plus, zero)[0]) - weighted(jvp(minus, zero)[0])) / step)
    largest = max(abs(d) for d in derivatives)
    for axis, (d, fd) in enumerate(zip(derivatives, differences, strict=True)):
        scale = max(abs(fd), 1e-2 * largest)
        assert abs(d - fd) <= CAMERA * scale, (axis, d, fd, abs(d - fd) / scale)
    assert np.count_nonzero(np.abs(derivatives) > 1e-3) == 3


# ---- bad input: refused before any rendering, the message naming the value -----------------


@pytest.fixture(scope="module")
def box():
    return fovjax.scenes.cornell_box()


def _render(arrays):
    raise AssertionError("bad input must be refused before anything renders")


@pytest.mark.parametrize(
    ("names", "kwargs", "match"),
    [
        (("kd", "diffuse"), {}, "unknown parameter 'diffuse'; the parameters are ka, kd, ks"),
        ((), {}, "choose at least one parameter from ka, kd"),
        (("kd", "ns", "kd"), {}, "parameter 'kd' chosen twice"),
        (("kd",), {"materials": ("red", "purple")}, "no material named 'purple'; the scene's are white, red"),
        (("kd",), {"materials": (1, 6)}, "material row 6 is out of range for 6 material rows"),
        (("kd",), {"materials": (1, "red")}, r"materials= names material row\(s\) \[1\] more than once"),
        (("kd",), {"materials": ()}, "materials= is empty"),
        (("light_color",), {"materials": ("red",)}, "materials= selects rows of ka, kd, ks, ke, kr, ns"),
        (("kd",), {"lights": (0,)}, "lights= selects rows of light_position, light_color"),
        (("light_color",), {"lights": (1,)}, "light row 1 is out of range for 1 light rows"),
        (("vertices",), {"vertices": (10_000,)}, "vertex row 10000 is out of range"),
        (("camera_position",), {}, "'camera_position' is the view's position; pass view="),
        (("head_pose",), {}, "the 'head_pose' parameter needs a starting head_pose="),
    ],
)
def test_bad_choices_are_refused_with_the_valid_ones(box, names, kwargs, match):
    with pytest.raises(ValueError, match=match):
        differentiable(_render, box, names, **kwargs)


def test_material_names_need_the_scene(box):
    with pytest.raises(ValueError, match="material name 'red' needs the Scene"):
        differentiable(_render, scene_arrays(box), "kd", materials=("red",))
    by_index = differentiable(_render, scene_arrays(box), "kd", materials=(1,))
    by_name = differentiable(_render, box, "kd", materials=("red",))
    np.testing.assert_array_equal(by_index.parameters["kd"], by_name.parameters["kd"])
    np.testing.assert_array_equal(by_name.parameters["kd"], np.asarray(box.materials.kd)[[1]])


@pytest.mark.no_typecheck
def test_bad_types_are_refused(box):
    with pytest.raises(TypeError, match="render_fn must be callable, got str"):
        differentiable("render", box, "kd")
    with pytest.raises(TypeError, match="view must be a Camera or a StereoRig, got tuple"):
        differentiable(_render, box, "camera_position", view=(0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match=r"unknown parameter 3; the parameters are"):
        differentiable(_render, box, ("kd", 3))


def test_wrong_parameters_are_refused_before_rendering(box):
    frame = differentiable(_render, box, ("kd", "light_color"), materials=("red", "green"))
    assert isinstance(frame, Differentiable) and frame.names == ("kd", "light_color")
    params = frame.parameters
    assert params["kd"].shape == (2, 3) and params["light_color"].shape == (1, 3)
    with pytest.raises(
        ValueError, match=r"the parameters are kd, light_color; got kd \(missing light_color\)"
    ):
        frame(Parameters({"kd": params["kd"]}))
    with pytest.raises(ValueError, match=r"\(not chosen: ks\)"):
        frame(Parameters({**params.values, "ks": params["kd"]}))
    with pytest.raises(ValueError, match=r"parameter 'kd' must have shape \(2, 3\), got \(6, 3\)"):
        frame(Parameters({"kd": jnp.zeros((6, 3)), "light_color": params["light_color"]}))
    with pytest.raises(KeyError, match="no parameter 'ks'; these are kd, light_color"):
        params["ks"]


@pytest.mark.no_typecheck
def test_a_dict_is_not_parameters(box):
    frame = differentiable(_render, box, "kd")
    with pytest.raises(TypeError, match="expected a Parameters \\(this frame's: kd\\), got dict"):
        frame({"kd": frame.parameters["kd"]})
    with pytest.raises(TypeError, match="Parameters: values must be a dict of name -> array, got list"):
        Parameters([frame.parameters["kd"]])


def test_every_name_is_documented_and_put_back(box):
    """Each name reaches its place: the parameters made from a scene are its values, and a
    changed value comes back from `inputs` where the renderer reads it (and nothing else moves)."""
    camera = fovjax.Camera.look_at((0.0, 0.3, 2.0), (0.0, 0.3, 0.0), width=4, height=4)
    doc = differentiable.__doc__ or ""
    for name in PARAMETER_NAMES:
        assert f"`{name}`" in doc, name
        frame = differentiable(_render, box, name, view=camera, head_pose=(1.0, 2.0, 3.0))
        params = frame.parameters
        changed = jax.tree.map(lambda x: x + 0.25, params)
        arrays, view, head_pose = frame.inputs(changed)
        if name == "camera_position":
            placed, before = view.position, camera.position
        elif name == "head_pose":
            placed, before = head_pose, np.array([1.0, 2.0, 3.0])
        else:
            placed, before = getattr(arrays, name), getattr(frame.arrays, name)
        np.testing.assert_allclose(np.asarray(placed), np.asarray(before) + 0.25, err_msg=name)
        untouched = [n for n in ("kd", "vertices", "light_color") if n != name]
        for other in untouched:
            np.testing.assert_array_equal(
                np.asarray(getattr(arrays, other)), np.asarray(getattr(frame.arrays, other))
            )
