"""The documentation: the site builds with `mkdocs build --strict` (a broken link, a missing page
or a docstring reference that does not resolve fails), every public name has an entry in the API
reference, the generated pages (API, Performance) are current, every tutorial's code runs, and
the README stays a short front door.

The tutorials run in this process, so their compiled programs go through the run's shared
compile cache (tests/conftest.py); they use the shapes other tests compile (the Cornell box at
2 x 32x24 with `compare_thresholds`'s sweep of tests/test_eval_compare.py, the session of
tests/test_session.py), so most of their compiling is shared with those tests."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import _extras
import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS / "_tools"))
sys.path.insert(0, str(ROOT / "benchmarks"))

import api_pages  # noqa: E402
import run_page  # noqa: E402

TUTORIALS = sorted((DOCS / "tutorials").glob("*.md"))
# Internal branch names and session talk the repository must not carry.
FORBIDDEN = re.compile(r"this session|pix12|out12|lod16|texspp|lodframe")


def need(module: str):
    """The docs toolchain (the [docs] extra), through the suite's one guard."""
    return _extras.require(module)


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    need("mkdocs")
    need("mkdocstrings_handlers.python")
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return out


def test_mkdocs_build_strict(site):
    assert (site / "index.html").exists()
    for page in ("getting-started", "how-to-choose", "thesis", "data", "performance", "troubleshooting"):
        assert (site / page / "index.html").exists(), page


def test_every_public_name_has_an_api_entry(site):
    missing = []
    for module, page, _ in api_pages.PACKAGES:
        html = (site / "api" / Path(page).stem / "index.html").read_text()
        names, _ = api_pages.public_names(module)
        missing += [f"{module}.{n}" for n in names if f'id="{module}.{n}"' not in html]
    assert not missing, missing


def test_generated_pages_are_current():
    assert api_pages.main_check() == [], "run python docs/_tools/api_pages.py"
    import records_to_page

    assert records_to_page.stale() == [], "run python benchmarks/records_to_page.py"


@pytest.mark.parametrize("page", TUTORIALS, ids=[p.stem for p in TUTORIALS])
def test_tutorial_runs(page, tmp_path):
    assert run_page.code_blocks(page), f"{page.name} has no Python code"
    run_page.run_page(page, tmp_path)


def test_readme_is_a_short_front_door():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 150
    # No dated measurements: dates, machine load and timings live in benchmarks/results/.
    assert not re.search(r"20\d\d-\d\d-\d\d|load average|quiet machine", text)
    for target in re.findall(r"\]\(([^)#]+)", text):
        if not target.startswith("http"):
            assert (ROOT / target).exists(), f"README links to a missing {target}"


def test_no_internal_branch_names():
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True).stdout.split()
    found = []
    for name in files:
        if name == "tests/test_docs.py":
            continue
        path = ROOT / name
        try:
            text = path.read_text()
        except (UnicodeDecodeError, FileNotFoundError, IsADirectoryError):
            continue
        found += [f"{name}: {m.group(0)}" for m in FORBIDDEN.finditer(text)]
        if FORBIDDEN.search(name):
            found.append(name)
    assert not found, found
