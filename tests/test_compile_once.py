"""One compiled program per rig, SPP, render config and scene shapes for a whole session: new
fovea/periphery thresholds (within `max_periphery_deg`), gaze, head pose and key reuse it, and
a session whose tracker loses the eye and widens the fovea compiles exactly once. Compiles are
counted by traces of the program (a retrace is a recompile)."""

from __future__ import annotations

import csv
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fovjax
from fovjax.foveate import Foveation
from fovjax.render import TRACE_COUNTS, RenderConfig, StereoRig, clear_compile_cache, compile_cache_info

RECORDING = (
    Path(__file__).resolve().parents[1] / "data" / "recordings" / "synthetic_scanpath_seed1_dropout.csv"
)
CONFIG = RenderConfig(max_depth=1)


@pytest.fixture(scope="module")
def cornell():
    scene = fovjax.scenes.cornell_box()
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=40, eye_height=32)
    return scene, rig


def test_new_thresholds_gaze_pose_and_key_reuse_the_program(cornell):
    scene, rig = cornell
    clear_compile_cache()
    frames = []
    for i, (pair, gaze, pose) in enumerate(
        [
            ((5.0, 10.0), ((0.5, 0.5), (0.5, 0.5)), (0, 0, 0)),
            ((7.5, 15.0), ((0.3, 0.4), (0.35, 0.4)), (5, -3, 1)),
            ((20, 40), ((0.8, 0.2), (0.75, 0.2)), (0, 0, 0)),  # ints: the same traced dtype
            ((180.0, 180.0), ((0.5, 0.5), (0.5, 0.5)), (0, 0, 0)),  # widened to full rendering
        ]
    ):
        f = Foveation.thesis(pair, spp=1)
        frames.append(
            fovjax.render_stereo(
                scene, rig, gaze=gaze, foveation=f, head_pose=pose, key=jax.random.key(i), config=CONFIG
            )
        )
    assert TRACE_COUNTS["foveated"] == 1 and compile_cache_info()["foveated"] == 1
    assert frames[0].stats.compile_seconds > 0
    assert [f.stats.compile_seconds for f in frames[1:]] == [0.0, 0.0, 0.0]
    # The thresholds really changed the frame: more foveal rays as the fovea widens, and at
    # 180° every sample is traced.
    fovea_rays = [f.foveation.primary_by_region[0] for f in frames]
    assert fovea_rays[0] < fovea_rays[1] < fovea_rays[2] < fovea_rays[3] == 2 * 40 * 32
    assert frames[3].stats.primary_rays == 2 * 40 * 32
    assert [f.foveation.fovea_deg for f in frames] == [5.0, 7.5, 20.0, 180.0]


def test_thresholds_beyond_the_maximum_are_rejected(cornell):
    scene, rig = cornell
    with pytest.raises(ValueError, match="max_periphery_deg"):
        Foveation(fovea_deg=5, periphery_deg=30, max_periphery_deg=20)
    capped = Foveation(fovea_deg=5, periphery_deg=10, max_periphery_deg=20)
    wider = Foveation(fovea_deg=10, periphery_deg=20, max_periphery_deg=20)
    a = fovjax.render_stereo(scene, rig, foveation=capped, key=jax.random.key(0), config=CONFIG)
    b = fovjax.render_stereo(scene, rig, foveation=wider, key=jax.random.key(0), config=CONFIG)
    # A capped maximum plans a smaller budget, the same for every pair within it.
    assert a.foveation.budget == b.foveation.budget < 2 * 40 * 32
    assert b.stats.compile_seconds == 0.0 and a.foveation.dropped == b.foveation.dropped == 0


@pytest.mark.parametrize("show_samples", [False, True])
def test_a_session_with_tracking_loss_compiles_once(tmp_path, capsys, show_samples):
    """`fovjax session` over the recording with a 1 s dropout: the tracker holds, widens the
    fovea step by step to full rendering and recovers, all on one compiled program; also when
    it writes the debug view of every frame (the frame program returns its outputs then)."""
    from fovjax.cli import main

    clear_compile_cache()
    out = tmp_path / "session"
    args = ["session", "--gaze", f"replay:{RECORDING}", "--seconds", "4", "--fps", "10", "--scene", "cornell"]
    args += ["--width", "40", "--height", "32", "--max-depth", "1", "--no-progress", "-o", str(out)]
    args += ["--show-samples"] if show_samples else []
    assert main(args) == 0
    capsys.readouterr()
    with open(out / "session.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 40
    widenings = {round(float(r["fovea_deg"]), 3) for r in rows}
    states = {r["tracking_state"] for r in rows}
    assert len(widenings) >= 3 and {"ok", "lost"} <= states, (widenings, states)
    assert TRACE_COUNTS["foveated"] == 1, dict(TRACE_COUNTS)
    assert compile_cache_info() == {"foveated": 1}
    compile_s = np.array([float(r["compile_s"]) for r in rows])
    assert (compile_s[1:] == 0).all() and compile_s[0] > 0
    assert len(list(out.glob("debug_*.png"))) == (40 if show_samples else 0)
    assert all(int(r["fovea_pixels"]) > 0 for r in rows)  # the regions the frame returned


def test_frame_programs_compile_with_loop_emitters_unless_told_otherwise(monkeypatch):
    from fovjax.render.internal import LOOP_EMITTERS, frame_compiler_options

    monkeypatch.delenv("FOVJAX_XLA_EMITTERS", raising=False)
    assert LOOP_EMITTERS == {"xla_cpu_use_fusion_emitters": False}
    for entry in ("mono", "stereo", "batch:full", "foveated-weier2016"):
        assert frame_compiler_options(entry) == LOOP_EMITTERS, entry
        # XLA:CPU's option only: XLA's GPU compiler refuses options it does not know.
        assert frame_compiler_options(entry, "gpu") == {}, entry
    for entry in ("foveated", "batch:foveated"):  # the thesis's foveated frame: XLA's default
        assert frame_compiler_options(entry) == {}, entry
    from fovjax.render._frame import _program_platform

    assert _program_platform((jnp.zeros(3), 1.0)) == jax.devices()[0].platform
    monkeypatch.setenv("FOVJAX_XLA_EMITTERS", "fusion")
    assert frame_compiler_options("stereo") == {}
    monkeypatch.setenv("FOVJAX_XLA_EMITTERS", "loop")
    assert frame_compiler_options("foveated") == LOOP_EMITTERS
    monkeypatch.setenv("FOVJAX_XLA_EMITTERS", "fast")
    with pytest.raises(ValueError, match="FOVJAX_XLA_EMITTERS='fast': expected one of auto, loop, fusion"):
        frame_compiler_options("stereo")
    # Read when a program compiles: a bad setting is said before any work.
    scene = fovjax.scenes.spheres(subdivisions=0, ground_cells=1)
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=8, eye_height=8)
    with pytest.raises(ValueError, match="'fast'"):
        fovjax.render.render_stereo(scene, rig, config=RenderConfig(max_depth=0))
