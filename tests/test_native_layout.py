"""The layout the native handlers and the Python side share (fovjax/native/csrc/layout.h): the
library's export equals the Python mirror (fovjax/native/_layout.py), the mirror equals the
constants of the packages that own each code, and the operands the wrappers build have the
layout's widths. A library whose layout differs is refused with the difference named."""

from __future__ import annotations

import _extras
import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import fovjax
from fovjax.native import _layout as layout
from fovjax.native._library import exported_layout
from fovjax.native._library import status as native_status


def test_the_library_exports_the_python_layout():
    _extras.require("embreex")
    assert native_status(), native_status().reason
    assert exported_layout() == layout.expected_layout()
    assert layout.layout_differences(exported_layout()) == []


def test_a_layout_that_differs_is_named():
    exported = dict(layout.expected_layout(), material_stride="15")
    del exported["rule_strict"]
    differences = layout.layout_differences(exported)
    assert differences == [
        "material_stride: library '15', Python '16'",
        "rule_strict: library 'missing', Python '1'",
    ]
    assert layout.parse_layout("a=1;b=x,y;") == {"a": "1", "b": "x,y"}


def test_the_mirror_is_the_owners_constants():
    from fovjax.foveate import _config, _sampling
    from fovjax.render import _config as render_config
    from fovjax.scene import _scene

    assert layout.REGIONS == {
        "fovea": _sampling.FOVEA,
        "periphery": _sampling.PERIPHERY,
        "outside": _sampling.OUTSIDE,
    }
    assert layout.CLASSES == {
        "mandatory": _sampling.MANDATORY,
        "optional": _sampling.OPTIONAL,
        "skipped": _sampling.SKIPPED,
    }
    assert set(layout.RULES) == {*_config.SAMPLING_RULES, "pixel-mask"}  # (the methods' pixel masks)
    from fovjax.render import internal as render_internal

    # The shading adjoint's field bits follow the order of the fields it returns.
    by_bit = tuple(sorted(layout.ADJOINT_FIELDS, key=layout.ADJOINT_FIELDS.get))
    assert by_bit == render_internal.SHADING_FIELDS
    assert layout.SHADOWS == {
        "all": render_internal.SHADOWS_ALL,
        "brightest": render_internal.SHADOWS_BRIGHTEST,
        "none": render_internal.SHADOWS_NONE,
    }
    assert (
        layout.LIGHT_KINDS
        == _scene.LIGHT_KINDS
        == {
            "point": _scene.POINT_LIGHT,
            "directional": _scene.DIRECTIONAL_LIGHT,
            "spot": _scene.SPOT_LIGHT,
        }
    )
    assert tuple(layout.SPECULARS) == render_config.SPECULARS
    assert sorted(layout.SPECULARS.values()) == list(range(len(render_config.SPECULARS)))
    scene = fovjax.render.scene_arrays(fovjax.scenes.cornell_box())
    for name, width in layout.MATERIAL_COLUMNS:  # each column a field of the scene, that wide
        assert np.asarray(getattr(scene, name)).reshape(len(scene.kd), -1).shape[1] == width, name
    spot = fovjax.make_lights(
        [(0, 1, 0)], [(1, 1, 1)], kind=[fovjax.SPOT_LIGHT], direction=[(0, -1, 0)], cone_deg=[30]
    )
    spot_scene = fovjax.render.scene_arrays(
        eqx.tree_at(lambda s: s.lights, fovjax.scenes.cornell_box(), spot)
    )
    light_fields = {"position": "light_position", "color": "light_color", "direction": "light_direction"}
    light_fields["cone"] = "light_cone"
    for name, width in layout.LIGHT_COLUMNS:  # each light column a field of the scene arrays, that wide
        field = np.asarray(getattr(spot_scene, light_fields[name]))
        assert field.reshape(spot_scene.num_lights, -1).shape[1] == width, name


def test_the_wrappers_build_the_layout():
    from fovjax.render import StereoRig
    from fovjax.render._native import camera_rows
    from fovjax.render.internal import whitted_operands
    from fovjax.trace import build_bvh

    scene = fovjax.scenes.cornell_box()
    arrays = fovjax.render.scene_arrays(scene)
    operands = whitted_operands(arrays, build_bvh(scene))
    assert len(operands) + 1 == len(layout.SCENE_OPERANDS)  # the ray offset comes last
    materials = operands[layout.SCENE_OPERANDS.index("materials")]
    lights = operands[layout.SCENE_OPERANDS.index("lights")]
    assert materials.shape == (len(arrays.kd), layout.MATERIAL_STRIDE)
    assert lights.shape == (len(arrays.light_kind), layout.LIGHT_STRIDE)
    assert np.array_equal(np.asarray(materials[:, 3:6]), np.asarray(arrays.kd, np.float32))  # kd second
    spot = fovjax.make_lights(
        [(0, 1, 0)], [(1, 1, 1)], kind=[fovjax.SPOT_LIGHT], direction=[(0, -2, 0)], cone_deg=[(20, 30)]
    )
    spot_arrays = fovjax.render.scene_arrays(eqx.tree_at(lambda s: s.lights, scene, spot))
    spot_operands = whitted_operands(spot_arrays, build_bvh(scene))
    row = np.asarray(spot_operands[layout.SCENE_OPERANDS.index("lights")])[0]
    # position, colour, unit axis, cos(inner), cos(outer): the columns the handler reads
    np.testing.assert_allclose(row, [0, 1, 0, 1, 1, 1, 0, -1, 0, *np.cos(np.radians([20, 30]))], rtol=1e-6)
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=8, eye_height=6)
    rows = camera_rows(rig.eye_cameras(jnp.zeros(3)))
    assert rows.shape == (2, layout.CAMERA_STRIDE)


@pytest.mark.parametrize("name", ["material_stride", "scene_operands"])
def test_the_loader_refuses_a_library_with_another_layout(monkeypatch, name):
    """What `_load` does with a library whose export differs: unavailable, the name in the reason."""
    from fovjax.native import _library

    exported = dict(layout.expected_layout(), **{name: "something else"})
    monkeypatch.setattr(_library, "layout_differences", lambda _: layout.layout_differences(exported))
    monkeypatch.setattr(_library, "_state", {})
    _extras.require("embreex")
    found = _library._load()
    assert not found and "the native layout differs" in found.reason and name in found.reason
