"""`RigGeometry`: the devices layer's plain-number rig agrees with the renderer's cameras and
eccentricity, and the synthetic gaze source puts each eye where that eye sees the point."""

from __future__ import annotations

import math
import re

import jax.numpy as jnp
import numpy as np
import pytest

from fovjax.devices import FixedPoints, GazeCorrection, RigGeometry, SyntheticGazeSource
from fovjax.foveate import eccentricity_angle
from fovjax.render import StereoRig, head_rotation

XY = np.array([[0.2, 0.7], [0.9, 0.1], [0.5, 0.5], [0.03, 0.97]])


def test_the_defaults_are_the_thesis_rig_as_the_renderer_has_it():
    default = RigGeometry.from_rig(StereoRig.look_at((0.0, 0.0, 0.0), (0.0, 0.0, -1.0)))
    assert default.matches(RigGeometry())
    assert RigGeometry().hfov_deg == pytest.approx(90.0) and RigGeometry().toe_out_deg == 13.0


@pytest.mark.parametrize("fov_axis", ["horizontal", "vertical"])
def test_rays_projections_and_angles_are_the_renderers(fov_axis):
    """Through both eyes of a toed-out rig with off-axis offsets and a head pose: the same rays
    (in the head frame) as the eye cameras', the same projections, and the same angle as the
    renderer's exact-angle eccentricity."""
    rig = StereoRig.look_at(
        (0.3, 1.2, -0.4), (2.0, 1.0, -3.0), eye_width=64, eye_height=48, fov_deg=70.0, fov_axis=fov_axis
    ).with_eye_placement(offsets=((0.1, 0.05), (-0.08, 0.02)))
    geometry = RigGeometry.from_rig(rig)
    pose = (20.0, -7.0, 4.0)
    world_from_head = np.asarray(rig.rotation, np.float64) @ np.asarray(head_rotation(pose), np.float64)
    size = np.array([rig.eye_width, rig.eye_height])
    for eye, camera in enumerate(rig.eye_cameras(pose)):
        rays = np.asarray(camera.ray_directions(XY * size), np.float64)
        np.testing.assert_allclose(geometry.ray(eye, XY) @ world_from_head.T, rays, atol=1e-5)
        head_points = geometry.eye_position(eye) + 2.5 * geometry.ray(eye, XY)
        world = (
            np.asarray(camera.position, np.float64)
            + (head_points - geometry.eye_position(eye)) @ world_from_head.T
        )
        pixels, depth = camera.project(jnp.asarray(world, jnp.float32))
        np.testing.assert_allclose(geometry.project(eye, head_points), np.asarray(pixels) / size, atol=1e-5)
        assert np.all(np.asarray(depth) > 0)
        ecc = np.asarray(eccentricity_angle(camera, XY[0], XY * size), np.float64)
        np.testing.assert_allclose(geometry.angle_deg(eye, XY[0], XY), ecc, atol=1e-3)


def test_fixation_and_transfer_agree():
    """The point both eyes look at: its position in one eye, carried through the rig at its
    distance from that eye, is its position in the other; at infinity only the direction."""
    g = RigGeometry()
    for xy in ((0.5, 0.5), (0.3, 0.7), (0.62, 0.2)):
        for distance in (0.4, 3.0, math.inf):
            left, right = g.fixation(xy, distance)
            along = distance
            if math.isfinite(distance):
                along = float(np.linalg.norm(distance * g.cyclopean_ray(xy) - g.eye_position("left")))
            np.testing.assert_allclose(g.transfer(left, "left", along), right, atol=1e-12)
    # Straight ahead, far: each eye sees it 13° from its own centre, towards the nose.
    left, right = g.fixation((0.5, 0.5))
    assert g.angle_deg("left", left, (0.5, 0.5)) == pytest.approx(13.0)
    assert left[0] > 0.5 > right[0] and left[0] + right[0] == pytest.approx(1.0)
    # Nearer, the eyes converge: each eye's point moves towards the nose.
    near_left, near_right = g.fixation((0.5, 0.5), 0.5)
    assert near_left[0] > left[0] and near_right[0] < right[0]


def test_a_point_behind_an_eye_has_no_display_position():
    g = RigGeometry()
    assert np.isnan(g.project("left", (0.0, 0.0, 1.0))).all()


