"""benchmarks/patney_window.py, the chart of Patney 2016's contrast window against its cost:
a bad command line is refused by name before anything renders."""

import pytest
from _scripts import BENCHMARKS, load_script


def _script():
    return load_script(BENCHMARKS / "patney_window.py")


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--windows", "1", "0"], "--windows must be positive, got [1.0, 0.0]"),
        (["--windows", "nan"], "--windows must be positive"),
        (["--frames", "1"], "--frames must be at least 2"),
        (["--warm-up", "-1"], "--warm-up at least 0"),
        (["--size", "4", "4"], "--size at least 8 x 8"),
        (["--scene", "sponza"], "--scene 'sponza': one of ['atrium', 'cornell_box', 'spheres']"),
    ],
)
def test_a_bad_command_line_is_refused_by_name(argv, named, capsys):
    with pytest.raises(SystemExit) as exc:
        _script().main(argv)
    assert exc.value.code == 2 and named in capsys.readouterr().err
