"""Temporal stability: the flicker measure, gaze sequences, and fresh against fixed key on a tiny
rendered sequence."""

from __future__ import annotations

import numpy as np
import pytest

import fovjax
from fovjax.acuity import THESIS_MODEL, LinearMAR
from fovjax.eval import (
    FullRenders,
    equal_budget_foveations,
    flicker,
    gaze_sequence,
    region_masks,
    temporal_stability,
)
from fovjax.foveate import Constant, Foveation, LinearFalloff
from fovjax.render import RenderConfig, StereoRig

# max_depth 0 and a tiny rig keep the two compiles (full, foveated) short; the failure-case
# tests use the same scene, rig, config and foveation, so a shared session compiles once.
CONFIG = RenderConfig(max_depth=0)
# The equal-budget arms of these models share one ray budget; their reference ("thesis") arm is
# the foveation of every test, so every foveated frame here reuses one compiled program.
MODELS = {
    "thesis": THESIS_MODEL,
    "linear MAR": LinearMAR(1.0, 2.35),
    "fall-off": LinearFalloff(),
    "constant": Constant(),
}


@pytest.fixture(scope="module")
def tiny():
    scene = fovjax.scenes.spheres(subdivisions=1, ground_cells=2)
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=64, eye_height=48)
    budget = equal_budget_foveations(rig, Foveation(10.0, 20.0), MODELS, gazes=((0.5, 0.5),))
    return scene, rig, budget.foveations["thesis"]


def test_flicker_of_identical_frames_is_zero_and_of_a_step_is_the_step():
    rng = np.random.default_rng(0)
    frame = rng.uniform(0, 1, (8, 10, 3))
    assert np.array_equal(flicker(np.stack([frame] * 4)), np.zeros(3))
    steps = np.stack([np.full((4, 5, 3), v) for v in (0.2, 0.5, 0.5, 0.1)])
    np.testing.assert_allclose(flicker(steps, transfer="linear"), [0.3, 0.0, 0.4])
    # sRGB: the encoded values differ, not the linear ones.
    enc = fovjax.eval.display_encode(np.array([0.2, 0.5]))
    np.testing.assert_allclose(flicker(steps[:2]), [enc[1] - enc[0]])


def test_flicker_uses_pixels_in_the_mask_in_both_frames():
    images = np.zeros((3, 2, 2, 3))
    images[1, 0, 0] = 1.0  # pixel (0, 0) changes 0 -> 1 -> 0
    masks = np.ones((3, 2, 2), bool)
    np.testing.assert_allclose(flicker(images, masks, transfer="linear"), [0.25, 0.25])
    masks[2, 0, 0] = False  # out of the mask in frame 2: the second step ignores it
    np.testing.assert_allclose(flicker(images, masks, transfer="linear"), [0.25, 0.0])
    assert np.isnan(flicker(images, np.zeros_like(masks))).all()


def test_region_masks_side_by_side():
    regions = np.array([[[0, 1], [2, 2]], [[1, 1], [0, 2]]])
    m = region_masks(regions)
    assert m["fovea"].shape == (2, 4)
    assert m["fovea"].tolist() == [[True, False, False, False], [False, False, True, False]]
    assert (m["beyond_fovea"] == (m["periphery"] | m["outside"])).all()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"images": np.zeros((1, 2, 2, 3))}, "F >= 2"),
        ({"images": np.zeros((2, 2, 2))}, "F >= 2"),
        ({"images": np.full((2, 2, 2, 3), np.nan)}, "NaN"),
        ({"images": np.zeros((2, 2, 2, 3)), "masks": np.ones((2, 3, 2), bool)}, "masks shape"),
        ({"images": np.zeros((2, 2, 2, 3)), "transfer": "gamma"}, "transfer"),
    ],
)
def test_flicker_rejects_bad_inputs(kwargs, match):
    with pytest.raises(ValueError, match=match):
        flicker(**kwargs)


