"""The type checker passes on the package: pyright, configured in pyproject.toml
(`[tool.pyright]`: basic mode on the whole package), the version pinned in the `dev` extra (a new
one can find new errors). It reads the annotations statically, where tests/test_types.py checks
them on calls."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import _extras

ROOT = Path(__file__).resolve().parents[1]


def test_pyright_passes_on_the_package():
    _extras.require("pyright")
    result = subprocess.run(
        [sys.executable, "-m", "pyright", "--pythonpath", sys.executable],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=900,
    )
    report = (result.stdout + result.stderr)[-20000:]
    assert result.returncode == 0, f"pyright found errors (pyproject.toml [tool.pyright]):\n{report}"
    assert "0 errors" in result.stdout, report


def test_pyright_leaves_no_package_out():
    settings = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pyright"]
    assert settings["include"] == ["fovjax"]
    # Only what is not Python source: caches and the viewer's browser files.
    assert set(settings["exclude"]) <= {"**/__pycache__", "fovjax/view/static"}, settings["exclude"]
