"""A plain script that imports fovjax against the `fovjax` program, and kept memory set through
mallopt at import against the same settings as glibc tunables at process start: the atrium's
foveated frame, in alternating processes.

    python benchmarks/kept_memory.py                      # the atrium, 2 x 1280x1024, SPP 1
    python benchmarks/kept_memory.py --rounds 3 --repeats 7 --size 640 512

Importing fovjax keeps malloc's freed memory for the next frame (fovjax/_startup.py): `mallopt`,
before JAX starts, in every process that imports it. Before that, only the `fovjax` program had
it: it started itself again (`os.execv`) with the settings as GLIBC_TUNABLES, and a script that
imported fovjax ran on malloc's defaults. The variants, each a process of its own, in turn
(`--rounds` rounds, the order alternated):

- `script`: a plain Python script (`import jax`, `import numpy`, `import fovjax`, the renderer,
  its frames) started with no GLIBC_TUNABLES: kept memory is what importing fovjax sets.
- `program (re-exec)`: the `fovjax` program as it started when only it kept memory: the process
  starts itself again with GLIBC_TUNABLES=KEPT_MEMORY_TUNABLES, then the same frames (importing
  fovjax leaves malloc to the user's tunables).
- `defaults`: FOVJAX_KEEP_MEMORY=0, malloc's defaults: a script before this change.
- `late`: a JAX computation before fovjax is imported, so XLA's threads exist and keep the
  arenas they have; importing fovjax still calls mallopt.

Each process builds the same renderer (`FoveatedRenderer`, the atrium, foveated 5°/10° at an
off-centre gaze; `_processes.atrium_renderer`), loads its program from a compile cache a first,
unmeasured process filled (the same executable in every process, no compile inside the
measured ones), then times `--repeats` frames. Printed per variant: the median wall and CPU ms
per frame, the kernel (sys) ms and the minor page faults per frame, the peak resident memory and
what importing fovjax did with malloc; then each variant's time over the program's (< 1:
faster). The script's ratio is the library's speed against the program's. Writes a record.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import tempfile
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

SCRIPT, PROGRAM, DEFAULTS, LATE = "script", "program (re-exec)", "defaults", "late"
VARIANTS = (SCRIPT, PROGRAM, DEFAULTS, LATE)


def child(args) -> None:
    """One process of `args.child`'s variant: frames timed after a warm-up; one RESULT line."""
    if args.child == PROGRAM and "GLIBC_TUNABLES" not in os.environ:
        # What the program did at import when only it kept memory, before anything else.
        os.environ["GLIBC_TUNABLES"] = args.tunables
        sys.stdout.flush()
        os.execv(sys.executable, [sys.executable, *sys.orig_argv[1:]])
    import jax
    import numpy as np  # noqa: F401 -- a script's usual imports, before fovjax's

    if args.child == LATE:
        jax.block_until_ready(jax.numpy.zeros(8) + 1)  # XLA starts its threads
    import fovjax
    from fovjax._startup import MALLOC, describe_malloc

    fovjax.enable_compile_cache(args.cache)
    renderer = atrium_renderer(args.size)
    jax.block_until_ready(renderer.render(GAZE).image)  # loads (or compiles) the program
    jax.block_until_ready(renderer.render(GAZE).image)
    rows = []
    for _ in range(args.repeats):
        u0, t0, c0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter(), time.process_time()
        jax.block_until_ready(renderer.render(GAZE).image)
        t1, c1, u1 = time.perf_counter(), time.process_time(), resource.getrusage(resource.RUSAGE_SELF)
        rows.append((t1 - t0, c1 - c0, u1.ru_stime - u0.ru_stime, u1.ru_minflt - u0.ru_minflt))
    print_result(
        {
            "frame": [statistics.median(r[i] for r in rows) for i in range(4)],
            "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,  # KiB on Linux
            "malloc": MALLOC,
            "malloc_said": describe_malloc(),
            "tunables": os.environ.get("GLIBC_TUNABLES", ""),
        }
    )


