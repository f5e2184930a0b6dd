"""Shading fidelity per region (`Fidelity`, `Foveation.fidelity`): the default is today's frame
bit for bit; a lower reflection depth or fewer shadow rays in a region trace exactly the rays
that region no longer needs and change nothing elsewhere (to float32 rounding, tests/_frames.py);
bad values fail clearly."""

from __future__ import annotations

import equinox as eqx
import jax
import numpy as np
import pytest
from _frames import assert_same_radiance

import fovjax
from fovjax.foveate import Fidelity, Foveation, render_foveated
from fovjax.foveate import _api as fov_api
from fovjax.foveate import _frame as fov_frame
from fovjax.render import RenderConfig, StereoRig
from fovjax.render.internal import SHADOWS_ALL, ShadingClasses
from fovjax.scene import make_lights

EYE_W, EYE_H = 48, 32
CONFIG = RenderConfig(max_depth=2)  # the spheres' mirror material (Kr 0.85) needs bounces
GAZE = ((0.5, 0.5), (0.5, 0.5))
FULL = Fidelity()


@pytest.fixture(scope="module")
def spheres():
    scene = fovjax.scenes.spheres(subdivisions=1, ground_cells=4)
    pose = fovjax.scenes.default_camera(scene)
    return scene, StereoRig.from_pose(pose, eye_width=EYE_W, eye_height=EYE_H)


def _render(scene, rig, fidelity=None, **kwargs):
    f = Foveation.thesis(0, fidelity=fidelity, **kwargs)
    return render_foveated(scene, rig, gaze=GAZE, foveation=f, key=jax.random.key(3), config=CONFIG)


def _counts(frame):
    s = frame.stats
    return (s.primary_rays, s.shadow_rays, s.reflection_rays)


@pytest.fixture(scope="module")
def plain(spheres):
    return _render(*spheres)


def test_default_fidelity_is_bit_identical(spheres, plain):
    for fidelity in ((FULL, FULL, FULL), (Fidelity(max_depth=2, shadows="all"),) * 3):
        frame = _render(*spheres, fidelity=fidelity)
        assert np.array_equal(frame.image, plain.image)
        assert _counts(frame) == _counts(plain)
    assert plain.stats.reflection_rays > 0 and plain.stats.shadow_rays > 0


def test_full_tables_through_the_class_path_are_the_same_frame(spheres, plain, monkeypatch):
    """The per-ray class machinery itself (not just the None shortcut) changes nothing at full
    fidelity: force full-fidelity tables through it, in a fresh compile (another program: the same
    to float32 rounding)."""
    full = ShadingClasses(np.full(3, CONFIG.max_depth, np.int32), np.full(3, SHADOWS_ALL, np.int32))
    used = []
    monkeypatch.setattr(fov_frame, "shading_classes", lambda foveation, config: used.append(1) or full)
    fovjax.render.clear_compile_cache()
    try:
        frame = _render(*spheres)
    finally:
        fovjax.render.clear_compile_cache()  # no patched program left for later tests
    assert used  # traced with the tables
    assert_same_radiance(frame.image, plain.image)
    assert _counts(frame) == _counts(plain)


def test_outside_without_reflections(spheres, plain):
    frame = _render(*spheres, fidelity=(FULL, FULL, Fidelity(max_depth=0)))
    assert frame.stats.primary_rays == plain.stats.primary_rays
    assert frame.stats.reflection_rays < plain.stats.reflection_rays
    fovea = np.concatenate([plain.regions[0], plain.regions[1]], axis=1) == 0
    assert fovea.any()
    assert_same_radiance(frame.image[fovea], plain.image[fovea])
    assert np.abs(frame.image - plain.image).max() > 1e-3
    # Depth 0 everywhere: no reflection rays at all, and the image of a frame without mirrors'
    # bounces (shadow rays of the reflections gone too).
    none = _render(*spheres, fidelity=(Fidelity(max_depth=0),) * 3)
    assert none.stats.reflection_rays == 0
    assert none.stats.shadow_rays < plain.stats.shadow_rays
    one = _render(*spheres, fidelity=(Fidelity(max_depth=1),) * 3)
    assert 0 < one.stats.reflection_rays <= plain.stats.reflection_rays


def test_no_shadows_drops_exactly_the_regions_shadow_rays(spheres, plain):
    none = Fidelity(shadows="none")
    per_region = []
    for r in range(3):
        fidelity = tuple(none if i == r else FULL for i in range(3))
        frame = _render(*spheres, fidelity=fidelity)
        assert frame.stats.primary_rays == plain.stats.primary_rays
        assert frame.stats.reflection_rays == plain.stats.reflection_rays
        per_region.append(plain.stats.shadow_rays - frame.stats.shadow_rays)
        if r == 2:
            fovea = np.concatenate([plain.regions[0], plain.regions[1]], axis=1) == 0
            assert_same_radiance(frame.image[fovea], plain.image[fovea])
    everywhere = _render(*spheres, fidelity=(none,) * 3)
    assert everywhere.stats.shadow_rays == 0
    assert all(d >= 0 for d in per_region) and per_region[0] > 0 and per_region[2] > 0
    assert sum(per_region) == plain.stats.shadow_rays
    # Unshadowed, not unlit: no pixel gets darker without its shadow rays.
    assert (everywhere.image >= plain.image - 1e-6).all()


