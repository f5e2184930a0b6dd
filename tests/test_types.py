"""Wrong types are answered with a TypeError that names the parameter, before any work.

The public functions of `fovjax.render`, `fovjax.trace` and `fovjax.foveate` are annotated
(jaxtyping shapes for arrays); while the suite runs, jaxtyping's import hook checks every call
against the annotations (tests/conftest.py). These pin that a wrong type or a wrong array shape
is refused with a `TypeError` naming the parameter, before a BVH is built or a program compiled
(the calls below would otherwise take seconds). The type checker's pass over the package is
tests/test_type_check.py."""

from __future__ import annotations

import os

import jax
import numpy as np
import pytest

import fovjax
from fovjax.foveate import FoveatedRenderer, Foveation, check_gaze, render_foveated
from fovjax.render import StereoRig, head_rotation, render_stereo_batch, scene_arrays
from fovjax.trace import Traversal, build_bvh, closest_hit, occluded

pytestmark = pytest.mark.skipif(
    os.environ.get("FOVJAX_TYPECHECK", "1") == "0",
    reason="annotation checks are off (FOVJAX_TYPECHECK=0)",
)


@pytest.fixture(scope="module")
def bvh():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    return build_bvh(vertices=V, faces=[[0, 1, 2]], cache=False)


@pytest.fixture(scope="module")
def scene_and_rig():
    scene = fovjax.scenes.cornell_box()
    return scene, StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=8, eye_height=8)


def refused(parameter: str):
    """`pytest.raises(TypeError)` whose message names `parameter` as the one that failed."""
    return pytest.raises(TypeError, match=f"parameter '{parameter}'")


RAYS = np.zeros((4, 3), np.float32), np.ones((4, 3), np.float32)


def test_ray_queries_refuse_rays_of_the_wrong_shape_or_type(bvh):
    o, d = RAYS
    with refused("origins"):
        closest_hit(bvh, np.zeros((4, 2), np.float32), d)  # not (..., 3)
    with refused("directions"):
        occluded(bvh, o, "down")
    with refused("tmax"):
        occluded(bvh, o, d, "far")
    with refused("level"):
        closest_hit(bvh, o, d, level=np.zeros(4, np.float32))  # levels are integers


def test_ray_queries_refuse_options_that_are_not_a_traversal(bvh):
    o, d = RAYS
    with refused("traversal"):
        closest_hit(bvh, o, d, traversal={"lanes": 64})
    with refused("bvh"):
        closest_hit(bvh.table, o, d)
    # A Traversal's own values are checked by it (a ValueError naming the field).
    with pytest.raises(ValueError, match="Traversal.lanes must be a positive int"):
        Traversal(lanes=0)


def test_bvh_build_refuses_faces_that_are_not_index_triples():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    with refused("faces"):
        build_bvh(vertices=V, faces=np.array([[0.0, 1.0, 2.0]]), cache=False)
    with refused("vertices"):
        build_bvh(vertices=V[:, :2], faces=[[0, 1, 2]], cache=False)


def test_rig_and_head_pose_refuse_wrong_types():
    with refused("eye_width"):
        StereoRig.look_at((0, 0, 0), (0, 0, -1), eye_width="64")
    with refused("position"):
        StereoRig.look_at("origin", (0, 0, -1))
    with refused("head_pose"):
        head_rotation(np.zeros(4, np.float32))  # (yaw, pitch, roll) is 3 angles
    with refused("head_pose"):
        head_rotation("level")


def test_foveated_entry_points_refuse_wrong_types_before_any_work(scene_and_rig):
    scene, rig = scene_and_rig
    with refused("gaze"):
        render_foveated(scene, rig, gaze="centre")
    with refused("foveation"):
        fovjax.render_stereo(scene, rig, foveation="thesis")
    with refused("config"):
        FoveatedRenderer(scene, rig, config={"max_depth": 1})
    with refused("rig"):
        FoveatedRenderer(scene, rig.eye_cameras()[0])  # a Camera is not a StereoRig
    with refused("diagnostics"):
        render_foveated(scene, rig, diagnostics=3)
    with refused("key"):
        render_foveated(scene, rig, key=7)  # a key array, not a seed
    with refused("gaze"):
        check_gaze(np.full((3, 3), 0.5))
    with refused("omega"):
        Foveation().probability("far")


def test_full_render_entry_points_refuse_wrong_types(scene_and_rig):
    scene, rig = scene_and_rig
    with refused("config"):
        fovjax.render.render_stereo(scene, rig, config="fast")
    with refused("envmap"):
        scene_arrays(scene, envmap=np.zeros((4, 8)))  # (He, We, 3)
    with refused("rig"):
        render_stereo_batch(scene, "hmd")
    with refused("key"):
        fovjax.render.render(scene, rig.eye_cameras()[0], key=jax.random.key_data(jax.random.key(0)).tolist())
