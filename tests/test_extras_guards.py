"""Every test that needs an optional extra gets it through tests/_extras.py, so that
FOVJAX_REQUIRE_EXTRAS=1 turns each such skip into a failure: no test file guards an import any
other way. The scan reads each test file's syntax tree; a test of the scan itself shows each kind
of guard it refuses."""

from __future__ import annotations

import ast
from pathlib import Path

import _extras
import pytest

TESTS = Path(__file__).resolve().parent
HELPER = TESTS / "_extras.py"


def _dotted(node: ast.AST) -> str:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return f"{_dotted(node.value)}.{node.attr}"
    return ""


def guards(source: str, name: str = "<test>") -> list[str]:
    """Where `source` guards an import outside the helper: FILE:LINE and what it does."""
    found = []
    tree = ast.parse(source)
    modules = set(_extras.EXTRAS)
    for node in ast.walk(tree):
        where = f"{name}:{getattr(node, 'lineno', '?')}"
        if isinstance(node, ast.Call):
            called = _dotted(node.func)
            last = called.rsplit(".", 1)[-1]
            if last in ("importorskip", "find_spec"):
                found.append(f"{where}: {called}(...)")
            if last == "skipif":
                # A skipif whose condition or reason is about an installed module.
                text = " ".join(ast.unparse(a) for a in [*node.args, *(k.value for k in node.keywords)])
                words = ("import", "install", "extra", "find_spec", "available", *modules)
                if any(w in text for w in words):
                    found.append(f"{where}: skipif on a module ({text[:60]})")
            if last == "skip" and called.startswith("pytest"):
                text = " ".join(ast.unparse(a) for a in node.args)
                if any(w in text for w in ("install", "extra", *modules)):
                    found.append(f"{where}: pytest.skip for a module ({text[:60]})")
        elif isinstance(node, ast.ExceptHandler) and node.type is not None:
            caught = ast.unparse(node.type)
            if "ImportError" in caught or "ModuleNotFoundError" in caught:
                found.append(f"{where}: except {caught}")
        elif isinstance(node, ast.Constant) and node.value == _extras.REQUIRE_VARIABLE:
            found.append(f"{where}: reads {_extras.REQUIRE_VARIABLE} itself")
    return found


def test_every_extra_guard_goes_through_the_helper():
    files = sorted(p for p in TESTS.rglob("*.py") if p != HELPER)
    assert len(files) > 40  # the scan sees the suite
    found = [g for p in files for g in guards(p.read_text(), str(p.relative_to(TESTS.parent)))]
    assert not found, "guard these through tests/_extras.py (require / needs / have):\n" + "\n".join(found)


@pytest.mark.parametrize(
    "source",
    [
        'flip = pytest.importorskip("flip_evaluator")',
        'HAVE = importlib.util.find_spec("pyfvvdp") is not None',
        '@pytest.mark.skipif(not HAVE_CV2, reason="pip install opencv")\ndef test_x(): pass',
        '@pytest.mark.skipif(not embree_available(), reason="no Embree")\ndef test_x(): pass',
        'def test_x():\n    pytest.skip("aiohttp missing")',
        "try:\n    import zmq\nexcept ImportError:\n    zmq = None",
        'STRICT = os.environ.get("FOVJAX_REQUIRE_EXTRAS") == "1"',
    ],
)
def test_the_scan_finds_each_kind_of_guard(source):
    assert len(guards(source)) == 1, guards(source)


def test_the_scan_lets_platform_conditions_pass():
    source = (
        '@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs os.openpty")\n'
        "def test_x(): pass\n"
        'def test_y():\n    pytest.skip("no C compiler to build the fake vendor libraries")'
    )
    assert guards(source) == []


def test_every_module_named_is_an_extra_of_pyproject():
    """The helper's map names extras pyproject defines (so its pip command is right)."""
    import tomllib

    project = tomllib.loads((TESTS.parent / "pyproject.toml").read_text())["project"]
    defined = set(project["optional-dependencies"])
    assert set(_extras.EXTRAS.values()) <= defined, set(_extras.EXTRAS.values()) - defined


def test_have_fails_rather_than_answers_false_when_extras_are_required(monkeypatch):
    monkeypatch.setitem(_extras.EXTRAS, "fovjax_no_such_module", "dev")
    monkeypatch.setenv(_extras.REQUIRE_VARIABLE, "1")
    with pytest.raises(pytest.fail.Exception, match="pip install 'fovjax\\[dev\\]'"):
        _extras.have("fovjax_no_such_module")
    with pytest.raises(pytest.fail.Exception, match="FOVJAX_REQUIRE_EXTRAS=1 requires every extra"):
        _extras.require("fovjax_no_such_module")
    monkeypatch.setenv(_extras.REQUIRE_VARIABLE, "0")
    assert _extras.have("fovjax_no_such_module") is False
    with pytest.raises(pytest.skip.Exception, match="fovjax_no_such_module is not installed"):
        _extras.require("fovjax_no_such_module")