def test_matches_ignores_the_resolution_not_the_rig():
    assert RigGeometry(eye_width=320, eye_height=256).matches(RigGeometry())
    assert not RigGeometry(eye_width=320, eye_height=320).matches(RigGeometry())
    assert not RigGeometry(toe_out_deg=0.0).matches(RigGeometry())


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"eye_width": 0}, "eye_width must be a positive integer, got 0"),
        ({"eye_height": 2.5}, "eye_height must be a positive integer, got 2.5"),
        ({"fov_deg": 180.0}, "fov_deg must be in (0, 180), got 180.0"),
        ({"fov_axis": "diagonal"}, "fov_axis must be 'horizontal' or 'vertical', got 'diagonal'"),
        ({"toe_out_deg": math.nan}, "toe_out_deg must be finite"),
        ({"ipd": -0.06}, "ipd must be >= 0, got -0.06"),
        ({"offsets": ((0.0, 0.0),)}, "offsets must be ((x, y) left, (x, y) right)"),
    ],
)
@pytest.mark.no_typecheck
def test_bad_rigs_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=f"RigGeometry: {re.escape(message)}"):
        RigGeometry(**kwargs)


@pytest.mark.no_typecheck
def test_bad_arguments_name_what_is_wrong():
    g = RigGeometry()
    with pytest.raises(ValueError, match="expected a fovjax.render.StereoRig, got object without eye_width"):
        RigGeometry.from_rig(object())
    with pytest.raises(ValueError, match="eye must be 'left' or 'right', got 'middle'"):
        g.ray("middle", (0.5, 0.5))
    with pytest.raises(ValueError, match="distance must be > 0"):
        g.fixation((0.5, 0.5), 0.0)
    with pytest.raises(ValueError, match=r"display positions must be \(\.\.\., 2\)"):
        g.ray("left", (0.5, 0.5, 0.5))


def test_synthetic_gaze_puts_each_eye_where_it_sees_the_point():
    """On the thesis's rig the display centre of the head's view is at x = 0.615 in the left
    eye and 0.385 in the right (not one position for both); nearer, the eyes converge."""
    g = RigGeometry()
    far = SyntheticGazeSource(FixedPoints([(0.5, 0.5)]), geometry=g, speed=None, duration=0.05)
    sample = far.open().read()
    assert sample.left.x == pytest.approx(0.6154, abs=1e-4) and sample.right.x == pytest.approx(
        0.3846, abs=1e-4
    )
    assert sample.left.y == sample.right.y == pytest.approx(0.5)
    near = SyntheticGazeSource(
        FixedPoints([(0.3, 0.6)]), geometry=g, fixation_distance=0.6, speed=None, duration=0.05
    )
    sample = near.open().read()
    left, right = g.fixation((0.3, 0.6), 0.6)
    assert (sample.left.x, sample.left.y) == (pytest.approx(left[0]), pytest.approx(left[1]))
    assert (sample.right.x, sample.right.y) == (pytest.approx(right[0]), pytest.approx(right[1]))
    # Without a rig both eyes are at the model's point (parallel displays, far away).
    plain = SyntheticGazeSource(FixedPoints([(0.3, 0.6)]), speed=None, duration=0.05).open().read()
    assert plain.left.xy == plain.right.xy == (0.3, 0.6)


def test_synthetic_distortion_moves_each_eye_by_its_map():
    distortion = GazeCorrection(
        left=((1.0, 0.0, 0.05), (0.0, 1.0, 0.0)), right=((2.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    )
    source = SyntheticGazeSource(FixedPoints([(0.3, 0.6)]), distortion=distortion, speed=None, duration=0.05)
    sample = source.open().read()
    assert sample.left.xy == (pytest.approx(0.35), pytest.approx(0.6))
    assert sample.right.xy == (pytest.approx(0.6), pytest.approx(0.6))


@pytest.mark.no_typecheck
def test_synthetic_gaze_refuses_a_rig_and_a_vergence_offset_together():
    with pytest.raises(ValueError, match="give vergence_offset .* or geometry, not both"):
        SyntheticGazeSource(FixedPoints(), geometry=RigGeometry(), vergence_offset=0.02)
    with pytest.raises(ValueError, match="fixation_distance must be > 0"):
        SyntheticGazeSource(FixedPoints(), geometry=RigGeometry(), fixation_distance=0.0)
    with pytest.raises(TypeError, match="geometry must be a fovjax.devices.RigGeometry"):
        SyntheticGazeSource(FixedPoints(), geometry="thesis")
