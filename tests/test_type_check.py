"""The type checker's settings: pyright, configured in pyproject.toml (`[tool.pyright]`: basic
mode on the whole package), the version pinned in the `dev` extra (a new one can find new
errors). It reads the annotations statically, where tests/test_types.py checks them on calls.
pyright itself runs as a step of its own in .ci/run (`python -m pyright`, before the suite: it
takes most of a minute of one core, and the suite's time is kept for what runs the package)."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_pyright_leaves_no_package_out():
    settings = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pyright"]
    assert settings["include"] == ["fovjax"]
    # Only what is not Python source: caches and the viewer's browser files.
    assert set(settings["exclude"]) <= {"**/__pycache__", "fovjax/view/static"}, settings["exclude"]


def test_ci_runs_pyright_before_the_suite():
    steps = (ROOT / ".ci" / "run").read_text()
    assert "python -m pyright --pythonpath" in steps
    assert steps.index("python -m pyright") < steps.index("python -m pytest")
