"""benchmarks/gradients.py refuses a bad size, repeat count or scene before any work (exit 2,
naming the value). Its figures are checked where it runs: it prints how its gradients agree with
Mitsuba's and with exact central differences."""

import importlib.util
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parent.parent / "benchmarks"


def _script():
    sys.path.insert(0, str(BENCH))  # the script imports mitsuba_frame beside it
    try:
        spec = importlib.util.spec_from_file_location("gradients_bench", BENCH / "gradients.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(BENCH))
    return module


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
