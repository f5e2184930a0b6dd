"""Every environment variable in one table (fovjax/_environment.py): the table lists every
`FOVJAX_` name the sources read, the docs' table (docs/how-to-choose.md, "Environment
variables") matches it, its readers check a value and name what they expected, and the caches
share one directory."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from fovjax import _environment
from fovjax._environment import VARIABLES, EnvironmentVariableError, cache_dir

REPO = Path(__file__).resolve().parents[1]
NAME = re.compile(r"\bFOVJAX_[A-Z0-9_]*[A-Z0-9]\b")
# The native sources' FOVJAX_ names are C macros, not environment variables: they are not read.
SOURCES = ("fovjax/**/*.py", "benchmarks/**/*.py", "benchmarks/**/*.sh", "tests/**/*.py", ".ci/*")
# Pages that describe today's variables (the changelog and the records are history).
DOCS = ("README.md", "CONTRIBUTING.md", "docs/**/*.md")
HISTORY = ("docs/performance.md", "docs/_generated/")


def _names_in(patterns, skip=()) -> dict[str, set[str]]:
    """Each FOVJAX_ name in the files `patterns` match, with the files that name it."""
    found: dict[str, set[str]] = {}
    for pattern in patterns:
        for path in REPO.glob(pattern):
            rel = path.relative_to(REPO).as_posix()
            if not path.is_file() or any(rel.startswith(s) for s in skip):
                continue
            for name in NAME.findall(path.read_text(encoding="utf-8", errors="replace")):
                found.setdefault(name, set()).add(rel)
    return found


def test_the_table_lists_every_variable_the_sources_read():
    here = Path(__file__).relative_to(REPO).as_posix()
    read = _names_in(SOURCES, skip=(here, "fovjax/_environment.py"))
    missing = {name: sorted(files) for name, files in read.items() if name not in VARIABLES}
    assert not missing, f"add these to fovjax/_environment.py VARIABLES: {missing}"
    unread = sorted(set(VARIABLES) - set(read))
    assert not unread, f"VARIABLES lists names no source reads any more: {unread}"


def _docs_table() -> dict[str, str]:
    """The variables and defaults of the table under "## Environment variables"."""
    text = (REPO / "docs" / "how-to-choose.md").read_text(encoding="utf-8")
    section = text.split("\n## Environment variables\n", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 3 and NAME.fullmatch(cells[0].strip("`")):
            rows[cells[0].strip("`")] = cells[1]
    return rows


def test_the_docs_table_matches_the_table():
    docs = _docs_table()
    assert set(docs) == set(VARIABLES), (
        f"docs/how-to-choose.md lacks {sorted(set(VARIABLES) - set(docs))}, "
        f"has unknown {sorted(set(docs) - set(VARIABLES))}"
    )
    wrong = {name: (docs[name], v.default) for name, v in VARIABLES.items() if docs[name] != v.default}
    assert not wrong, f"defaults in the docs differ from VARIABLES (docs, table): {wrong}"


def test_the_docs_name_no_variable_the_table_lacks():
    named = _names_in(DOCS, skip=HISTORY)
    unknown = {name: sorted(files) for name, files in named.items() if name not in VARIABLES}
    assert not unknown, unknown


def test_every_variable_is_described():
    for v in VARIABLES.values():
        assert v.kind in (_environment.SWITCH, _environment.CHOICE, _environment.PATH, _environment.TEXT)
        assert v.scope in (_environment.PACKAGE, _environment.BENCHMARKS, _environment.TESTS)
        assert v.default and v.meaning, v.name
        if v.kind == _environment.SWITCH:
            assert v.default in ("0", "1"), v.name
        if v.kind == _environment.CHOICE:
            assert v.default in v.choices, v.name


def test_a_switch():
    assert _environment.switch("FOVJAX_NATIVE", {}) is True  # its default
    assert _environment.switch("FOVJAX_AUTO_OTHER_PLATFORMS", {}) is False
    assert _environment.switch("FOVJAX_NATIVE", {"FOVJAX_NATIVE": "0"}) is False
    assert _environment.switch("FOVJAX_NATIVE", {"FOVJAX_NATIVE": " 0 "}) is False
    assert _environment.switch("FOVJAX_NATIVE", {"FOVJAX_NATIVE": ""}) is True
    with pytest.raises(EnvironmentVariableError) as err:
        _environment.switch("FOVJAX_NATIVE", {"FOVJAX_NATIVE": "off"})
    assert isinstance(err.value, ValueError)
    assert str(err.value) == "environment variable FOVJAX_NATIVE='off': expected 0 (off) or 1 (on)"


def test_a_choice():
    assert _environment.choice("FOVJAX_XLA_EMITTERS", {}) == "auto"
    assert _environment.choice("FOVJAX_XLA_EMITTERS", {"FOVJAX_XLA_EMITTERS": "loop"}) == "loop"
    with pytest.raises(ValueError, match=r"FOVJAX_XLA_EMITTERS='Loop': expected one of auto, loop, fusion"):
        _environment.choice("FOVJAX_XLA_EMITTERS", {"FOVJAX_XLA_EMITTERS": "Loop"})


def test_a_path_and_a_text():
    assert _environment.path("FOVJAX_ISENSE_LIB", {}) is None
    got = _environment.path("FOVJAX_ISENSE_LIB", {"FOVJAX_ISENSE_LIB": "~/lib/libisense.so"})
    assert got == Path.home() / "lib" / "libisense.so"
    assert _environment.text("FOVJAX_BENCH_COMMIT", {"FOVJAX_BENCH_COMMIT": "abc123"}) == "abc123"
    assert _environment.text("FOVJAX_BENCH_COMMIT", {}) is None


def test_a_reader_takes_only_a_variable_of_its_kind_in_the_table():
    with pytest.raises(KeyError, match="FOVJAX_NOT_LISTED"):
        _environment.switch("FOVJAX_NOT_LISTED", {})
    with pytest.raises(KeyError, match="FOVJAX_CACHE_DIR is not a switch"):
        _environment.switch("FOVJAX_CACHE_DIR", {})


def test_the_cache_directory():
    home = Path.home() / ".cache" / "fovjax"
    assert cache_dir("bvh", environ={}) == home / "bvh"
    assert cache_dir("xla", environ={"FOVJAX_CACHE_DIR": "/tmp/c"}) == Path("/tmp/c/xla")
    assert cache_dir(environ={"FOVJAX_CACHE_DIR": "/tmp/c"}) == Path("/tmp/c")
    assert cache_dir("lod", environ={"XDG_CACHE_HOME": "/tmp/x"}) == Path("/tmp/x/fovjax/lod")
    # the XDG specification: a relative (or empty) XDG_CACHE_HOME is ignored
    assert cache_dir("lod", environ={"XDG_CACHE_HOME": "rel"}) == home / "lod"
    assert cache_dir("lod", environ={"XDG_CACHE_HOME": ""}) == home / "lod"
    both = {"FOVJAX_CACHE_DIR": "/tmp/c", "XDG_CACHE_HOME": "/tmp/x"}
    assert cache_dir("native", environ=both) == Path("/tmp/c/native")


def test_every_cache_uses_the_one_directory(monkeypatch, tmp_path):
    from fovjax.render import compile_cache_dir
    from fovjax.scene import _lod
    from fovjax.trace import _bvh

    monkeypatch.setenv("FOVJAX_CACHE_DIR", str(tmp_path))
    assert compile_cache_dir() == tmp_path / "xla"
    assert _bvh._cache_dir(None) == tmp_path / "bvh"
    assert _lod._cache_dir(None) == tmp_path / "lod"
    assert _lod._cache_dir(tmp_path / "mine") == tmp_path / "mine"  # an explicit folder wins


def test_the_command_line_names_a_switch_it_cannot_use(monkeypatch, tmp_path, capsys):
    """Exit 2 and one line naming the variable, before anything is rendered."""
    from fovjax.cli import main

    monkeypatch.setenv("FOVJAX_COMPILE_CACHE", "yes")
    out = tmp_path / "x.png"
    argv = ["render", "--scene", "cornell", "--width", "8", "--height", "8", "--mono", "-o", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "FOVJAX_COMPILE_CACHE='yes': expected 0 (off) or 1 (on)" in err
    assert "Traceback" not in err and not out.exists()