def test_gaze_sequence_from_models_callables_and_arrays():
    from fovjax.devices import SmoothPursuit

    g = gaze_sequence(SmoothPursuit(frequency=1.0), 5, fps=10.0)
    assert g.shape == (5, 2, 2) and np.allclose(g[:, 0], g[:, 1])
    assert not np.allclose(g[0], g[1])
    assert np.allclose(gaze_sequence(lambda t: (0.1 + t, 0.5), 3, fps=10.0)[:, 0, 0], [0.1, 0.2, 0.3])
    assert gaze_sequence((0.4, 0.6), 3).shape == (3, 2, 2)
    per_frame = np.random.default_rng(1).uniform(0, 1, (4, 2, 2))
    assert np.allclose(gaze_sequence(per_frame, 4), per_frame)
    with pytest.raises(ValueError, match="frame 2"):
        gaze_sequence(lambda t: (0.5, 0.5 + 3 * t), 3, fps=10.0)
    with pytest.raises(ValueError, match="frames must be"):
        gaze_sequence((0.5, 0.5), 1)
    with pytest.raises(ValueError, match="gaze array"):
        gaze_sequence(np.zeros((3, 3)), 4)
    with pytest.raises(ValueError, match="fps"):
        gaze_sequence((0.5, 0.5), 3, fps=0.0)


def test_fixed_key_is_still_on_a_still_gaze_and_fresh_key_flickers(tiny, tmp_path):
    scene, rig, fov = tiny
    full = FullRenders(scene, rig, CONFIG)
    result = temporal_stability(full, (0.5, 0.5), fov, frames=3)
    by = {r["key_mode"]: r for r in result.summary}
    assert by["fixed"]["flicker_beyond_fovea"] == 0.0
    assert by["fixed"]["full_same_policy_flicker_beyond_fovea"] == 0.0
    assert by["fresh"]["flicker_beyond_fovea"] > 0.0
    assert by["fresh"]["full_fresh_flicker_beyond_fovea"] > 0.0
    assert by["fixed"]["flicker_beyond_fovea"] <= by["fresh"]["flicker_beyond_fovea"]
    assert result.ratio("fixed") == 0.0 and result.ratio("fresh") > 0.0
    # The fresh-key foveated fovea is the fresh-key full render's: same keys, same samples.
    assert by["fresh"]["flicker_fovea"] == pytest.approx(by["fresh"]["full_fresh_flicker_fovea"], abs=1e-6)
    assert len(result.records) == 2 * 2 and all(r["gaze_step_deg"] < 1e-3 for r in result.records)
    paths = result.write(tmp_path)
    assert all(p.exists() and p.stat().st_size > 0 for p in paths.values())


def test_moving_gaze_makes_fixed_key_flicker(tiny):
    scene, rig, fov = tiny
    moving = np.array([(0.3, 0.5), (0.5, 0.5), (0.7, 0.5)])
    result = temporal_stability(FullRenders(scene, rig, CONFIG), moving, fov, frames=3, key_modes="fixed")
    (row,) = result.summary
    assert row["full_same_policy_flicker_beyond_fovea"] == 0.0
    assert row["flicker_beyond_fovea"] > 0.0  # the eccentricity map moved, the key did not
    assert all(r["gaze_step_deg"] > 5 for r in result.records)


def test_temporal_stability_rejects_bad_inputs(tiny):
    scene, rig, fov = tiny
    full = FullRenders(scene, rig, CONFIG)
    with pytest.raises(ValueError, match="key_modes"):
        temporal_stability(full, (0.5, 0.5), fov, frames=2, key_modes="random")
    with pytest.raises(ValueError, match="head_poses"):
        temporal_stability(full, (0.5, 0.5), fov, frames=2, head_poses=np.zeros((3, 3)))


@pytest.mark.no_typecheck
def test_temporal_stability_needs_full_renders_of_what_to_render(tiny):
    scene, _, fov = tiny
    with pytest.raises(TypeError, match="the first argument must be a fovjax.eval.FullRenders"):
        temporal_stability(scene, (0.5, 0.5), fov, frames=2)
