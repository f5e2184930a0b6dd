"""benchmarks/gradients.py refuses a bad size, repeat count or scene before any work (exit 2,
naming the value). Its figures are checked where it runs: it prints how its gradients agree with
Mitsuba's and with exact central differences."""

import pytest
from _scripts import BENCHMARKS, load_script


def _script():
    return load_script(BENCHMARKS / "gradients.py", "gradients_bench")


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--sizes", "320x256", "320by256"], "320by256"),
        (["--sizes", "0x256"], "0x256"),
        (["--repeats", "0"], "--repeats 0"),
        (["--scene", "nowhere"], "nowhere"),
    ],
)
def test_bad_arguments_are_named_before_any_work(argv, named, capsys):
    with pytest.raises(SystemExit) as exc:
        _script().main(argv)
    assert exc.value.code == 2
    assert named in capsys.readouterr().err
