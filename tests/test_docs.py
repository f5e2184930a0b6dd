"""The documentation: the site builds with `mkdocs build --strict` (a broken link, a missing page
or a docstring reference that does not resolve fails), every public name has an entry in the API
reference, the generated pages (API, Performance) are current, every tutorial's code (and the home
page's example) runs and writes the images its page shows, and the README stays a short front door.

The tutorials run in this process, so their compiled programs go through the run's shared
compile cache (tests/conftest.py); they use the shapes other tests compile (the Cornell box at
2 x 32x24 with `compare_thresholds`'s sweep of tests/test_eval_compare.py, the session of
tests/test_session.py), so most of their compiling is shared with those tests; the home page's
example renders the program of docs/tutorials/compare-thresholds.md's first frame."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import urllib.parse
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
# The pages whose Python runs: the home page's example and every tutorial.
EXECUTED = [DOCS / "index.md", *TUTORIALS]
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
    pages = ("getting-started", "how-to-choose", "thesis", "data", "performance", "troubleshooting")
    for page in (*pages, "performance-records"):
        assert (site / f"{page}.html").exists(), page
    # Every record's tables stay out of the search index (benchmarks/records_to_page.py); the
    # summary page is searched.
    indexed = {
        doc["location"].split("#")[0]
        for doc in json.loads((site / "search" / "search_index.json").read_text())["docs"]
    }
    assert "performance.html" in indexed and "performance-records.html" not in indexed


def test_site_browses_from_files(site):
    """Every relative link and image of the built site names a file (page.html, not a folder a
    web server would complete with index.html), so the site works opened from file://. The 404
    page is the exception: a server shows it for any URL, so its links are from the site's root."""
    broken = []
    for page in site.rglob("*.html"):
        if page == site / "404.html":
            continue
        for target in re.findall(r'(?:href|src)="([^"#?]*)[^"]*"', page.read_text()):
            if target and not re.match(r"[a-z]+:|//", target):
                if not (page.parent / urllib.parse.unquote(target)).is_file():
                    broken.append(f"{page.relative_to(site)}: {target}")
    assert not broken, broken[:20]


def test_every_public_name_has_an_api_entry(site):
    missing = []
    for module, page, _ in api_pages.PACKAGES:
        html = (site / "api" / f"{Path(page).stem}.html").read_text()
        names, _ = api_pages.public_names(module)
        missing += [f"{module}.{n}" for n in names if f'id="{module}.{n}"' not in html]
    assert not missing, missing


def test_generated_pages_are_current():
    assert api_pages.main_check() == [], "run python docs/_tools/api_pages.py"
    import records_to_page

    assert records_to_page.stale() == [], "run python benchmarks/records_to_page.py"


def _records() -> list[dict]:
    return [
        {**json.loads(path.read_text()), "_file": path.name}
        for path in sorted((ROOT / "benchmarks" / "results").glob("*.json"))
    ]


def _on_gpu(record: dict) -> bool:
    return any(d.startswith("cuda") for d in record["machine"].get("jax_devices") or [])


def test_performance_summary_cites_the_newest_clean_records():
    """The summary's headline table names, for the main frame benchmarks, the newest record run
    from a clean tree, and no record of a modified tree is cited anywhere on the summary."""
    text = (DOCS / "performance.md").read_text()
    table = text[text.index("## Headline figures") :]
    records = _records()
    for benchmark, gpu in (("mitsuba_frame", False), ("trace_throughput", False), ("foveation", True)):
        clean = [
            r
            for r in records
            if r["benchmark"] == benchmark and r.get("dirty") is False and _on_gpu(r) == gpu
        ]
        newest = max(clean, key=lambda r: r["date"])
        assert f"[`{newest['_file'].removesuffix('.json')}`]" in table, benchmark
    for record in records:
        if record.get("dirty"):
            assert record["_file"].removesuffix(".json") not in text, record["_file"]
    # Newest first: the dates of the table's rows (a row's record cell: link, date, machine).
    dates = re.findall(r"<br>(\d{4}-\d\d-\d\d[ \d:]*)<br>", table)
    assert len(dates) > 5 and dates == sorted(dates, reverse=True)


