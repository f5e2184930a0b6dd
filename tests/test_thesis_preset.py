"""`fovjax.foveate.thesis_preset` and `fovjax render --preset thesis`: the thesis's whole
configuration in one switch, each item as docs/thesis.md tables it with the thesis's section."""

from __future__ import annotations

import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fovjax
from fovjax.acuity import THESIS_MODEL
from fovjax.foveate import THESIS_PAIRS, ThesisPreset, thesis_pixel_pitch_mm, thesis_preset
from fovjax.render import THESIS_BACKGROUND, RenderConfig

DOCS = Path(__file__).resolve().parents[1] / "docs" / "thesis.md"


def test_the_preset_sets_each_item():
    preset = thesis_preset(3)
    assert isinstance(preset, ThesisPreset)
    f, c = preset.foveation, preset.config
    assert (f.fovea_deg, f.periphery_deg) == THESIS_PAIRS[3] == (12.5, 25.0)
    # regions: the planar eccentricity of eq. 4-5 at D = 24 mm, the SX111's 16 pixels per degree
    assert (f.eccentricity, f.eye_display_mm) == ("planar", 24.0)
    assert f.pixel_pitch_mm == pytest.approx(24.0 * np.tan(np.radians(64.0 / 1024)))
    # sampling: Table 2's rule, blocks of 2 and 4, the acuity model of eq. 6-7
    assert (f.rule, f.blocks, f.acuity) == ("thesis-measured", (2, 4), THESIS_MODEL)
    # every pixel blurred (§4.5), σ fovjax's 1 pixel
    assert (f.blur_fovea, f.blur_sigma) == (True, 1.0)
    assert f.spp == 4 and f.method.name == "thesis"
    # shading: Blinn-Phong with the payload (§4.4.3), the cut-off (§2.5.2), depth 5, "bg color"
    assert (c.specular, c.specular_payload, c.min_contribution) == ("blinn-phong", True, 0.01)
    assert (c.max_depth, c.background) == (5, THESIS_BACKGROUND) == (5, (0.34, 0.55, 0.85))
    # and each item departs from fovjax's default where the table says it does
    default = fovjax.foveate.Foveation()
    assert (default.eccentricity, default.rule, default.blur_fovea, default.spp) == (
        "angle",
        "either",
        False,
        1,
    )
    assert (RenderConfig().specular_payload, RenderConfig().min_contribution) == (False, 0.0)


def test_the_pitch_follows_the_rows_and_other_settings_are_kept():
    """At half the rows a pixel is twice the angle (a threshold covers the same share of the
    display); a given config keeps its own ray backend, integrator and chunks."""
    half = thesis_preset(
        (6.0, 9.0), spp=16, eye_height=512, config=RenderConfig(backend="jax", chunk_size=512)
    )
    assert half.foveation.pixel_pitch_mm == pytest.approx(thesis_pixel_pitch_mm(512))
    assert half.foveation.pixel_pitch_mm == pytest.approx(2 * thesis_pixel_pitch_mm(1024), rel=1e-3)
    assert (half.foveation.fovea_deg, half.foveation.periphery_deg, half.foveation.spp) == (6.0, 9.0, 16)
    assert (half.config.backend, half.config.chunk_size, half.config.specular_payload) == ("jax", 512, True)
    with pytest.raises(ValueError, match="spp must be a positive square"):
        thesis_preset(0, spp=3)


def _preset_table() -> list[list[str]]:
    text = DOCS.read_text()
    section = text.split("## The thesis's configuration", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("| ") and not line.startswith("| item")]
    return [[cell.strip() for cell in row.strip("|").split("|")] for row in rows]


