"""Frames under glibc malloc's settings — the defaults, huge pages, kept memory, both — in
alternating processes.

    python benchmarks/huge_pages.py                      # the atrium, 2 x 1280x1024, SPP 1
    python benchmarks/huge_pages.py --rounds 3 --repeats 7 --size 640 512
    python benchmarks/huge_pages.py --variants "huge pages" "huge + kept"

XLA allocates a frame program's buffers on every call and frees them after; with malloc's
defaults each call faults its pages in afresh (`benchmarks/mitsuba_frame.py` prints them as
"fresh MiB"). Two settings: huge pages (`glibc.malloc.hugetlb=1`: 2 MiB pages for malloc's
large blocks) and kept memory (one arena, no mmap'd blocks, no trimming: a freed frame's memory
serves the next). Importing fovjax sets kept memory itself, through mallopt (fovjax/_startup.py;
`benchmarks/kept_memory.py` measures that way against this one); here each variant is its
tunables alone (FOVJAX_KEEP_MEMORY=0). The tunables are read when a process starts, so the
variants run in separate processes, in turn (`--rounds` rounds, the order alternated), each one
the same renderer (`FoveatedRenderer`: the full frame and the foveated 5°/10° frame at an
off-centre gaze) compiled once then timed `--repeats` times. Printed per
variant: the median wall and CPU ms per frame, the kernel (sys) ms and the minor page faults per
frame, the process's peak resident memory, and the time ratios over the defaults (< 1: faster).
Writes a record.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _processes import (  # noqa: E402
    GAZE,
    add_arguments,
    atrium_renderer,
    check_arguments,
    print_result,
    run_measuring_process,
)

from fovjax._startup import HUGE_PAGES_TUNABLE, KEPT_MEMORY_TUNABLES, glibc_version  # noqa: E402

KEPT = ":".join(KEPT_MEMORY_TUNABLES)
VARIANTS = {
    "default pages": None,
    "huge pages": HUGE_PAGES_TUNABLE,
    "kept memory": KEPT,  # what importing fovjax sets through mallopt
    "huge + kept": f"{HUGE_PAGES_TUNABLE}:{KEPT}",
}


def child(args) -> None:
    """One process: compile, then time each frame `repeats` times; print one JSON line."""
    import jax

    renderer, gaze = atrium_renderer(args.size), GAZE
    frames = {"full": renderer.render_full, "foveated": lambda: renderer.render(gaze)}
    out = {}
    for name, render in frames.items():
        jax.block_until_ready(render().image)  # compiles
        rows = []
        for _ in range(args.repeats):
            u0, t0, c0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter(), time.process_time()
            jax.block_until_ready(render().image)
            t1, c1, u1 = time.perf_counter(), time.process_time(), resource.getrusage(resource.RUSAGE_SELF)
            rows.append((t1 - t0, c1 - c0, u1.ru_stime - u0.ru_stime, u1.ru_minflt - u0.ru_minflt))
        out[name] = [statistics.median(r[i] for r in rows) for i in range(4)]
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    print_result({"tunables": os.environ.get("GLIBC_TUNABLES", ""), "frames": out, "peak_mib": peak_mib})


def run_variant(tunables: str | None, args) -> dict:
    env = dict(os.environ, FOVJAX_KEEP_MEMORY="0")  # malloc as the tunables say, no more
    env.pop("GLIBC_TUNABLES", None)
    if tunables:
        env["GLIBC_TUNABLES"] = tunables
    argv = ["--child", "--repeats", str(args.repeats), "--size", *map(str, args.size)]
    return run_measuring_process("huge_pages", __file__, argv, env)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(ap, repeats=7)
    ap.add_argument("--variants", nargs="+", choices=tuple(VARIANTS), default=tuple(VARIANTS)[1:])
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    check_arguments(ap, args)
    if args.child:
        child(args)
        return
    if glibc_version() is None:
        sys.exit("huge_pages: needs Linux with glibc (its malloc tunables)")
    variants = list(dict.fromkeys(["default pages", *args.variants]))
    runs = {name: [] for name in variants}
    peaks = {name: [] for name in variants}
    for r in range(args.rounds):
        order = variants if r % 2 == 0 else variants[::-1]
        for name in order:
            result = run_variant(VARIANTS[name], args)
            runs[name].append(result["frames"])
            peaks[name].append(result["peak_mib"])
            f = result["frames"]
            print(
                f"round {r + 1} {name:14s} full {1e3 * f['full'][0]:7.1f} ms  "
                f"foveated {1e3 * f['foveated'][0]:7.1f} ms",
                flush=True,
            )
    w, h = args.size
    rows, figures = [], {}
    for frame in ("full", "foveated"):
        med = {
            name: [statistics.median(run[frame][i] for run in runs[name]) for i in range(4)]
            for name in variants
        }
        for name in variants:
            wall, cpu, sys_s, faults = med[name]
            peak = round(max(peaks[name]))
            row = [frame, name, round(1e3 * wall, 1), round(1e3 * cpu, 1), round(1e3 * sys_s, 1), int(faults)]
            rows.append([*row, peak])
        for name in variants[1:]:
            key = name.replace(" ", "_")
            figures[f"{frame}_{key}_wall_ratio"] = round(med[name][0] / med["default pages"][0], 3)
            figures[f"{frame}_{key}_cpu_ratio"] = round(med[name][1] / med["default pages"][1], 3)
    print(
        f"\n2 x {w}x{h}, SPP 1, the atrium; medians over {args.rounds} processes x {args.repeats} frames each"
    )
    print(
        f"  {'frame':9s} {'variant':14s} {'wall ms':>8s} {'CPU ms':>8s} {'sys ms':>7s} {'faults':>8s} "
        f"{'peak MiB':>8s}"
    )
    for row in rows:
        print(f"  {row[0]:9s} {row[1]:14s} {row[2]:8.1f} {row[3]:8.1f} {row[4]:7.1f} {row[5]:8d} {row[6]:8d}")
    for name in variants[1:]:
        key = name.replace(" ", "_")
        print(
            f"  time ratios, {name} / default pages (< 1: faster): "
            f"full {figures[f'full_{key}_wall_ratio']:.3f} (CPU {figures[f'full_{key}_cpu_ratio']:.3f}), "
            f"foveated {figures[f'foveated_{key}_wall_ratio']:.3f} "
            f"(CPU {figures[f'foveated_{key}_cpu_ratio']:.3f})"
        )
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _record import write_record

    figures["tables"] = [
        {
            "title": (
                f"malloc's settings: default, large blocks on huge pages (GLIBC_TUNABLES="
                f"{HUGE_PAGES_TUNABLE}), kept memory ({KEPT}; what importing fovjax sets) "
                f"and both, as run: the atrium, 2 x {w}x{h}, SPP 1, full and foveated 5°/10° frames; "
                f"medians of {args.rounds} processes per variant, {args.repeats} frames each; peak: the "
                "largest resident memory of a variant's processes (both frames compiled and run)"
            ),
            "columns": ["frame", "malloc", "wall ms", "CPU ms", "sys ms", "minor faults", "peak MiB"],
            "rows": rows,
        }
    ]
    write_record("huge_pages", figures)


if __name__ == "__main__":
    main()