def test_performance_summary_leaves_out_records_of_a_modified_tree():
    import records_to_page

    def record(name, benchmark, date, dirty):
        table = {"title": "t", "columns": ["frame", "ms per frame"], "rows": [["full", 1.5]]}
        machine = {"cpu": "CPU", "cores": 2, "jax_devices": ["cpu:0"]}
        return {"_file": f"{name}.json", "benchmark": benchmark, "command": "python x.py", "date": date,
                "dirty": dirty, "machine": machine, "figures": {"tables": [table]}}  # fmt: skip

    records = [
        record("frame-old-clean", "mitsuba_frame", "2026-01-01T00:00:00+00:00", False),
        record("frame-new-dirty", "mitsuba_frame", "2026-02-01T00:00:00+00:00", True),
        record("frame-older-clean", "mitsuba_frame", "2025-12-01T00:00:00+00:00", False),
        record("malloc-dirty", "huge_pages", "2026-02-01T00:00:00+00:00", True),
    ]
    text = records_to_page.render_summary(records, charts=False)
    assert "frame-old-clean" in text
    for left_out in ("frame-new-dirty", "frame-older-clean", "malloc-dirty"):
        assert left_out not in text
    # The benchmark with no clean record is named (links to its section still land), not cited.
    assert "{#malloc-settings-kept-memory-huge-pages}" in text and "modified tree" in text
    # The records page lists every record, the dirty ones marked.
    records_page = records_to_page.render_records(records, charts=False)
    assert all(r["_file"].removesuffix(".json") in records_page for r in records)
    assert records_page.count("*Modified tree:") == 2


def test_performance_summary_charts_exist_and_open_the_page():
    import records_to_page

    text = (DOCS / "performance.md").read_text()
    lines = text.splitlines()
    for name in (records_to_page.HISTORY_CHART, records_to_page.FOVEATION_CHART):
        target = f"images/perf/{name}.png"
        assert f"]({target})" in text, target
        assert (DOCS / target).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", target
    # The first screen: the first chart within the page's first 20 lines; every record a link away.
    first_image = next(i for i, line in enumerate(lines) if line.startswith("!["))
    assert first_image < 20
    assert "(performance-records.md)" in text


def test_api_pages_list_functions_and_classes_before_constants():
    assert api_pages.is_data("fovjax", "DIRECTIONAL_LIGHT")
    assert not api_pages.is_data("fovjax", "render_stereo") and not api_pages.is_data("fovjax", "Scene")
    for module, page, _ in api_pages.PACKAGES:
        listed = re.findall(r"^        - (\w+)$", (DOCS / "api" / page).read_text(), re.M)
        data = [api_pages.is_data(module, name) for name in listed]
        assert data == sorted(data), page


def test_api_pages_say_which_render_stereo_is_which():
    both = ("[`fovjax.render_stereo`](fovjax.md#fovjax.render_stereo)",
            "[`fovjax.render.render_stereo`](render.md#fovjax.render.render_stereo)")  # fmt: skip
    for page in ("fovjax.md", "render.md"):
        text = (DOCS / "api" / page).read_text()
        assert all(link in text for link in both), page


@pytest.mark.parametrize("page", EXECUTED, ids=[p.stem for p in EXECUTED])
def test_tutorial_runs(page, tmp_path, capsys):
    assert run_page.code_blocks(page), f"{page.name} has no Python code"
    run_page.run_page(page, tmp_path)
    # The images the page shows from its run are files its code writes (the committed copies
    # come from `python docs/_tools/run_page.py --images`).
    assert run_page.missing_outputs(page, tmp_path) == []
    printed = capsys.readouterr().out
    assert "<bound method" not in printed and "<function " not in printed


def test_every_image_a_page_shows_exists():
    missing = [
        f"{page.relative_to(DOCS)}: {image}"
        for page in DOCS.rglob("*.md")
        for image in run_page.images(page)
        if not image.is_file()
    ]
    assert not missing, missing


def test_getting_started_and_every_tutorial_show_pictures(tmp_path):
    for page in (DOCS / "getting-started.md", *TUTORIALS):
        assert run_page.images(page), f"{page.name} shows no image"
    # The tutorials that render or plot show what their own code wrote.
    for name in ("acuity-fit", "stereo-jit-grad", "compare-thresholds", "sessions", "user-study"):
        assert run_page.outputs(DOCS / "tutorials" / f"{name}.md"), name
    assert run_page.outputs(DOCS / "index.md")
    # An image a page names that its run did not write is caught (here: no run at all).
    page = DOCS / "tutorials" / "stereo-jit-grad.md"
    assert run_page.missing_outputs(page, tmp_path) == ["out/frame.png", "out/again.png"]


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