def test_every_item_is_tabled_with_the_thesiss_section():
    """docs/thesis.md's table names every item the preset sets, each with where in the thesis
    it comes from and fovjax's default beside it."""
    rows = {row[0]: row for row in _preset_table()}
    for item in (
        "eccentricity",
        "pixel pitch",
        "sampling rule",
        "blocks",
        "blur",
        "blur σ",
        "specular",
        "contribution cut-off",
        "background",
        "depth",
        "samples per pixel",
        "acuity",
    ):
        assert item in rows, item
        _, thesis, where, setting, default = rows[item]
        assert re.search(r"§\d|Fig \d|eq\. \d|Table \d", where), (item, where)
        assert thesis and setting and default, item
    for field in ("eccentricity=", "pixel_pitch_mm=", "rule=", "blur_fovea=", "specular_payload=",
                  "min_contribution=", "background=", "max_depth=", "spp="):  # fmt: skip
        assert any(field in row[3] for row in rows.values()), field


def _captured_render(monkeypatch, argv) -> list[dict]:
    """`fovjax render argv`'s calls of `render_stereo` (the first one stops the command)."""
    from fovjax.cli import main

    calls = []

    class Stop(BaseException):  # not an error the command reports: it stops the command
        pass

    def capture(*args, **kwargs):
        calls.append(kwargs)
        raise Stop

    monkeypatch.setattr(fovjax, "render_stereo", capture)
    with pytest.raises(Stop):
        main(["render", "--scene", "cornell", "--width", "8", "--height", "8", *argv])
    return calls


def test_render_preset_thesis_renders_with_the_preset(monkeypatch, tmp_path):
    out = ["-o", str(tmp_path / "x.png")]
    (call,) = _captured_render(
        monkeypatch, ["--preset", "thesis", "--fovea", "7.5", "--periphery", "15", *out]
    )
    expected = thesis_preset((7.5, 15.0), eye_height=8)
    assert call["foveation"] == expected.foveation
    assert call["config"] == expected.config
    # --spp given keeps its value; without --preset the frame is fovjax's defaults
    (call,) = _captured_render(monkeypatch, ["--preset", "thesis", "--spp", "16", *out])
    assert call["foveation"] == thesis_preset((5.0, 10.0), spp=16, eye_height=8).foveation
    (call,) = _captured_render(monkeypatch, out)
    assert call["foveation"].spp == 1 and call["foveation"].rule == "either"
    assert call["config"].specular_payload is False


def test_an_unknown_preset_is_refused(capsys):
    from fovjax.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(["render", "--preset", "sponza"])
    assert exit_info.value.code == 2
    assert "invalid choice: 'sponza'" in capsys.readouterr().err


def test_the_slots_handler_shades_as_the_preset_says():
    """The foveated frame's native slots handler gets the preset's shading as attributes (its
    numbers are the Whitted handler's: tests/test_shading_options.py)."""
    from test_shading_options import native_available

    if not native_available():
        pytest.skip("the native handlers are not built here")
    from fovjax.foveate._frame import eccentricities, selection_with_mask, traced_sums
    from fovjax.render import StereoRig, scene_arrays
    from fovjax.trace import build_bvh

    scene = fovjax.scenes.spheres(subdivisions=1)
    w, h = 16, 12
    preset = thesis_preset(0, spp=1, eye_height=h, config=RenderConfig(integrator="native"))
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=w, eye_height=h)
    cameras = rig.eye_cameras(jnp.zeros(3))
    ecc = eccentricities(cameras, jnp.asarray([[0.5, 0.5], [0.5, 0.5]]), preset.foveation)
    budget = 2 * w * h
    sel, *_ = selection_with_mask(
        ecc, jax.random.key(3), foveation=preset.foveation, budget=budget, native=False
    )
    bvh = build_bvh(scene, cache=False)

    def sums(arrays):
        return traced_sums(arrays, bvh, cameras, None, sel, config=preset.config, budget=budget).consumed

    text = jax.jit(sums).lower(scene_arrays(scene)).as_text()
    (call,) = [line for line in text.splitlines() if "fovjax_whitted_slots" in line]
    for attribute in ("max_depth = 5 : i32", "specular = 0 : i32", "specular_payload = 1 : i32"):
        assert attribute in call, attribute
    assert re.search(r"min_contribution = 0\.0099999\d* : f32", call)
