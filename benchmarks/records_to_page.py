"""Turn the benchmark records (benchmarks/results/*.json) into the documentation's Performance pages.

    python benchmarks/records_to_page.py           # rewrite the pages, their charts, docs/_generated/
    python benchmarks/records_to_page.py --check   # exit 1 if a page is stale

docs/performance.md is the summary: a headline table (per benchmark, on CPU and on GPU apart, the
newest clean record's first figures, newest first) and charts drawn from the records (frames
against Mitsuba 3 over the project's history; foveated against full frames per SPP).
docs/performance-records.md quotes every record: one section per benchmark, one subsection per
record (newest first), with its command, date, commit, machine and tables; a table with a `chart`
gets a bar chart. Charts go to docs/images/perf/. A record is *clean* when git had no changes in
the tree it ran from (`dirty: false`, benchmarks/_record.py); records of a modified tree are
listed with the others but cited in no headline or chart. tests/test_docs.py fails while a page
is stale.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import re
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results"
PAGE = ROOT / "docs" / "performance.md"
RECORDS_PAGE = ROOT / "docs" / "performance-records.md"
CHARTS = ROOT / "docs" / "images" / "perf"
# Each record's tables alone, for other pages to include (`--8<-- "docs/_generated/<stem>.md"`,
# e.g. docs/thesis.md): pages quote records, not copies of their numbers.
GENERATED = ROOT / "docs" / "_generated"
# The summary's charts (docs/images/perf/<name>.png), drawn from the records by `summary_charts`.
HISTORY_CHART = "summary-frames-history"
FOVEATION_CHART = "summary-foveated-vs-full"

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
    ("ray_density", "Cost per ray against pixel density"),
    ("trace_warp", "Ray queries on a GPU: Warp and the JAX traversal"),
    ("compare_video", "Foveation methods along a gaze recording"),
]

# The records page stays out of the site's search index (Material's `search: exclude`): its tables
# of every run would be most of the index that each page of the site loads, and indexing them is
# most of the site's build; the summary page, which links into it, is searched.
RECORDS_HEAD = """---
search:
  exclude: true
---

# Performance records

