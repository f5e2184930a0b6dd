"""Benchmark records: every benchmark run writes one JSON file under `benchmarks/results/`.

A record holds what a figure needs to be believed and re-run: the command line, the git commit
(and whether the tree had changes), the date, the machine (CPU model, cores, GPU if any, the
platform JAX ran on) and the library versions, beside the figures themselves.
`benchmarks/records_to_page.py` turns the records into the documentation's Performance page;
the documentation quotes no figure that no record holds.

    from _record import write_record
    write_record("render", {"tables": [...]})      # benchmarks/results/render-<date>-<commit>.json

`figures` is any JSON-ready dict. Tables the Performance page should show go in
`figures["tables"]`, each `{"title": ..., "columns": [...], "rows": [[...], ...]}` (optionally
`"chart": {"label": column, "values": [column, ...], "ylabel": ...}` for a bar chart);
other keys are shown as a list of values. `note` (a string) is printed under the record.
Set FOVJAX_BENCH_RECORD=0 to run a benchmark without writing a record.
"""

from __future__ import annotations

import datetime as _dt
import importlib.metadata as _metadata
import json
import os
import platform
import re
import shlex
import subprocess
import sys
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
ROOT = RESULTS.parents[1]
LIBRARIES = ("fovjax", "jax", "jaxlib", "equinox", "optimistix", "numpy", "embreex", "mitsuba", "torch")


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _gpus() -> list[str]:
    try:
        out = subprocess.run(
            ["nvidia-smi", "--query-gpu=name,memory.total", "--format=csv,noheader"],
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.TimeoutExpired):
        return []
    return [line.strip() for line in out.stdout.splitlines() if line.strip()] if out.returncode == 0 else []


SETTINGS = ("FOVJAX_XLA_EMITTERS", "FOVJAX_KEEP_MEMORY", "XLA_FLAGS")


def machine() -> dict:
    """CPU model, cores, load average at the time, GPUs (nvidia-smi), and JAX's devices if JAX
    was already imported (a record never imports JAX itself: it would pick a backend)."""
    info = {
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "gpus": _gpus(),
        # malloc's settings read at process start; importing fovjax sets its own (below)
        "glibc_tunables": os.environ.get("GLIBC_TUNABLES", ""),
        # Settings that change how frame programs compile or run (fovjax's own and XLA's).
        "settings": {k: os.environ[k] for k in SETTINGS if k in os.environ},
    }
    try:
        info["load_average"] = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        pass
    startup = sys.modules.get("fovjax._startup")  # how importing fovjax left malloc
    if startup is not None and startup.describe_malloc() is not None:
        info["malloc"] = startup.describe_malloc()
    jax = sys.modules.get("jax")
    if jax is not None:
        try:
            info["jax_devices"] = [str(d) for d in jax.devices()]
        except Exception:  # noqa: BLE001 -- a record must not fail the benchmark
            pass
    return info


def versions() -> dict[str, str]:
    out = {}
    for name in LIBRARIES:
        try:
            out[name] = _metadata.version(name)
        except _metadata.PackageNotFoundError:
            pass
    return out


def write_record(
    name: str, figures: dict, *, command: str | None = None, note: str | None = None
) -> Path | None:
    """Write `figures` with the run's provenance to a new record and return its path.

    Args:
        name: the benchmark's name (lower case, digits, underscores); the file is
            `benchmarks/results/<name>-<UTC date and time>-<commit>.json`.
        figures: the measured values, JSON-ready (see the module docstring for `tables`).
        command: the command line to record; defaults to this process's.
        note: what a reader should know about the run (load, what else ran).

    Returns:
        The record's path, or None when FOVJAX_BENCH_RECORD=0.
    """
    if os.environ.get("FOVJAX_BENCH_RECORD", "1") == "0":
        return None
    if not re.fullmatch(r"[a-z0-9_]+", name):
        raise ValueError(f"record name {name!r}: use lower-case letters, digits and underscores")
    now = _dt.datetime.now(_dt.UTC).replace(microsecond=0)
    # A copy of the tree without its git folder (a lent GPU machine): the commit as given.
    commit = _git("rev-parse", "HEAD") or os.environ.get("FOVJAX_BENCH_COMMIT")
    record = {
        "benchmark": name,
        "command": command or shlex.join(["python", *sys.argv]),
        "date": now.isoformat(),
        "commit": commit,
        "dirty": bool(_git("status", "--porcelain", "--untracked-files=no")),
        "machine": machine(),
        "versions": versions(),
        "figures": figures,
    }
    if note:
        record["note"] = note
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}-{now.strftime('%Y%m%dT%H%M%S')}-{(commit or 'nogit')[:7]}.json"
    path.write_text(json.dumps(record, indent=1, ensure_ascii=False) + "\n")
    print(f"record: {path.relative_to(ROOT)}")
    return path
