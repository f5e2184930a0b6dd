"""Turn the benchmark records (benchmarks/results/*.json) into the documentation's Performance page.

    python benchmarks/records_to_page.py           # rewrite docs/performance.md, its charts, docs/_generated/
    python benchmarks/records_to_page.py --check   # exit 1 if the page is stale

The page quotes the records only: one section per benchmark, one subsection per record (newest
first), with its command, date, commit, machine and tables. A table with a `chart` gets a bar
chart (docs/images/perf/). tests/test_docs.py fails while the page is stale.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results"
PAGE = ROOT / "docs" / "performance.md"
CHARTS = ROOT / "docs" / "images" / "perf"
# Each record's tables alone, for other pages to include (`--8<-- "docs/_generated/<stem>.md"`,
# e.g. docs/thesis.md): pages quote records, not copies of their numbers.
GENERATED = ROOT / "docs" / "_generated"

# Sections in this order; a benchmark not listed goes last, under its own name.
SECTIONS = [
    ("fovjax_render", "The main job: `fovjax render`"),
    ("compile_cache", "Compile cache"),
    ("trace_throughput", "Ray queries"),
    ("mitsuba_frame", "Frames against Mitsuba 3"),
    ("render", "Full frames"),
    ("foveation", "Foveated frames"),
    ("profile_frame", "Inside the frame program"),
    ("compile_options", "Compile options: XLA's emitters, the ray queries' branches"),
    ("huge_pages", "Malloc settings: kept memory, huge pages"),
    ("kept_memory", "Kept memory: a script and the program"),
    ("fidelity", "Fidelity per region"),
    ("fidelity_density", "Sampling density"),
    ("plan_fidelity", "Planned fidelity"),
    ("lod", "Geometry level of detail: the levels"),
    ("lod_tree_cost", "Geometry level of detail: tree cost"),
    ("lod_frame", "Geometry level of detail: in a frame"),
    ("compare", "Comparing thresholds"),
    ("failures", "Failure cases"),
    ("study_video", "The user study on video"),
    ("video_study_sensitivity", "The video study's sensitivity"),
    ("shard", "Scaling out"),
    ("view_latency", "Live viewer"),
    ("cornell_inverse", "Inverse rendering example"),
]

HEAD = """# Performance

