"""The main job with and without the persistent compilation cache, in one run.

    python benchmarks/compile_cache.py                 # `fovjax render` (2 x 1280x1024 foveated + full)
    python benchmarks/compile_cache.py --args --width 320 --height 256

Runs the same `fovjax render` command three times as separate processes, each with its own
fresh cache directory for the BVH already built (so only compiling differs): with the cache off
(the peer: what every run paid before), with the cache on and empty (the first run on a
machine: compiles and writes), and again with that cache (a later run: loads). Prints each
frame's compile seconds as the command reports them (tracing and lowering included; only XLA's
compile is skipped by the cache), the process's wall time, and the ratios to the peer.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _record import write_record

REPO = Path(__file__).resolve().parents[1]


def run(argv, env) -> tuple[float, list[float], str]:
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "fovjax", *argv], capture_output=True, text=True, env=env)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        sys.exit(f"fovjax {' '.join(argv)} failed ({done.returncode}):\n{done.stderr}")
    compiles = [float(x) for x in re.findall(r"compile (\d+(?:\.\d+)?) s", done.stdout)]
    return wall, compiles, done.stdout


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--args", nargs=argparse.REMAINDER, default=[], help="arguments of `fovjax render`")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        base = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        # The BVH (and nothing else) is built once into a shared cache first, so no run below builds it.
        bvh_cache = tmp / "shared"
        command = ["render", *args.args, "-o", str(tmp / "out.png")]
        warm_env = dict(base, FOVJAX_CACHE_DIR=str(bvh_cache), FOVJAX_COMPILE_CACHE="0")
        run(["render", *args.args, "--preview", "-o", str(tmp / "p.png")], warm_env)
        rows = []
        off = run(command, warm_env)
        rows.append(("cache off (the peer)", off))
        on_env = dict(base, FOVJAX_CACHE_DIR=str(bvh_cache), FOVJAX_COMPILE_CACHE="1")
        rows.append(("cache on, empty (first run)", run(command, on_env)))
        rows.append(("cache on, filled (later runs)", run(command, on_env)))
        print(f"fovjax {' '.join(command[:-2])}; load average {os.getloadavg()[0]:.1f}")
        for name, (wall, compiles, _) in rows:
            ratio = sum(off[1]) / sum(compiles) if sum(compiles) else float("inf")
            per_frame = ", ".join(f"{c:.1f}" for c in compiles)
            print(
                f"  {name:32s} wall {wall:6.1f} s ({off[0] / wall:4.2f}x the peer's speed); compile per "
                f"frame {per_frame} s, total {sum(compiles):5.1f} s ({ratio:4.2f}x less)"
            )
        print("(`compile` as each frame reports it: tracing + lowering + XLA's compile or the cache's load)")
    table = {
        "title": f"`fovjax {' '.join(command[:-2])}` with JAX's persistent compilation cache",
        "columns": ["cache", "compile s per frame", "compile s", "process s", "compile, x less than off"],
        "rows": [
            [
                name,
                ", ".join(f"{c:.1f}" for c in compiles),
                round(sum(compiles), 2),
                round(wall, 2),
                round(sum(off[1]) / sum(compiles), 2) if sum(compiles) else None,
            ]
            for name, (wall, compiles, _) in rows
        ],
        "chart": {"label": "cache", "values": ["compile s"], "ylabel": "compile s"},
    }
    write_record("compile_cache", {"tables": [table]})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
