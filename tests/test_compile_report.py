"""tests/compile_report.py sums the compile logs FOVJAX_TEST_COMPILE_LOG writes."""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
import compile_report  # noqa: E402


def _write(path, rows):
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))


def test_sums_by_file_and_test(tmp_path, capsys):
    _write(
        tmp_path / "compiles-gw0.jsonl",
        [
            {"test": "tests/test_a.py::test_x", "kind": "xla", "s": 2.0, "fun": "jit(frame)"},
            {"test": "tests/test_a.py::test_x", "kind": "trace", "s": 0.5, "fun": "frame"},
            {"test": "tests/test_a.py::test_y", "kind": "xla", "s": 1.0, "fun": "jit(frame)"},
        ],
    )
    _write(
        tmp_path / "compiles-gw1.jsonl",
        [{"test": "tests/test_b.py::test_z", "kind": "xla", "s": 4.0, "fun": "jit(g)"}],
    )
    assert compile_report.main([str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "trace 0, lower 0, xla 7" in out and "XLA compiles 3" in out
    by_file = out.split("by file")[1].split("by test")[0].splitlines()[1:3]
    assert "tests/test_b.py" in by_file[0] and by_file[0].split()[0] == "4.0"
    assert "tests/test_a.py" in by_file[1] and by_file[1].split()[0] == "3.5"
    assert "   2  jit(frame)" in out


def test_a_bad_line_names_the_file_and_line(tmp_path, capsys):
    (tmp_path / "compiles-gw0.jsonl").write_text('{"test": "t", "kind": "xla", "s": 1}\nnot json\n')
    assert compile_report.main([str(tmp_path)]) == 2
    assert "compiles-gw0.jsonl:2" in capsys.readouterr().err
    assert compile_report.main([str(tmp_path / "empty")]) == 2
