"""Run the Python code blocks of documentation pages, as tests/test_docs.py does.

Every ```python block of a page runs, in order, in one namespace, in a fresh directory holding
a link to the repository's `data/` (so the pages' relative paths work and their outputs land in
the scratch directory). Blocks in other languages (bash, text) are not run.

    python docs/_tools/run_page.py docs/tutorials/acuity-fit.md [...]
"""

import os
import re
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FENCE = re.compile(r"^```python\n(.*?)^```$", re.S | re.M)


def code_blocks(page: Path) -> list[str]:
    return FENCE.findall(page.read_text())


def run_page(page: Path, workdir: Path) -> float:
    """Run the page's blocks in `workdir`; return the seconds it took."""
    page = Path(page).resolve()
    (workdir / "data").symlink_to(ROOT / "data")
    namespace = {"__name__": f"docs_page_{page.stem}"}
    cwd = os.getcwd()
    start = time.perf_counter()
    os.chdir(workdir)
    try:
        for i, block in enumerate(code_blocks(page)):
            exec(compile(block, f"{page.relative_to(ROOT)}[block {i + 1}]", "exec"), namespace)
    finally:
        os.chdir(cwd)
    return time.perf_counter() - start


if __name__ == "__main__":
    for name in sys.argv[1:]:
        with tempfile.TemporaryDirectory() as tmp:
            print(f"{name}: {run_page(Path(name), Path(tmp)):.1f} s", flush=True)
