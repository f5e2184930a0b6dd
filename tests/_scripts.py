"""The project's scripts (benchmarks/, fits/) loaded as modules by their paths, for tests that
call their `main` or their functions."""

import importlib.util
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
BENCHMARKS = REPO / "benchmarks"


def load_script(path: Path, name: str | None = None):
    """The script at `path` as a module named `name` (default: its file's stem), its folder on
    `sys.path` while it loads (a script imports the scripts beside it)."""
    folder = str(path.parent)
    sys.path.insert(0, folder)
    try:
        spec = importlib.util.spec_from_file_location(name or path.stem, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(folder)
    return module
