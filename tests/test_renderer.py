"""One preparation path: the same foveated frame through every entry point — `render_foveated`,
a `FoveatedRenderer`, its batch, the session loop and the viewer's renderer — with geometry
levels of detail and both image tiles on (the preparation `render_foveated_batch` once skipped),
gives the same image, ray counts and traced samples, on one compiled frame program."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import fovjax
from fovjax.foveate import DEBUG_VIEW_DIAGNOSTICS, Fidelity, FoveatedRenderer, Foveation, render_foveated
from fovjax.render import TRACE_COUNTS, RenderConfig, StereoRig
from fovjax.scene import lod_levels

CONFIG = RenderConfig(max_depth=1)
# Levels of detail in the periphery and outside, the fovea tile and the pixel grid: every part
# of the preparation a frame can need.
FOVEATION = Foveation.thesis(
    0,
    fidelity=(Fidelity(), Fidelity(lod=1), Fidelity(lod=2, shadows="none")),
    fovea_tile_deg=10.0,
    grid_tile=True,
)
# The debug view's outputs (traced samples, regions, pre-fill means): what the session and the
# viewer return with their debug view on, so every entry point runs the same program.
DIAGNOSTICS = ("region", *DEBUG_VIEW_DIAGNOSTICS)
GAZE = ((0.4, 0.45), (0.45, 0.45))


@pytest.fixture(scope="module")
def prepared(tmp_path_factory):
    scene = fovjax.scenes.spheres(subdivisions=1, ground_cells=4)
    levels = lod_levels(scene, (1.0, 0.5, 0.25), cache_dir=tmp_path_factory.mktemp("lod"))
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=48, eye_height=32)
    renderer = FoveatedRenderer(scene, rig, FOVEATION, CONFIG, lod_levels=levels, diagnostics=DIAGNOSTICS)
    return scene, rig, levels, renderer


def _same(frame, reference):
    assert np.array_equal(frame.image, reference.image)
    assert np.array_equal(frame.sample_mask, reference.sample_mask)
    assert np.array_equal(frame.regions, reference.regions)
    assert frame.stats.rays == reference.stats.rays
    assert frame.foveation == reference.foveation


def test_every_entry_point_renders_the_same_frame(prepared, tmp_path):
    from fovjax.files import load_image, save_image
    from fovjax.view import LiveRenderer

    scene, rig, levels, renderer = prepared
    # The preparation really includes the tiles and the merged levels.
    assert renderer.tile is not None and renderer.grid == FOVEATION.blocks[1]
    assert renderer._tables[0] is not None  # LODTables
    key = jax.random.key(5)
    traced_before = TRACE_COUNTS["foveated"]
    reference = render_foveated(
        scene,
        rig,
        gaze=GAZE,
        foveation=FOVEATION,
        key=key,
        config=CONFIG,
        lod_levels=levels,
        diagnostics=DIAGNOSTICS,
    )
    _same(renderer.render(GAZE, key=key), reference)

    # The batch: the same samples, rays and regions; the same image (one frame after another
    # in `lax.map`, compiled as its own program).
    batch = renderer.render_batch([GAZE], keys=[key])
    assert np.array_equal(batch.sample_mask[0], reference.sample_mask)
    assert np.array_equal(batch.regions[0], reference.regions)
    assert int(batch.rays[0]) == reference.stats.rays
    np.testing.assert_allclose(batch.images[0], reference.image, rtol=1e-5, atol=1e-6)

    # The session: its first frame (key folded with 0) at the gaze and thresholds it logged.
    out = tmp_path / "session"
    result = fovjax.run_session(
        renderer,
        gaze="synthetic:fixed:0.4,0.45",
        session=fovjax.SessionConfig(frames=1),
        out=fovjax.SessionOutput(out, debug=True),
        key=key,
        progress=False,
    )
    (row,) = result.frames
    thresholds = (row.fovea_deg, row.periphery_deg)
    expected = renderer.render(
        (row.gaze_left, row.gaze_right), key=jax.random.fold_in(key, 0), thresholds=thresholds
    )
    assert row.primary_rays == expected.stats.primary_rays and row.shadow_rays == expected.stats.shadow_rays
    for name, image in (("frame_00000.png", expected.image), ("debug_00000.png", expected.debug_view)):
        save_image(tmp_path / name, image)  # the session's own encoding of the frame
        assert np.array_equal(load_image(out / name), load_image(tmp_path / name)), name

    # The viewer: mouse gaze on the left eye, its debug view on.
    live = LiveRenderer(renderer, None, None, seed=11)
    live.apply_action("toggle_debug")
    live.set_mouse("left", 0.4, 0.45, 0.0)
    shown = live.render_next()
    expected = renderer.render(
        tuple(shown.stats[name] for name in ("gaze_left", "gaze_right")),
        key=jax.random.fold_in(jax.random.key(11), 0),
        thresholds=(FOVEATION.fovea_deg, FOVEATION.periphery_deg),
    )
    assert np.array_equal(shown.image, expected.image)
    assert np.array_equal(shown.debug_image, expected.debug_view)
    assert shown.stats["rays"] == expected.stats.rays
    # One frame program served them all.
    assert TRACE_COUNTS["foveated"] - traced_before == 1


def test_a_new_gaze_pose_key_or_threshold_pair_compiles_nothing(prepared):
    *_, renderer = prepared
    renderer.render(GAZE, key=jax.random.key(0))
    traced = TRACE_COUNTS["foveated"]
    frame = renderer.render(
        ((0.7, 0.2), (0.65, 0.2)), head_pose=(10.0, -4.0, 2.0), key=jax.random.key(1), thresholds=(7.5, 15.0)
    )
    assert frame.stats.compile_seconds == 0.0 and TRACE_COUNTS["foveated"] == traced
    assert (frame.foveation.fovea_deg, frame.foveation.periphery_deg) == (7.5, 15.0)


@pytest.mark.no_typecheck
def test_bad_arguments_name_the_value(prepared):
    scene, rig, levels, renderer = prepared
    with pytest.raises(TypeError, match="foveation must be a Foveation"):
        FoveatedRenderer(scene, rig, "thesis")
    with pytest.raises(ValueError, match="periphery_deg"):
        renderer.render(GAZE, thresholds=(10.0, 5.0))
    with pytest.raises(ValueError, match="off-screen"):
        renderer.render(((1.5, 0.5), (0.5, 0.5)))
    with pytest.raises(ValueError, match="with_rig"):
        renderer.with_rig(
            StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=64, eye_height=32)
        )