<!-- Written by benchmarks/records_to_page.py from benchmarks/results/*.json; do not edit. -->

Every figure on this page comes from a record in `benchmarks/results/`: one JSON file per
benchmark run, with its command, date, git commit, machine (CPU, cores, GPU, load) and library
versions. Records marked *transcribed* were copied from the figures the README stated before
the records existed: the date and machine are as the README gave them, and their own commit and
versions were not recorded. Timings on a shared 2-core machine vary by ±30% between runs: read
the ratios within one record. To add a record, run the benchmark (it writes one) and then
`python benchmarks/records_to_page.py`; see [Contributing](contributing.md).

What the figures mean for your choices is on [How to choose](how-to-choose.md).

## Ray-query backends

`backend="auto"` (Embree through XLA's FFI on a CPU) against bare Embree (embreex, one and two
threads) and Mitsuba 3 on the same rays: [Ray queries](#ray-queries)
(`benchmarks/trace_throughput.py`). Whole frames against Mitsuba 3 rendering the same Whitted
frame (same rays, materials, light and depth; its image checked against fovjax's by PSNR):
[Frames against Mitsuba 3](#frames-against-mitsuba-3) (`benchmarks/mitsuba_frame.py`). The
foveated frame against the full one and the per-stage profile: [Foveated
frames](#foveated-frames) (`benchmarks/foveation.py --speedup`, `--profile`). Where the fused
frame program's own time goes, operation by operation, grouped by stage: [Inside the frame
program](#inside-the-frame-program) (`benchmarks/profile_frame.py`).
"""


def load() -> list[dict]:
    records = []
    for path in sorted(RESULTS.glob("*.json")):
        rec = json.loads(path.read_text())
        rec["_file"] = path.name
        records.append(rec)
    return records


def cell(value) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, int):
        return f"{value:,}" if abs(value) >= 10000 else str(value)
    if isinstance(value, float):
        return f"{value:g}"
    return str(value).replace("|", "\\|")


def value_text(value) -> str:
    if isinstance(value, dict):
        return "; ".join(f"{k}: {value_text(v)}" for k, v in value.items())
    if isinstance(value, list):
        return ", ".join(value_text(v) for v in value)
    return cell(value)


def slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")


def chart(table: dict, name: str) -> str | None:
    spec = table.get("chart")
    if not spec:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    cols = table["columns"]
    labels = [str(r[cols.index(spec["label"])]) for r in table["rows"]]
    series = [(v, [r[cols.index(v)] or 0 for r in table["rows"]]) for v in spec["values"]]
    x = np.arange(len(labels))
    width = 0.8 / len(series)
    fig, ax = plt.subplots(figsize=(7, 3.2), dpi=100)
    for i, (label, values) in enumerate(series):
        ax.bar(x + (i - (len(series) - 1) / 2) * width, values, width, label=label)
    ax.set_xticks(x, [lbl if len(lbl) < 28 else lbl[:26] + "…" for lbl in labels], fontsize=7)
    ax.set_ylabel(spec.get("ylabel", ""))
    ax.legend(fontsize=7)
    fig.tight_layout()
    CHARTS.mkdir(parents=True, exist_ok=True)
    fig.savefig(CHARTS / f"{name}.png", metadata={"Software": None})
    plt.close(fig)
    return f"images/perf/{name}.png"


def tables_md(rec: dict) -> str:
    """A record's tables as Markdown, with a line naming the record."""
    stem = rec["_file"].removesuffix(".json")
    out = []
    for table in rec["figures"].get("tables", []):
        out.append(f"{table['title']}\n")
        out.append("| " + " | ".join(table["columns"]) + " |")
        out.append("|" + "---|" * len(table["columns"]))
        out += ["| " + " | ".join(cell(v) for v in row) + " |" for row in table["rows"]]
        out.append("")
    anchor = slug(stem)
    source = f"benchmarks/results/{rec['_file']}"
    out.append(f"*From the record [`{stem}`](performance.md#{anchor}) (`{source}`).*")
    return "\n".join(out) + "\n"


def generated(records: list[dict]) -> dict[Path, str]:
    return {GENERATED / f"{r['_file'].removesuffix('.json')}.md": tables_md(r) for r in records}


def render(records: list[dict], *, charts: bool) -> str:
    out = [HEAD]
    order = {name: i for i, (name, _) in enumerate(SECTIONS)}
    titles = dict(SECTIONS)
    groups: dict[str, list[dict]] = {}
    for rec in records:
        groups.setdefault(rec["benchmark"], []).append(rec)
    for name in sorted(groups, key=lambda n: (order.get(n, len(order)), n)):
        out.append(f"## {titles.get(name, name)}\n")
        recs = sorted(groups[name], key=lambda r: (r.get("date") or "", r["_file"]), reverse=True)
        for rec in recs:
            stem = rec["_file"].removesuffix(".json")
            machine = rec.get("machine", {})
            load = machine.get("load_average_stated", machine.get("load_average"))
            when = rec.get("date") or "date not stated"
            out.append(f"### `{stem}` {{#{slug(stem)}}}\n")
            out.append(f"- command: `{rec['command']}`")
            out.append(f"- date: {when}; commit: {rec.get('commit') or 'not recorded'}")
            gpus = ", ".join(machine.get("gpus") or []) or "none"
            cpu, cores = machine.get("cpu", "?"), machine.get("cores", "?")
            out.append(f"- machine: {cpu}, {cores} cores, GPU: {gpus}; load: {value_text(load)}")
            if rec.get("versions"):
                out.append(f"- versions: {value_text(rec['versions'])}")
            if rec.get("transcribed"):
                t = rec["transcribed"]
                out.append(f"- *transcribed* from {t['from']} at {t['commit'][:7]}")
            out.append("")
            figures = dict(rec["figures"])
            for i, table in enumerate(figures.pop("tables", [])):
                out.append(f"{table['title']}\n")
                out.append("| " + " | ".join(table["columns"]) + " |")
                out.append("|" + "---|" * len(table["columns"]))
                for row in table["rows"]:
                    out.append("| " + " | ".join(cell(v) for v in row) + " |")
                out.append("")
                if table.get("chart"):
                    path = (
                        chart(table, f"{slug(stem)}-{i}") if charts else f"images/perf/{slug(stem)}-{i}.png"
                    )
                    out.append(f"![{table['title']}]({path})\n")
            if figures:
                for key, value in figures.items():
                    out.append(f"- {key.replace('_', ' ')}: {value_text(value)}")
                out.append("")
            if rec.get("note"):
                out.append(f"{rec['note']}\n")
    return "\n".join(out).rstrip() + "\n"


def stale() -> list[str]:
    """What is out of date: the page, or a chart it names that is missing."""
    text = render(load(), charts=False)
    problems = [] if PAGE.exists() and PAGE.read_text() == text else [str(PAGE.relative_to(ROOT))]
    for path, md in generated(load()).items():
        if not path.exists() or path.read_text() != md:
            problems.append(str(path.relative_to(ROOT)))
    for name in re.findall(r"\]\((images/perf/[^)]+)\)", text):
        if not (ROOT / "docs" / name).exists():
            problems.append(name)
    return problems


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the page is stale")
    args = parser.parse_args()
    if args.check:
        problems = stale()
        for p in problems:
            print(f"stale: {p} (run python benchmarks/records_to_page.py)")
        return 1 if problems else 0
    records = load()
    PAGE.write_text(render(records, charts=True))
    GENERATED.mkdir(exist_ok=True)
    for old in GENERATED.glob("*.md"):
        old.unlink()
    for path, md in generated(records).items():
        path.write_text(md)
    print(f"wrote {PAGE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
