"""The frame-memory estimate (`fovjax.render.frame_memory`) and the size check built on it.

The estimate is read from what the frame programs allocate (see `fovjax/render/_memory.py`);
here it is held to be an upper bound of what XLA assigns to the compiled programs at a small
size (arguments, outputs and temporaries: `Compiled.memory_analysis()`), for the full frame
with either integrator and the foveated frame. An upper bound, not a fit: no tolerance."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import fovjax
from fovjax.render import (
    FrameTooLargeError,
    RenderConfig,
    StereoRig,
    check_frame_memory,
    frame_memory,
    memory_limit,
)
from fovjax.render import _frame as frame_module
from fovjax.render import _memory as memory_module

# An eye size no other test compiles, so the program below is this test's own.
EYE = (24, 16)


@pytest.fixture(scope="module")
def cornell():
    scene = fovjax.scenes.cornell_box()
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=EYE[0], eye_height=EYE[1])
    return scene, rig


def _compiled_bytes(before: set) -> int:
    """Arguments + outputs + temporaries of the one program compiled since `before`."""
    (key,) = set(frame_module._COMPILED) - before
    m = frame_module._COMPILED[key].memory_analysis()
    return m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes


@pytest.mark.parametrize(
    ("foveated", "integrator", "spp"),
    [(False, "auto", 4), (True, "auto", 4), (False, "jax", 1)],
    ids=["full", "foveated", "full-jax-integrator"],
)
def test_the_estimate_bounds_what_the_compiled_frame_allocates(cornell, foveated, integrator, spp):
    scene, rig = cornell
    config = RenderConfig(integrator=integrator, max_depth=2)
    before = set(frame_module._COMPILED)
    if foveated:
        fovjax.render_stereo(scene, rig, foveation=fovjax.Foveation(spp=spp), config=config)
    else:
        fovjax.render.render_stereo(scene, rig, spp=spp, config=config)
    allocated = _compiled_bytes(before)
    estimate = frame_memory(*EYE, spp, foveated=foveated, config=config)
    assert estimate >= allocated, (estimate, allocated)


def test_the_estimate_grows_with_pixels_and_samples():
    small = frame_memory(64, 64, 1, integrator="native")
    assert frame_memory(128, 64, 1, integrator="native") == 2 * small  # linear in pixels
    assert frame_memory(64, 64, 4, integrator="native") > small
    assert frame_memory(64, 64, 1, integrator="jax") > small  # the queues and a band
    assert frame_memory(64, 64, 1, eyes=1, integrator="native") == small // 2
    assert frame_memory(64, 64, 1, integrator="native", kept_images=3) == small + 3 * 12 * 2 * 64 * 64
    with pytest.raises(ValueError, match="integrator must be 'native' or 'jax', got 'cuda'"):
        frame_memory(64, 64, integrator="cuda")


def test_a_frame_over_the_limit_is_refused_naming_size_estimate_and_limit(monkeypatch):
    monkeypatch.delenv("FOVJAX_SIZE_CHECK", raising=False)
    monkeypatch.setattr(memory_module, "memory_limit", lambda platform=None: (10**6, "available here"))
    estimate = frame_memory(64, 48, 16, foveated=True, integrator="native")
    assert estimate > 10**6
    with pytest.raises(FrameTooLargeError) as err:
        check_frame_memory(64, 48, 16, foveated=True, integrator="native", where="test")
    assert str(err.value) == (
        f"test: a foveated frame of 2 x 64x48 pixels at SPP 16 needs about {estimate / 1e6:.0f} MB, "
        "more than the 1 MB available here; make it smaller, or set FOVJAX_SIZE_CHECK=0 "
        "(--no-size-check) on a machine that has the memory"
    )
    assert check_frame_memory(8, 8, 1, integrator="native") == frame_memory(8, 8, 1, integrator="native")
    monkeypatch.setenv("FOVJAX_SIZE_CHECK", "0")
    assert check_frame_memory(64, 48, 16, foveated=True, integrator="native") == estimate


def test_constructors_refuse_a_rig_no_machine_can_render(cornell, monkeypatch):
    """Where the frame is made, before the BVH or a compile: the rig, the renderer, the frame."""
    monkeypatch.delenv("FOVJAX_SIZE_CHECK", raising=False)
    scene, rig = cornell
    pose = fovjax.scenes.default_camera(scene)
    with pytest.raises(FrameTooLargeError, match=r"^StereoRig: a full frame of 2 x 1000000x1000000 pixels"):
        StereoRig.from_pose(pose, eye_width=10**6, eye_height=10**6)
    # A rig whose SPP-1 frame fits, with a frame of many samples that does not.
    monkeypatch.setattr(memory_module, "memory_limit", lambda platform=None: (10**6, "available here"))
    small = StereoRig.from_pose(pose, eye_width=8, eye_height=8)
    with pytest.raises(
        FrameTooLargeError, match=r"^FoveatedRenderer: a foveated frame of 2 x 8x8 pixels at SPP 4096"
    ):
        fovjax.FoveatedRenderer(scene, small, fovjax.Foveation(spp=4096))
    with pytest.raises(
        FrameTooLargeError, match=r"^render_stereo: a full frame of 2 x 8x8 pixels at SPP 256"
    ):
        fovjax.render_stereo(scene, small, spp=256)
    camera = fovjax.Camera.from_pose(pose, width=8, height=8)
    with pytest.raises(FrameTooLargeError, match=r"^render: a full frame of 8x8 pixels at SPP 1024"):
        fovjax.render(scene, camera, spp=1024)


def test_the_limit_is_the_available_memory_or_the_devices_free(monkeypatch):
    limit, what = memory_limit("cpu")
    assert limit is None or limit > 0
    assert what in ("available on this machine", "free under this process's memory limit (cgroup)")

    class Device:
        device_kind = "NVIDIA H100"

        def memory_stats(self):
            return {"bytes_limit": 80 * 10**9, "bytes_in_use": 5 * 10**9}

    monkeypatch.setattr(jax, "devices", lambda *a: [Device()])
    assert memory_limit("gpu") == (75 * 10**9, "free on the NVIDIA H100")


@pytest.mark.no_typecheck
def test_render_stereo_names_a_scene_that_is_not_one(cornell):
    _, rig = cornell
    with pytest.raises(TypeError, match=r"render_stereo: scene 'cornell' is not a fovjax\.Scene"):
        fovjax.render_stereo("cornell", rig)
    with pytest.raises(TypeError, match=r"render: scene 'cornell' is not a fovjax\.Scene"):
        fovjax.render.render_stereo("cornell", rig)
    assert np.isfinite(frame_memory(*EYE))