def run_variant(name: str, args, cache: str, tunables: str) -> dict:
    env = dict(os.environ)
    env.pop("GLIBC_TUNABLES", None)
    env.pop("FOVJAX_KEEP_MEMORY", None)
    if name == DEFAULTS:
        env["FOVJAX_KEEP_MEMORY"] = "0"
    argv = ["--child", name, "--cache", cache, "--tunables", tunables, "--repeats", str(args.repeats)]
    return run_measuring_process("kept_memory", __file__, [*argv, "--size", *map(str, args.size)], env)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(ap, repeats=7)
    ap.add_argument("--variants", nargs="+", choices=VARIANTS, default=VARIANTS)
    ap.add_argument("--note", help="what a reader of the record should know (load, what else ran)")
    ap.add_argument("--child", choices=VARIANTS, help=argparse.SUPPRESS)
    ap.add_argument("--cache", help=argparse.SUPPRESS)
    ap.add_argument("--tunables", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    check_arguments(ap, args)
    if args.child:
        child(args)
        return
    from fovjax._startup import KEPT_MEMORY_TUNABLES, glibc_version

    if glibc_version() is None:
        sys.exit("kept_memory: needs Linux with glibc (its malloc)")
    tunables = ":".join(KEPT_MEMORY_TUNABLES)
    variants = list(dict.fromkeys([PROGRAM, SCRIPT, *args.variants]))
    runs = {name: [] for name in variants}
    with tempfile.TemporaryDirectory(prefix="fovjax-kept-memory-") as cache:
        run_variant(SCRIPT, args, cache, tunables)  # fills the compile cache; not measured
        for r in range(args.rounds):
            for name in variants if r % 2 == 0 else variants[::-1]:
                result = run_variant(name, args, cache, tunables)
                runs[name].append(result)
                wall, _, _, faults = result["frame"]
                print(f"round {r + 1} {name:18s} {1e3 * wall:7.1f} ms  {int(faults):7d} faults", flush=True)
    w, h = args.size
    med = {n: [statistics.median(run["frame"][i] for run in runs[n]) for i in range(4)] for n in variants}
    rows, figures = [], {}
    for name in variants:
        wall, cpu, sys_s, faults = med[name]
        peak = round(max(run["peak_mib"] for run in runs[name]))
        said = runs[name][-1]["malloc_said"]
        rows.append(
            [name, round(1e3 * wall, 1), round(1e3 * cpu, 1), round(1e3 * sys_s, 1), int(faults), peak, said]
        )
        key = name.split(" ")[0]
        figures[f"{key}_wall_ms"] = round(1e3 * wall, 1)
        figures[f"{key}_faults_per_frame"] = int(faults)
        if name != PROGRAM:
            figures[f"{key}_over_program_wall"] = round(wall / med[PROGRAM][0], 3)
            figures[f"{key}_over_program_cpu"] = round(cpu / med[PROGRAM][1], 3)
    print(
        f"\nthe atrium's foveated frame, 2 x {w}x{h}, SPP 1; medians over {args.rounds} processes "
        f"x {args.repeats} frames"
    )
    print(
        f"  {'variant':18s} {'wall ms':>8s} {'CPU ms':>8s} {'sys ms':>7s} {'faults':>8s} "
        f"{'peak MiB':>8s}  malloc"
    )
    for row in rows:
        print(f"  {row[0]:18s} {row[1]:8.1f} {row[2]:8.1f} {row[3]:7.1f} {row[4]:8d} {row[5]:8d}  {row[6]}")
    for name in variants:
        if name != PROGRAM:
            key = name.split(" ")[0]
            print(
                f"  {name} / program (re-exec): wall {figures[f'{key}_over_program_wall']:.3f}, "
                f"CPU {figures[f'{key}_over_program_cpu']:.3f}"
            )
    from _record import write_record

    figures["tables"] = [
        {
            "title": (
                f"A plain script that imports fovjax (kept memory through mallopt at import) against "
                f"the fovjax program as it started when only it kept memory (re-executed with "
                f"GLIBC_TUNABLES={tunables}), "
                f"malloc's defaults (FOVJAX_KEEP_MEMORY=0) and mallopt after a JAX computation (late): "
                f"the atrium's foveated 5°/10° frame, 2 x {w}x{h}, SPP 1; medians of {args.rounds} "
                f"processes per variant, {args.repeats} frames each, the order alternated"
            ),
            "columns": ["variant", "wall ms", "CPU ms", "sys ms", "minor faults", "peak MiB", "malloc"],
            "rows": rows,
        }
    ]
    write_record("kept_memory", figures, note=args.note)


if __name__ == "__main__":
    main()
