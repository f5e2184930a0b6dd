"""benchmarks/plan_fidelity.py: a bad command line is refused by name before the scene is built."""

import _extras
import pytest
from _scripts import BENCHMARKS, load_script


def _script():
    return load_script(BENCHMARKS / "plan_fidelity.py")


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--flip-tolerance", "-0.001"], "--flip-tolerance: expected a finite number >= 0, got '-0.001'"),
        (["--flip-tolerance", "nan"], "--flip-tolerance: expected a finite number >= 0, got 'nan'"),
        (["--flip-tolerance", "inf"], "--flip-tolerance: expected a finite number >= 0, got 'inf'"),
        (["--densities", "2"], "--densities: expected P,O (two integers), got '2'"),
    ],
)
def test_a_bad_command_line_is_refused_by_name(argv, named, capsys, monkeypatch):
    script = _script()

    def no_scene(**kwargs):
        raise AssertionError("the scene was built before the command line was checked")

    monkeypatch.setattr(script.fovjax.scenes, "atrium", no_scene)
    with pytest.raises(SystemExit) as exc:
        script.main(argv)
    assert exc.value.code == 2 and named in capsys.readouterr().err


@_extras.needs("pyfvvdp")
def test_jod_judges_each_frame_against_the_full_render_of_its_key():
    """`--jod`'s scores: a "plan" whose fovea covers the screen renders every frame's full
    render (the same key's), JOD 10 at every gaze; plain foveation (5°/10°) scores below it."""
    import types

    import fovjax
    from fovjax.foveate import Foveation
    from fovjax.render import RenderConfig, StereoRig

    script = _script()
    scene = fovjax.scenes.cornell_box()
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=32, eye_height=32)
    plain = Foveation(5.0, 10.0, spp=1)
    screen = fovjax.full_eccentricity(rig, plain)
    plan = types.SimpleNamespace(plain=plain, foveation=Foveation(screen, screen, spp=1))
    jod_plain, jod_plan = script._jod(scene, rig, RenderConfig(max_depth=0), plan, keys=[3])
    # The full render up to float rounding (two programs: tests/_frames.py), every frame.
    assert jod_plan[0] == pytest.approx(10.0, abs=1e-3) and jod_plan[1] == pytest.approx(10.0, abs=1e-3)
    assert jod_plain[2] < 9.99


def test_jod_without_fovvideovdp_is_refused_before_the_scene_is_built(capsys, monkeypatch):
    import importlib.util

    script = _script()
    installed = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "pyfvvdp" else installed(name, *a)
    )

    def no_scene(**kwargs):
        raise AssertionError("the scene was built before the command line was checked")

    monkeypatch.setattr(script.fovjax.scenes, "atrium", no_scene)
    with pytest.raises(SystemExit) as exc:
        script.main(["--jod"])
    assert (
        exc.value.code == 2
        and "--jod: needs FovVideoVDP (pip install 'fovjax[fvvdp]')" in capsys.readouterr().err
    )
