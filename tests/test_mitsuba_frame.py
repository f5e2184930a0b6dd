"""benchmarks/mitsuba_frame.py, the frame-level peer: at a tiny size its Mitsuba 3 frame matches
fovjax's full frame (PSNR, ray counts by kind) and its JSON record holds the figures.

Mitsuba is in the `[bench]` extra (`.ci/run` installs it, and Debian's libllvm19 for Dr.Jit).
Where mitsuba is installed but Dr.Jit finds no libLLVM >= 16 (a system library, not an extra),
it skips with the script's own reason."""

import importlib.util
import json
from pathlib import Path

import _extras
import pytest

_extras.require("mitsuba", module_level=True)

SCRIPT = Path(__file__).resolve().parent.parent / "benchmarks" / "mitsuba_frame.py"


def _script():
    spec = importlib.util.spec_from_file_location("mitsuba_frame", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_mitsuba_frame_matches_fovjax(tmp_path, capsys):
    bench = _script()
    try:
        bench.load_mitsuba()
    except bench.Unavailable as exc:
        pytest.skip(str(exc))
    out = tmp_path / "record.json"
    argv = ["--width", "32", "--height", "24", "--max-depth", "2", "--repeats", "1", "--no-foveated"]
    record = bench.main([*argv, "--json", str(out)])
    printed = capsys.readouterr().out
    (r,) = record["results"]
    assert r["psnr_db"] >= bench.PSNR_EXPECTED, printed
    mi, fj = r["mitsuba_full_rays"], r["fovjax_full_rays"]
    assert mi["primary"] == fj["primary"] == 2 * 32 * 24
    assert fj["shadow"] > 0 and fj["reflection"] > 0  # the atrium's light and mirrors are in the frame
    for kind in ("shadow", "reflection"):  # equal up to a tie or a grazing ray
        assert abs(mi[kind] - fj[kind]) <= max(2, fj[kind] // 1000), printed
    assert r["mitsuba_full_ms"] > 0 and r["fovjax_full_ms"] > 0
    assert r["fovjax_full_page_faults"] >= 0 and r["fovjax_full_sys_ms"] >= 0  # fresh memory per frame
    assert "PSNR of Mitsuba's image against fovjax's full frame" in printed
    saved = json.loads(out.read_text())
    assert saved["results"][0]["psnr_db"] == pytest.approx(r["psnr_db"])
    assert saved["command"].startswith("benchmarks/mitsuba_frame.py --width 32")
    assert {"date", "git_commit", "machine"} <= set(saved)


def test_a_samples_count_that_is_not_a_square_is_named(capsys):
    with pytest.raises(SystemExit) as exc:
        _script().main(["--spp", "1", "2"])
    assert exc.value.code == 2 and "--spp 2" in capsys.readouterr().err


def test_mitsuba_integrator_textures_environment_lights():
    """The paths the atrium leaves out: a diffuse texture (bilinear, wrapping UVs), a lat-long
    environment map, a directional light beside a point light, flat normals, SPP 4."""
    import numpy as np

    import fovjax
    from fovjax.render import RenderConfig, StereoRig, render_stereo, scene_arrays
    from fovjax.trace import build_bvh

    bench = _script()
    try:
        bench.load_mitsuba()
    except bench.Unavailable as exc:
        pytest.skip(str(exc))
    rng = np.random.default_rng(3)
    floor = [(-4, 0, -4), (4, 0, -4), (4, 0, 4), (-4, 0, 4)]
    mirror = [(-3, 0, -3), (3, 0, -3), (3, 3, -3.5), (-3, 3, -3.5)]
    block = [(-1, 0, 0), (1, 0, 0), (0, 1.5, 0.5), (0, 0, 1.5)]
    vertices = np.array(floor + mirror + block, np.float32)
    faces = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [8, 9, 10], [9, 11, 10], [8, 10, 11]])
    uvs = np.concatenate([np.array([(0, 0), (3.5, 0), (3.5, 2.5), (0, 2.5)], np.float32), np.zeros((8, 2))])
    materials = fovjax.make_materials(
        [
            {"kd": (0.9, 0.9, 0.9), "ka": (0.2, 0.2, 0.2), "texture": 0},
            {"kd": (0.1, 0.1, 0.1), "kr": 0.6, "ks": (0.3, 0.3, 0.3), "ns": 40},
            {"kd": (0.7, 0.3, 0.2), "ks": (0.5, 0.5, 0.5), "ns": 12, "ke": (0.05, 0.0, 0.0)},
        ]
    )
    lights = fovjax.make_lights(
        [(1.0, 5.0, 3.0), (0.3, 1.0, 0.5)],
        [(0.8, 0.7, 0.6), (0.3, 0.3, 0.4)],
        [fovjax.POINT_LIGHT, fovjax.DIRECTIONAL_LIGHT],
    )
    scene = fovjax.make_scene(
        vertices,
        faces,
        face_material=np.array([0, 0, 1, 1, 2, 2, 2]),
        materials=materials,
        lights=lights,
        uvs=uvs.astype(np.float32),
        textures=(rng.uniform(0, 1, (4, 5, 3)).astype(np.float32),),
    )
    arrays = scene_arrays(scene, envmap=rng.uniform(0, 1, (8, 16, 3)).astype(np.float32))
    rig = StereoRig.look_at((0.5, 2.0, 6.0), (0.0, 0.8, -2.0), eye_width=20, eye_height=14, fov_deg=100)
    config = RenderConfig(max_depth=3)
    reference = render_stereo(arrays, rig, spp=4, config=config, bvh=build_bvh(scene))
    image, counts = bench.render_mitsuba(arrays, rig, spp=4, config=config)
    stats = reference.stats
    assert counts == {
        "primary": stats.primary_rays,
        "shadow": stats.shadow_rays,
        "reflection": stats.reflection_rays,
    }
    assert stats.reflection_rays > 0 and stats.shadow_rays > 0
    from fovjax.eval import psnr

    assert psnr(image, reference.image).value >= bench.PSNR_EXPECTED
    assert np.abs(image - reference.image).max() < 1e-3