def test_brightest_traces_only_the_brightest_lights_shadow_rays(spheres):
    scene, rig = spheres
    dim = (0.3, 0.3, 0.3)
    bright = (0.9, 0.8, 0.9)
    two = eqx.tree_at(
        lambda s: s.lights, scene, make_lights([(-4.0, 5.0, 3.0), (3.0, 6.0, 4.0)], [dim, bright])
    )
    only_bright = eqx.tree_at(lambda s: s.lights, scene, make_lights([(3.0, 6.0, 4.0)], [bright]))
    brightest = _render(two, rig, fidelity=(Fidelity(shadows="brightest"),) * 3)
    reference = _render(only_bright, rig)  # the module's one-light program
    # Every light's shadow rays in the fovea, the brightest's elsewhere: the same compiled program
    # as `brightest` (shadow modes are traced tables), so no third compile for the comparison.
    fovea_all = _render(
        two, rig, fidelity=(FULL, Fidelity(shadows="brightest"), Fidelity(shadows="brightest"))
    )
    assert _counts(brightest)[0::2] == _counts(reference)[0::2]
    # One shadow ray per hit that faces the light: exactly the single bright light's.
    assert brightest.stats.shadow_rays == reference.stats.shadow_rays
    assert brightest.stats.shadow_rays < fovea_all.stats.shadow_rays
    assert _counts(fovea_all)[0::2] == _counts(brightest)[0::2]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"shadows": "some"}, "shadows must be one of"),
        ({"max_depth": -1}, "max_depth must be None or an integer >= 0, got -1"),
        ({"max_depth": 1.5}, "got 1.5"),
    ],
)
def test_bad_fidelity_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Fidelity(**kwargs)


def test_bad_fidelity_tuple_and_depth_above_config(spheres):
    with pytest.raises(ValueError, match="three Fidelity"):
        Foveation(fidelity=(FULL, FULL))
    with pytest.raises(ValueError, match="three Fidelity"):
        Foveation(fidelity=(FULL, FULL, "none"))
    f = Foveation(fidelity=(Fidelity(max_depth=3), FULL, FULL))
    before = dict(fov_api.TRACE_COUNTS)
    with pytest.raises(ValueError, match=r"fovea.*max_depth 3 exceeds the render config's max_depth 2"):
        render_foveated(*spheres, foveation=f, config=CONFIG)
    assert dict(fov_api.TRACE_COUNTS) == before  # failed before any compile


def test_fidelity_moves_with_the_gaze_without_recompiling(spheres):
    scene, rig = spheres
    f = Foveation.thesis(0, fidelity=(FULL, Fidelity(max_depth=1), Fidelity(max_depth=0, shadows="none")))
    render_foveated(scene, rig, gaze=GAZE, foveation=f, config=CONFIG)
    traces = fov_api.TRACE_COUNTS["foveated"]
    second = render_foveated(scene, rig, gaze=((0.2, 0.3), (0.25, 0.3)), foveation=f, config=CONFIG)
    assert fov_api.TRACE_COUNTS["foveated"] == traces
    assert second.stats.compile_seconds == 0.0


def test_new_depth_or_shadow_mode_per_region_does_not_recompile(spheres, plain):
    """Depth and shadow mode per region are traced tables (`program_fidelity`): a plan's search
    over them compiles one frame program, and each table still gives its own frame."""
    scene, rig = spheres
    first = _render(scene, rig, fidelity=(FULL, FULL, Fidelity(max_depth=0)))
    traces = fov_api.TRACE_COUNTS["foveated"]
    unshadowed = _render(scene, rig, fidelity=(FULL, FULL, Fidelity(shadows="none")))
    flat = _render(scene, rig, fidelity=(Fidelity(max_depth=0, shadows="brightest"),) * 3)
    assert fov_api.TRACE_COUNTS["foveated"] == traces
    assert unshadowed.stats.compile_seconds == flat.stats.compile_seconds == 0.0
    # Not one frame served three times: each table reaches the program.
    assert first.stats.reflection_rays < plain.stats.reflection_rays
    assert unshadowed.stats.reflection_rays == plain.stats.reflection_rays
    assert unshadowed.stats.shadow_rays < plain.stats.shadow_rays
    assert flat.stats.reflection_rays == 0
