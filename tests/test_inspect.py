"""`fovjax.eval.inspect_scene` and `fovjax inspect` on hand-checkable scenes (tiny images: every
share is a handful of full renders).

- One triangle straight down the left eye's gaze ray: it is the only triangle, in the left
  eye's innermost ring; its ambient + one light split the radiance, and they sum to the total.
- The Cornell box has no mirror (every kr is 0): reflection depths beyond 0 add nothing.
"""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest

import fovjax
from fovjax.eval import inspect_scene
from fovjax.foveate import Foveation
from fovjax.render import StereoRig


def _rig(scene, size=8):
    return StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=size, eye_height=size)


def test_one_triangle_on_the_gaze_ray_is_in_the_innermost_ring():
    probe = fovjax.scenes.cornell_box()
    rig = _rig(probe)
    left = rig.eye_cameras((0.0, 0.0, 0.0))[0]
    d = np.array(left.ray_directions(jnp.float32([4.0, 4.0])))  # the centre: gaze (0.5, 0.5)
    d /= np.linalg.norm(d)
    centre = np.asarray(left.position) + 3.0 * d
    # A triangle facing the eye with its centroid on that ray, covering the four pixel centres
    # around the gaze point (0.5 px off each way: ~8° at these 11° pixels; inradius 0.5 m at 3 m).
    up = np.float32([0, 1, 0])
    side = np.cross(d, up)
    side /= np.linalg.norm(side)
    up2 = np.cross(side, d)
    corners = np.stack([side, -0.5 * side + 0.866 * up2, -0.5 * side - 0.866 * up2]) * 1.0
    corners -= corners.mean(axis=0)
    scene = fovjax.make_scene(
        (centre + corners).astype(np.float32),
        [[0, 1, 2]],
        lights=fovjax.make_lights([np.asarray(left.position)], [(1.0, 1.0, 1.0)]),
        name="one",
    )
    result = inspect_scene(scene, rig, ((0.5, 0.5), (0.5, 0.5)), Foveation(15.0, 30.0), max_depth=0)
    assert result.rings[0]["lo"] == 0.0 and result.rings[0]["hi"] == 5.0
    assert result.region_pixels["fovea"] >= 4
    assert result.rings[0]["triangles"][0] == 1
    assert sum(r["triangles"][0] for r in result.rings) == 1
    assert sum(r["triangles"][1] for r in result.rings) <= 1
    for eye in (0, 1):
        assert sum(r["pixels"][eye] for r in result.rings) == 64
    assert sum(result.region_pixels.values()) == 2 * 64
    fovea = result.light_share["fovea"]
    assert set(fovea) == {"ambient+emission", "light 0"}
    assert fovea["light 0"] > 0 and fovea["ambient+emission"] > 0
    assert abs(sum(fovea.values()) - 1.0) < 1e-4
    assert result.depth_share["fovea"] == [pytest.approx(1.0)]


def test_cornell_box_reflections_add_nothing_and_shares_sum_to_one():
    scene = fovjax.scenes.cornell_box()
    assert not np.asarray(scene.materials.kr).any()
    result = inspect_scene(scene, _rig(scene), ((0.3, 0.5), (0.3, 0.5)), Foveation(10.0, 20.0), max_depth=1)
    for region in ("fovea", "periphery", "outside"):
        depth = result.depth_share[region]
        assert depth[0] == pytest.approx(1.0, abs=1e-6) and depth[1] == pytest.approx(0.0, abs=1e-6)
        light = result.light_share[region]
        assert sum(light.values()) == pytest.approx(1.0, abs=1e-4)
    assert result.fovea_deg == 10.0 and result.periphery_deg == 20.0
    parsed = json.loads(result.to_json())
    assert parsed["scene"] == "cornell_box" and len(parsed["rings"]) == len(result.rings)
    assert "share of radiance by light" in result.table()
    assert parsed["rig"]["fov_deg"] == pytest.approx(float(_rig(scene).fov_deg))
    assert "rig: fov_deg" in result.table()


@pytest.mark.no_typecheck  # wrong types on purpose: the function's own check answers
@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"scene": "cornell_box"}, "scene must be a fovjax Scene, got str"),
        ({"max_depth": -1}, "max_depth must be an integer >= 0, got -1"),
        ({"ring_deg": 0.0}, "ring_deg must be a positive number of degrees, got 0.0"),
        ({"gaze": ((0.5, 0.5), (1.5, 0.5))}, "gaze"),
    ],
)
def test_bad_arguments(kwargs, match):
    scene = fovjax.scenes.cornell_box()
    args = {"scene": scene, "rig": _rig(scene), **kwargs}
    with pytest.raises(ValueError, match=match):
        inspect_scene(**args)


def test_command_prints_json(capsys):
    from fovjax.cli import main

    assert main(["inspect", "cornell", "--width", "8", "--height", "8", "--max-depth", "0", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["scene"] == "cornell_box" and out["eye_size"] == [8, 8] and out["max_depth"] == 0
    assert set(out["depth_share"]) == {"fovea", "periphery", "outside"}
