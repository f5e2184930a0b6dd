"""tests/native_mutations.py, the mutation check of the native integrator: its table names lines
that exist, once each, in the package's C++ sources (a change that moves or rewrites one fails
here, not only when the check is run), and it finds a snippet the way it documents. The check
itself (a build and a test run per mutation, minutes each) is run by hand: CONTRIBUTING.md."""

from __future__ import annotations

from pathlib import Path

import native_mutations as nm
import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("mutation", nm.MUTATIONS, ids=lambda m: m.name)
def test_each_mutation_names_one_place_in_the_sources(mutation):
    path = nm.locate(ROOT / nm.PACKAGE, mutation.snippet)
    assert path.suffix in nm.SOURCE_SUFFIXES
    assert mutation.replacement != mutation.snippet and mutation.description


def test_the_table_covers_the_integrators_known_mistakes():
    names = {m.name for m in nm.MUTATIONS}
    assert len(names) == len(nm.MUTATIONS)  # names are unique: the command line picks by name
    expected = {"specular-exponent", "shadow-ignored", "one-bounce-fewer", "one-bounce-more"}
    assert expected | {"unbounded-shadow", "uncompounded-reflection"} <= names


def test_a_snippet_is_found_once_among_every_cc_and_h(tmp_path):
    package = tmp_path / "pkg"
    (package / "sub").mkdir(parents=True)
    (package / "a.cc").write_text("int x = 1;\nw = w * kr;\n")
    (package / "sub" / "b.h").write_text("// header\nint y = 2;\nint x = 1;\n")
    (package / "c.py").write_text("w = w * kr;\nnot_cpp = True\n")  # not a C++ source
    mutation = nm.Mutation("m", "a mistake", "w = w * kr;", "w = kr;")
    assert nm.locate(package, "int y = 2;") == package / "sub" / "b.h"
    assert nm.apply(package, mutation) == (package / "a.cc", "pkg/a.cc:2")
    assert (package / "a.cc").read_text() == "int x = 1;\nw = kr;\n"
    assert (package / "c.py").read_text().startswith("w = w * kr;")  # untouched
    with pytest.raises(nm.CheckError, match=r"found 2 times \(pkg/a.cc:1, pkg/sub/b.h:3\)"):
        nm.locate(package, "int x = 1;")
    with pytest.raises(nm.CheckError, match="'w = w \\* kr;' not found in the 2 C\\+\\+ sources under pkg/"):
        nm.locate(package, "w = w * kr;")


def test_bad_command_lines_exit_2_naming_the_value(capsys):
    for argv, named in ((["nope"], "unknown mutation nope"), (["--tests", "tests/none.py"], "tests/none.py")):
        with pytest.raises(SystemExit) as exc:
            nm.main(argv)
        assert exc.value.code == 2 and named in capsys.readouterr().err