<!-- Written by benchmarks/records_to_page.py from benchmarks/results/*.json; do not edit. -->

Every record in `benchmarks/results/`, benchmark by benchmark, newest first; the
[summary](performance.md) has the headline figures and charts. A record is one JSON file per
benchmark run, with its command, date, git commit (and whether the tree had changes: *modified
tree*), machine (CPU, cores, GPU, load) and library versions. Records marked *transcribed* were
copied from the figures the README stated before the records existed: the date and machine are as
the README gave them, and their own commit and versions were not recorded. Timings on a shared
2-core machine vary by ±30% between runs: read the ratios within one record. To add a record, run
the benchmark (it writes one) and then `python benchmarks/records_to_page.py`; see
[Contributing](contributing.md).

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

SUMMARY_HEAD = """# Performance

<!-- Written by benchmarks/records_to_page.py from benchmarks/results/*.json; do not edit. -->

Every figure here comes from a benchmark record in `benchmarks/results/` (its command, date, git
commit, machine and library versions); [all {count} records](performance-records.md) are listed
benchmark by benchmark on the next page, and what the figures mean for your choices is on [How to
choose](how-to-choose.md). Timings on a shared 2-core CPU vary by ±30% between runs: compare
figures within one record.
"""

# Per benchmark, the columns of its first table the headline shows (the first column labels the
# rows), and how many rows; others show their first two value columns and two rows.
HEADLINES = {
    "mitsuba_frame": (["ms per frame"], 3),
    "foveation": (["foveated ms", "full ms", "speed-up"], 2),
    "trace_throughput": (["fovjax auto", "Embree 2 threads", "Mitsuba 3"], 3),
    # Not the "JAX" column: up to trace_warp-20261204T195340 it ran Warp too (CHANGELOG, Fixed).
    "trace_warp": (["Warp (lbvh) Mrays/s", "Warp (sah) Mrays/s"], 3),
    "profile_frame": (["full", "foveated"], 3),
    "compile_options": (["variant", "compile s", "ms per frame"], 4),
    "fovjax_render": (["frame", "s per frame", "compile s"], 2),
    "compile_cache": (["compile s (run 1)", "process s (run 1)"], 3),
    "render": (["SPP", "ms / frame", "Mrays/s"], 4),
    "view_latency": (["viewer fps", "latency median (p90) ms"], 2),
    "ray_density": (["fovjax ns per ray", "Mitsuba 3 ns per ray"], 3),
    "shard": (["foveated, run 1", "full, run 1"], 3),
}
MAX_TITLE = 72


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
    out.append(f"*From the record [`{stem}`](performance-records.md#{anchor}) (`{source}`).*")
    return "\n".join(out) + "\n"


def generated(records: list[dict]) -> dict[Path, str]:
    return {GENERATED / f"{r['_file'].removesuffix('.json')}.md": tables_md(r) for r in records}


def status(rec: dict) -> str:
    """ "clean" (git had no changes in the tree it ran from), "modified tree", or "transcribed"
    (figures the README stated before records existed; no git state recorded)."""
    if rec.get("transcribed"):
        return "transcribed"
    return "clean" if rec.get("dirty") is False else "modified tree"


def platform(rec: dict) -> str:
    """ "GPU" when JAX ran on one (the record's `jax_devices`), else "CPU"."""
    devices = rec.get("machine", {}).get("jax_devices") or []
    return "GPU" if any(d.split(":")[0] in ("cuda", "gpu", "rocm") for d in devices) else "CPU"


def newest_first(records: list[dict]) -> list[dict]:
    return sorted(records, key=lambda r: (r.get("date") or "", r["_file"]), reverse=True)


def stem_of(rec: dict) -> str:
    return rec["_file"].removesuffix(".json")


def record_link(rec: dict) -> str:
    stem = stem_of(rec)
    return f"[`{stem}`](performance-records.md#{slug(stem)})"


def section_titles() -> dict[str, str]:
    return dict(SECTIONS)


def section_order(names) -> list[str]:
    order = {name: i for i, (name, _) in enumerate(SECTIONS)}
    return sorted(names, key=lambda n: (order.get(n, len(order)), n))


def render_records(records: list[dict], *, charts: bool) -> str:
    """The records page: every record, benchmark by benchmark, newest first."""
    out = [RECORDS_HEAD]
    titles = section_titles()
    groups: dict[str, list[dict]] = {}
    for rec in records:
        groups.setdefault(rec["benchmark"], []).append(rec)
    for name in section_order(groups):
        out.append(f"## {titles.get(name, name)}\n")
        for rec in newest_first(groups[name]):
            stem = stem_of(rec)
            machine = rec.get("machine", {})
            load = machine.get("load_average_stated", machine.get("load_average"))
            when = rec.get("date") or "date not stated"
            out.append(f"### `{stem}` {{#{slug(stem)}}}\n")
            if status(rec) == "modified tree":
                out.append(
                    "*Modified tree: git had uncommitted changes when this ran; not cited in the summary.*\n"
                )
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


def heading_slug(title: str) -> str:
    """The anchor Markdown's table of contents gives a heading (`toc`'s slugify)."""
    text = re.sub(r"[^\w\s-]", "", title.replace("`", "")).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def shorten(text: str, limit: int = MAX_TITLE) -> str:
    if len(text) <= limit:
        return text
    cut = text[:limit].rsplit(" ", 1)[0].rstrip(",;:")
    return cut + " …"


def headline_figures(rec: dict) -> str:
    """A record's first figures for the summary: its first table's title (shortened) and, for its
    first rows, the columns `HEADLINES` names (else the first two of numbers), on lines."""
    tables = rec["figures"].get("tables") or []
    if not tables:
        items = [(k, v) for k, v in rec["figures"].items() if k != "tables"][:3]
        return "; ".join(f"{k.replace('_', ' ')}: {shorten(value_text(v), 40)}" for k, v in items)
    table = tables[0]
    cols, rows = table["columns"], table["rows"]
    wanted, count = HEADLINES.get(rec["benchmark"], ((), 2))
    picked = [cols.index(c) for c in wanted if c in cols[1:]]
    if not picked:
        numeric = [
            i
            for i in range(1, len(cols))
            if any(isinstance(r[i], int | float) and not isinstance(r[i], bool) for r in rows)
        ]
        picked = (numeric or list(range(1, len(cols))))[:2]

    def label(row) -> str:
        value = cell(row[0])
        return f"{cols[0]} {value}" if isinstance(row[0], int | float) and cols[0] else value

    def figure(value) -> str:
        text = cell(value) if not isinstance(value, str) else cell(shorten(value, 40))
        return f"**{text}**" if text else "–"

    lines = [f"*{cell(shorten(table['title']))}*"]
    if len(picked) == 1:
        i = picked[0]
        lines.append(f"{cell(cols[i])}: " + "; ".join(f"{label(r)} {figure(r[i])}" for r in rows[:count]))
    else:
        for row in rows[:count]:
            lines.append(f"{label(row)}: " + ", ".join(f"{cell(cols[i])} {figure(row[i])}" for i in picked))
    if len(rows) > count:
        lines.append(f"… {len(rows) - count} more rows")
    return "<br>".join(lines)


def _first_columns(rec: dict) -> list[str]:
    tables = rec["figures"].get("tables") or []
    return tables[0]["columns"] if tables else []


def machine_text(rec: dict) -> str:
    machine = rec.get("machine", {})
    if platform(rec) == "GPU":
        return ", ".join(g.split(",")[0] for g in machine.get("gpus") or []) or "GPU"
    cpu = str(machine.get("cpu", "CPU")).split(",")[0]
    cores = machine.get("cores")
    return cpu if cores is None or "core" in cpu else f"{cpu}, {cores} cores"


def headline(records: list[dict]) -> tuple[list[tuple[str, str, dict]], list[tuple[str, str, list[dict]]]]:
    """Per (benchmark, "CPU" or "GPU"): the record the summary cites, the newest clean one, else
    the newest transcribed one; newest first. And the groups with neither (every record of a
    modified tree), which the summary names without figures."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for rec in records:
        groups.setdefault((rec["benchmark"], platform(rec)), []).append(rec)
    cited, uncited = [], []
    for (name, kind), recs in groups.items():
        # A benchmark with several kinds of run (foveation: --speedup, --profile) heads with the
        # newest record of the kind its headline columns name, when there is one.
        wanted_columns = set(HEADLINES.get(name, ((), 0))[0])
        fitting = [r for r in recs if wanted_columns & set(_first_columns(r))] or recs
        for wanted in ("clean", "transcribed"):
            chosen = [r for r in newest_first(fitting) if status(r) == wanted]
            if chosen:
                cited.append((name, kind, chosen[0]))
                break
        else:
            uncited.append((name, kind, newest_first(recs)))
    cited.sort(key=lambda c: (c[2].get("date") or "", c[2]["_file"]), reverse=True)
    order = {name: i for i, name in enumerate(section_order({n for n, _, _ in uncited}))}
    uncited.sort(key=lambda u: (order[u[0]], u[1]))
    return cited, uncited


def variant(rec: dict) -> list[str]:
    """How a `mitsuba_frame` record's options differ from the benchmark's defaults."""
    f = rec["figures"]
    out = []
    if f.get("backend") not in (None, "auto"):
        out.append(f"backend {f['backend']}")
    if f.get("hits") not in (None, "recomputed"):
        out.append(f"hits {f['hits']}")
    if f.get("integrator") not in (None, "auto"):
        out.append(f"integrator {f['integrator']}")
    if f.get("watertight") is False:
        out.append("not watertight")
    out += [f"{k}={v}" for k, v in (rec.get("machine", {}).get("settings") or {}).items()]
    return out


HISTORY_SERIES = ("Mitsuba 3, full", "fovjax, full", "fovjax, foveated")


def history(records: list[dict]) -> tuple[dict[str, list[tuple[dict, dict]]], dict[str, int]]:
    """The `mitsuba_frame` records the history chart draws: per frame size and SPP, the clean
    records at the benchmark's defaults that measured all three frames, oldest first, each with
    its ms per frame by series; and how many records were left out, by reason."""
    points: dict[str, list[tuple[dict, dict]]] = {}
    left = {"modified tree": 0, "other options": 0}
    for rec in sorted(records, key=lambda r: (r.get("date") or "", r["_file"])):
        if rec["benchmark"] != "mitsuba_frame" or platform(rec) != "CPU":
            continue
        if status(rec) != "clean":
            left["modified tree"] += 1
            continue
        if variant(rec):
            left["other options"] += 1
            continue
        f = rec["figures"]
        table = (f.get("tables") or [None])[0]
        if not table or "ms per frame" not in table["columns"]:
            continue
        ms = table["columns"].index("ms per frame")
        values = {row[0]: row[ms] for row in table["rows"] if row[0] in HISTORY_SERIES}
        if len(values) < len(HISTORY_SERIES):
            continue
        spp = (f.get("results") or [{}])[0].get("spp", 1)
        size = f"2 × {f['eye_width']}×{f['eye_height']}, SPP {spp}"
        points.setdefault(size, []).append((rec, values))
    return {k: v for k, v in points.items() if len(v) >= 3}, left


def foveation_pairs(records: list[dict]) -> dict[str, list[tuple[dict, dict]]]:
    """The `foveation --speedup` records the per-SPP chart draws: per machine kind, per frame
    size and SPP, the newest clean record's foveated and full ms."""
    out: dict[str, dict[tuple, tuple[dict, dict]]] = {}
    for rec in newest_first(records):
        speedups = rec["figures"].get("speedup")
        if rec["benchmark"] != "foveation" or status(rec) != "clean" or not isinstance(speedups, list):
            continue
        w, h = rec["figures"].get("eye", (None, None))
        for row in speedups:
            out.setdefault(platform(rec), {}).setdefault((w, h, row["spp"]), (rec, row))
    return {kind: [v for _, v in sorted(pairs.items())] for kind, pairs in sorted(out.items())}


def _dated(rec: dict) -> dt.datetime:
    return dt.datetime.fromisoformat(rec["date"])


def summary_charts(records: list[dict]) -> None:
    """Draw the summary's two charts into docs/images/perf/."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.dates as mdates
    import matplotlib.pyplot as plt
    import numpy as np

    CHARTS.mkdir(parents=True, exist_ok=True)
    points, _ = history(records)
    sizes = sorted(points, key=lambda s: -len(points[s]))
    if sizes:
        _history_chart(plt, mdates, points, sizes)
    pairs = foveation_pairs(records)
    if pairs:
        _foveation_chart(plt, np, pairs)


def _history_chart(plt, mdates, points, sizes) -> None:
    fig, axes = plt.subplots(1, len(sizes), figsize=(5 * len(sizes), 3.4), dpi=100, squeeze=False)
    for ax, size in zip(axes[0], sizes, strict=True):
        when = [_dated(rec) for rec, _ in points[size]]
        for series, marker in zip(HISTORY_SERIES, "so^", strict=True):
            ax.plot(when, [v[series] for _, v in points[size]], marker=marker, ms=4, lw=1, label=series)
        ax.set_title(f"atrium, {size}", fontsize=9)
        ax.set_ylabel("ms per frame")
        ax.set_ylim(bottom=0)
        ax.xaxis.set_major_formatter(mdates.DateFormatter("%m-%d %Hh"))
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.autofmt_xdate()
    fig.tight_layout()
    fig.savefig(CHARTS / f"{HISTORY_CHART}.png", metadata={"Software": None})
    plt.close(fig)


def _foveation_chart(plt, np, pairs) -> None:
    fig, axes = plt.subplots(1, len(pairs), figsize=(5 * len(pairs), 3.4), dpi=100, squeeze=False)
    for ax, (kind, rows) in zip(axes[0], pairs.items(), strict=True):
        x = np.arange(len(rows))
        foveated = [r["foveated_ms"] for _, r in rows]
        full = [r["full_ms"] for _, r in rows]
        # The history chart's colours: fovjax's full frame orange, its foveated frame green.
        ax.bar(x - 0.2, full, 0.4, label="full", color="C1")
        bars = ax.bar(x + 0.2, foveated, 0.4, label="foveated 5°/10°", color="C2")
        for bar, (_, r) in zip(bars, rows, strict=True):
            ax.annotate(
                f"{r['full_ms'] / r['foveated_ms']:.1f}×",
                (bar.get_x() + bar.get_width() / 2, bar.get_height()),
                ha="center",
                va="bottom",
                fontsize=8,
            )
        labels = [
            f"2×{rec['figures']['eye'][0]}×{rec['figures']['eye'][1]}\nSPP {r['spp']}\n{_dated(rec):%m-%d}"
            for rec, r in rows
        ]
        ax.set_xticks(x, labels, fontsize=7)
        gpus = sorted({machine_text(rec) for rec, _ in rows})
        ax.set_title(f"{kind}: {', '.join(gpus)}", fontsize=9)
        ax.set_ylabel("ms per frame")
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(CHARTS / f"{FOVEATION_CHART}.png", metadata={"Software": None})
    plt.close(fig)


def render_summary(records: list[dict], *, charts: bool) -> str:
    """The summary page: the charts, then the headline table, newest first."""
    if charts:
        summary_charts(records)
    titles = section_titles()
    out = [SUMMARY_HEAD.format(count=len(records))]

    points, left = history(records)
    cited = sum(len(v) for v in points.values())
    if points:
        out += _history_section(cited, left, titles)
    pairs = foveation_pairs(records)
    if pairs:
        out += _foveation_section(pairs)
    out += _headline_section(records, titles)
    return "\n".join(out).rstrip() + "\n"


def _history_section(cited: int, left: dict[str, int], titles: dict[str, str]) -> list[str]:
    return [
        "## Frames against Mitsuba 3 over the project's history\n",
        "![ms per frame over the project's history: fovjax against Mitsuba 3]"
        f"(images/perf/{HISTORY_CHART}.png)\n",
        f"One point per clean record of `benchmarks/mitsuba_frame.py` at its defaults ({cited} records, "
        "the atrium's Whitted frame at depth 5 on the project's shared 2-core CPU): Mitsuba 3's full "
        "frame against fovjax's full and foveated (5°/10°) frames of the same rays. "
        f"Left out: {left['modified tree']} records of a modified tree and {left['other options']} run "
        "with other options (hits, integrator, watertightness, compile settings). Every record: "
        f"[Frames against Mitsuba 3](performance-records.md#{heading_slug(titles['mitsuba_frame'])}).\n",
    ]


def _foveation_section(pairs: dict[str, list[tuple[dict, dict]]]) -> list[str]:
    sources = "; ".join(
        f"{kind}: " + ", ".join(record_link(rec) for rec in {r["_file"]: r for r, _ in rows}.values())
        for kind, rows in pairs.items()
    )
    return [
        "## Foveated against full frames, per SPP\n",
        f"![Foveated against full frames per SPP, on a CPU and a GPU](images/perf/{FOVEATION_CHART}.png)\n",
        "The newest clean record of `benchmarks/foveation.py --speedup` per frame size and SPP, on a "
        "CPU and a GPU apart: the atrium at depth 5, foveated at 5°/10° around an off-centre gaze, "
        "the label over each pair the speed-up; the date under each pair is its record's. "
        f"From {sources}.\n",
    ]


def _headline_section(records: list[dict], titles: dict[str, str]) -> list[str]:
    out = []
    cited_rows, uncited = headline(records)
    out.append("## Headline figures\n")
    out.append(
        "Per benchmark, on a CPU and on a GPU apart, newest first: the newest *clean* record (run from "
        "a tree without uncommitted changes) and the first figures of its first table; a benchmark "
        "without one shows its newest *transcribed* record (figures the README stated before records "
        "existed). The benchmark's name leads to all its records.\n"
    )
    out.append("| benchmark | the record's first figures | record, date, machine |")
    out.append("|---|---|---|")
    anchored: set[str] = set()
    for name, kind, rec in cited_rows:
        anchor = heading_slug(titles.get(name, name))
        link = f"[{titles.get(name, name)}](performance-records.md#{anchor})"
        if anchor not in anchored:  # links to the old page's sections land on the benchmark's row
            link += f"{{#{anchor}}}"
            anchored.add(anchor)
        if kind == "GPU":
            link += " (GPU)"
        mark = " *transcribed*" if status(rec) == "transcribed" else ""
        when = (rec.get("date") or "not stated")[:16].replace("T", " ")
        source = f"{record_link(rec)}{mark}<br>{when}<br>{machine_text(rec)}"
        out.append(f"| {link} | {headline_figures(rec)} | {source} |")
    out.append("")
    if uncited:
        names = []
        for name, kind, recs in uncited:
            anchor = heading_slug(titles.get(name, name))
            link = f"[{titles.get(name, name)}](performance-records.md#{anchor})"
            if anchor not in anchored:
                link += f"{{#{anchor}}}"
                anchored.add(anchor)
            names.append(f"{link} ({kind}, {len(recs)} record{'s' if len(recs) > 1 else ''})")
        out.append(
            "Every record of these ran from a modified tree (git had uncommitted changes), so none is "
            "cited here: " + "; ".join(names) + ".\n"
        )
    return out


def expected(records: list[dict]) -> dict[Path, str]:
    """The pages this script writes, without drawing the charts."""
    return {
        PAGE: render_summary(records, charts=False),
        RECORDS_PAGE: render_records(records, charts=False),
        **generated(records),
    }


def stale() -> list[str]:
    """What is out of date: a page, or a chart a page names that is missing."""
    problems = []
    for path, text in expected(load()).items():
        if not path.exists() or path.read_text() != text:
            problems.append(str(path.relative_to(ROOT)))
        for name in re.findall(r"\]\((images/perf/[^)]+)\)", text):
            if not (ROOT / "docs" / name).exists():
                problems.append(name)
    return problems


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if a page is stale")
    args = parser.parse_args()
    if args.check:
        problems = stale()
        for p in problems:
            print(f"stale: {p} (run python benchmarks/records_to_page.py)")
        return 1 if problems else 0
    records = load()
    PAGE.write_text(render_summary(records, charts=True))
    RECORDS_PAGE.write_text(render_records(records, charts=True))
    GENERATED.mkdir(exist_ok=True)
    for old in GENERATED.glob("*.md"):
        old.unlink()
    for path, md in generated(records).items():
        path.write_text(md)
    print(f"wrote {PAGE.relative_to(ROOT)}, {RECORDS_PAGE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
