"""benchmarks/mitsuba_frame.py, the frame-level peer: at a tiny size its Mitsuba 3 frame matches
fovjax's full frame (PSNR, ray counts by kind) and its JSON record holds the figures.

Mitsuba is in the `[bench]` extra (`.ci/run` installs it, and Debian's libllvm19 for Dr.Jit).
Where mitsuba is installed but does not start (Dr.Jit finds no libLLVM >= 16, a system library
rather than an extra, or the package fails to import), its tests skip with the script's own
reason, and fail with it under FOVJAX_REQUIRE_EXTRAS=1: CI installs what Mitsuba needs, so a
Mitsuba that cannot start there is a broken install, not a machine without the extra."""

import json
import sys
import types

import _extras
import pytest
from _scripts import BENCHMARKS, load_script

_extras.require("mitsuba", module_level=True)


def _script():
    return load_script(BENCHMARKS / "mitsuba_frame.py")


def _started(bench):
    """`bench.load_mitsuba()`; where Mitsuba is installed but cannot start, a skip with the
    reason, or a failure with it under FOVJAX_REQUIRE_EXTRAS=1. (Not installed: the module's
    `_extras.require` skipped or failed first.)"""
    try:
        return bench.load_mitsuba()
    except bench.Unavailable as exc:
        reason = f"{type(exc).__name__}: {exc}"
    # Outside the handler: the failure or skip shows the reason alone, not the chain behind it.
    if _extras.required():
        pytest.fail(f"{reason}; {_extras.REQUIRE_VARIABLE}=1 requires every extra to run", pytrace=False)
    pytest.skip(reason)


def test_mitsuba_frame_matches_fovjax(tmp_path, capsys):
    bench = _script()
    _started(bench)
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
    _started(bench)
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


def _fake_mitsuba(monkeypatch, set_variant):
    """Mitsuba and Dr.Jit as modules whose start-up is `set_variant` (imported in their place)."""
    mi = types.SimpleNamespace(set_variant=set_variant)
    dr = types.SimpleNamespace(
        has_backend=lambda backend: True, JitBackend=types.SimpleNamespace(LLVM="llvm")
    )
    monkeypatch.setitem(sys.modules, "mitsuba", mi)
    monkeypatch.setitem(sys.modules, "drjit", dr)


def test_an_installed_mitsuba_that_cannot_start_is_told_from_a_missing_one(monkeypatch):
    """A start-up failure (set_variant raising, as without a libLLVM) is `CannotStart` with its
    reason and what to do; packages that cannot be imported and are not installed are
    `NotInstalled`; installed ones that fail to import are `CannotStart`."""
    bench = _script()

    def no_llvm(variant):
        raise RuntimeError(f"variant {variant}: jit_llvm_init(): could not find libLLVM")

    _fake_mitsuba(monkeypatch, no_llvm)
    with pytest.raises(bench.CannotStart, match="could not find libLLVM.*(DRJIT_LIBLLVM_PATH|libllvm19)"):
        bench.load_mitsuba()

    monkeypatch.setitem(sys.modules, "mitsuba", None)  # an import of it raises ImportError
    monkeypatch.setitem(sys.modules, "drjit", None)
    with pytest.raises(bench.NotInstalled, match=r"mitsuba and drjit not installed \(pip install"):
        bench.load_mitsuba()
    monkeypatch.setattr(bench, "_installed", lambda module: True)
    with pytest.raises(bench.CannotStart, match="installed but did not import"):
        bench.load_mitsuba()
    assert issubclass(bench.NotInstalled, bench.Unavailable) and issubclass(
        bench.CannotStart, bench.Unavailable
    )


@pytest.mark.parametrize("required", [True, False])
def test_a_mitsuba_that_cannot_start_fails_under_require_extras(monkeypatch, required):
    """The tests' start-up: under FOVJAX_REQUIRE_EXTRAS=1 a failure naming the reason, else a
    skip naming it."""
    bench = _script()

    def cannot_start():
        raise bench.CannotStart("Dr.Jit loaded libLLVM 15.0.6, too old")

    monkeypatch.setattr(bench, "load_mitsuba", cannot_start)
    monkeypatch.setenv(_extras.REQUIRE_VARIABLE, "1" if required else "0")
    outcome = pytest.fail.Exception if required else pytest.skip.Exception
    with pytest.raises(outcome, match="CannotStart: Dr.Jit loaded libLLVM 15.0.6, too old"):
        _started(bench)
