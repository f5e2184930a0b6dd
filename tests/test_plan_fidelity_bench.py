"""benchmarks/plan_fidelity.py: a bad command line is refused by name before the scene is built."""

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
