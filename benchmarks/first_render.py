"""The first `fovjax render` on a fresh machine: end to end and by phase, from an empty cache.

    python benchmarks/first_render.py                        # 3 runs of `fovjax render`
    python benchmarks/first_render.py --repeats 5 --baseline main --prebuilt
    python benchmarks/first_render.py --check-frames         # the handlers' two builds, bit for bit
    python benchmarks/first_render.py --args --width 320 --height 256

Each run is a new process, `python -m fovjax render` with every argument after `--args`, given a
new empty `FOVJAX_CACHE_DIR` (no native handlers, no BVH, no compiled programs: what a fresh
clone has) and JAX's own compile cache unset. The progress lines the command prints are
timestamped as they arrive, and the phases are the gaps between them: startup (Python, JAX and
fovjax imported, the arguments checked), the scene, its BVH, the wait for the native handlers'
build (started in the background when the arguments were checked), the foveated frame (its
program compiled, then rendered), writing it (the first image), the full frame and writing it.
The first image's time is when `out.png` was written (its modification time). After each run
of this tree, the same command runs again with what it left in the cache ("later run"). Printed
per phase: the median over the runs and each run's figure; with `--baseline REV`, the same
command of that git revision (exported with `git archive`, run from there) alternates with this
tree's, for the before and after in one run (its phases are what its own progress lines mark);
with `--prebuilt`, this tree also runs with the native handlers already in the otherwise empty
cache (built once beforehand, as an install that built them would leave them).

`--check-frames` builds the native handlers both ways this machine can (GCC's parallel
link-time back end, `fovjax.native._library.PARALLEL_FLAGS`, and the plain unity build), each
in a fresh cache in its own process, renders the atrium's full and foveated frames at 2 x
1280x1024 with each, and compares the images bit for bit; it also times each build and the
frames (median of `--frames` each).

Writes a record. The machine is shared with other work: the load average is printed and kept.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from _record import write_record

REPO = Path(__file__).resolve().parents[1]
RESULT = "RESULT "

# (phase, the lines that begin it, the line that ends it): regular expressions on the command's
# output; a phase begins at the last of its beginning lines that was printed, and a phase whose
# lines a run did not print (an older revision, another mode) is left out.
PHASES = (
    ("startup (imports, checks)", (), r"^\[1/\d\]"),
    ("scene", (r"^\[1/\d\]",), r"^\[2/\d\]"),
    ("BVH", (r"^\[2/\d\]",), r"^\[3/\d\]"),
    (
        "wait for the native handlers",
        (r"waiting for the native handlers",),
        r"native handlers (built|unavailable)",
    ),
    ("foveated frame (compile, render)", (r"^\[3/6\]", r"native handlers (built|unavailable)"), r"^\[4/6\]"),
    ("write the first image", (r"^\[4/6\]",), r"^\[5/6\]"),
    ("full frame (compile, render)", (r"^\[5/6\]",), r"^\[6/6\]"),
    # what a revision that rendered both frames before writing either printed
    ("both frames (compile, render)", (r"^\[3/4\]",), r"^\[4/4\]"),
)


def _load() -> float:
    return round(os.getloadavg()[0], 2)


def run_once(checkout: Path, argv: list[str], tmp: Path, handlers: Path | None = None) -> dict:
    """One fresh-cache `fovjax render` from `checkout` (with the native handlers of the folder
    `handlers` already in the cache, where given): its timestamped output lines, phases, the
    first image's time, the total, and the figures the command printed."""
    cache = tmp / "cache"
    if handlers is not None:
        shutil.copytree(handlers, cache / "native")
    out = tmp / "out.png"
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR", "FOVJAX_NATIVE_DIR")}
    env.update(
        FOVJAX_CACHE_DIR=str(cache),
        PYTHONPATH=str(checkout) + os.pathsep + os.environ.get("PYTHONPATH", ""),
        PYTHONUNBUFFERED="1",
    )
    load = _load()
    start_wall, start = time.time(), time.perf_counter()
    process = subprocess.Popen(
        [sys.executable, "-m", "fovjax", "render", *argv, "-o", str(out)],
        cwd=checkout,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines: list[tuple[float, str]] = []

    def read(stream) -> None:
        for line in stream:
            lines.append((time.perf_counter() - start, line.rstrip("\n")))

    readers = [threading.Thread(target=read, args=(s,)) for s in (process.stdout, process.stderr)]
    for reader in readers:
        reader.start()
    code = process.wait()
    total = time.perf_counter() - start
    for reader in readers:
        reader.join()
    if code != 0:
        sys.exit(f"first_render: fovjax render failed ({code}):\n" + "\n".join(t for _, t in lines[-20:]))
    lines.sort(key=lambda item: item[0])

    def when(pattern: str) -> float | None:
        return next((t for t, text in lines if re.search(pattern, text)), None)

    phases = {}
    for name, begins, end in PHASES:
        found = [when(begin) for begin in begins]
        t0 = max((t for t in found if t is not None), default=None) if begins else 0.0
        t1 = when(end)
        if t0 is not None and t1 is not None and t1 >= t0:
            phases[name] = round(t1 - t0, 2)
    text = "\n".join(t for _, t in lines)
    compiles = [float(x) for x in re.findall(r"compile (\d+(?:\.\d+)?) s", text)]
    renders = [float(x) for x in re.findall(r"rays in (\d+(?:\.\d+)?) s", text)]
    built = re.search(r"native handlers built in (\d+(?:\.\d+)?) s", text)
    bvh = re.search(r"BVH built in (\d+(?:\.\d+)?) s", text)
    return {
        "first_image_s": round(out.stat().st_mtime - start_wall, 2),
        "total_s": round(total, 2),
        "phases": phases,
        "handler_build_s": float(built.group(1)) if built else None,
        "bvh_s": float(bvh.group(1)) if bvh else None,
        "compile_s": compiles,
        "render_s": renders,
        "load_before": load,
        "lines": [[round(t, 2), line] for t, line in lines],
    }


THIS_TREE = "this tree"
PREBUILT = "handlers built"
LATER = "later run"


def _say(name: str, result: dict) -> None:
    print(
        f"{name}: first image {result['first_image_s']:.1f} s, total {result['total_s']:.1f} s "
        f"(load average before {result['load_before']})",
        flush=True,
    )


def prebuild(cache: Path) -> Path:
    """Build this tree's native handlers into `cache`/native (what an install that built them
    would leave) and return that folder."""
    env = dict(os.environ, FOVJAX_CACHE_DIR=str(cache), PYTHONPATH=str(REPO))
    env.pop("FOVJAX_NATIVE_DIR", None)
    code = "from fovjax.native import status; found = status(); print(found.reason); assert found"
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(
            f"first_render --prebuilt: the native handlers did not build:\n{done.stdout}{done.stderr[-2000:]}"
        )
    return cache / "native"


def export(revision: str, folder: Path) -> Path:
    """`revision`'s tree (git archive) in `folder`, to run its fovjax from there."""
    folder.mkdir(parents=True)
    archive = subprocess.run(["git", "archive", revision], cwd=REPO, capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive.stdout, check=True)
    return folder


def _median(values):
    values = [v for v in values if v is not None]
    return round(statistics.median(values), 2) if values else None


def summary(name: str, runs: list[dict]) -> list[list]:
    """Rows of the table (phase, median s, each run's s) for one variant."""
    names = [p for p, _, _ in PHASES if any(p in r["phases"] for r in runs)]
    each = {phase: [r["phases"].get(phase) for r in runs] for phase in names}
    each["handler build (in the background)"] = [r["handler_build_s"] for r in runs]
    for i, frame in enumerate(("foveated", "full")):
        # the compile seconds the command printed (tracing, lowering, XLA or the cache's load)
        each[f"{frame} program's compile"] = [
            r["compile_s"][i] if len(r["compile_s"]) > i else None for r in runs
        ]
    each["first image"] = [r["first_image_s"] for r in runs]
    each["total"] = [r["total_s"] for r in runs]
    return [
        [name, phase, _median(values), ", ".join("-" if v is None else f"{v:.1f}" for v in values)]
        for phase, values in each.items()
        if any(v is not None for v in values)
    ]


# -- --check-frames: the handlers' two builds, bit for bit --------------------------------------
def frames_child(build: str, folder: Path, frames: int) -> None:
    """In a fresh cache: build the handlers `build` ("parallel" or "plain"), render the atrium's
    full and foveated frames, save them, time them; print one RESULT line."""
    import numpy as np

    from fovjax.native import _library

    if build == "plain":
        _library.PARALLEL_FLAGS = ()
    compiler = _library._compiler()
    choice = _library._choices(compiler)[0] if compiler else ()
    if build == "parallel" and _library.PARALLEL_FLAGS and not set(_library.PARALLEL_FLAGS) <= set(choice):
        print(RESULT + json.dumps({"skipped": f"{compiler} takes no parallel build"}), flush=True)
        return
    t0 = time.perf_counter()
    found = _library.status()
    build_s = time.perf_counter() - t0
    if not found:
        sys.exit(f"first_render --check-frames: the native handlers are unavailable: {found.reason}")
    import jax

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _processes import GAZE, atrium_renderer

    renderer = atrium_renderer((1280, 1024))
    key = jax.random.key(3)
    result = {"build_s": round(build_s, 2), "flags": list(choice), "library": found.library}
    for name, render in (
        ("full", lambda: renderer.render_full(key=key)),
        ("foveated", lambda: renderer.render(GAZE, key=key)),
    ):
        np.save(folder / f"{name}.npy", np.asarray(render().image))
        times, cpu = [], []
        for _ in range(frames):
            t0, c0 = time.perf_counter(), time.process_time()
            jax.block_until_ready(render().image)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)  # every thread's: steadier on a shared machine
        result[f"{name}_ms"] = round(1000 * statistics.median(times), 1)
        result[f"{name}_cpu_ms"] = round(1000 * statistics.median(cpu), 1)
    print(RESULT + json.dumps(result), flush=True)


def check_frames(frames: int, rounds: int) -> dict:
    import numpy as np

    results: dict[str, list[dict]] = {"parallel": [], "plain": []}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(rounds):
            order = ("parallel", "plain") if i % 2 == 0 else ("plain", "parallel")
            for build in order:
                folder = Path(tmp) / f"{build}-{i}"
                folder.mkdir()
                env = dict(os.environ, FOVJAX_CACHE_DIR=str(folder / "cache"), FOVJAX_COMPILE_CACHE="0")
                env.pop("FOVJAX_NATIVE_DIR", None)
                argv = ["--child-frames", build, "--child-folder", str(folder), "--frames", str(frames)]
                done = subprocess.run(
                    [sys.executable, __file__, *argv], cwd=REPO, env=env, capture_output=True, text=True
                )
                found = [ln for ln in done.stdout.splitlines() if ln.startswith(RESULT)]
                if done.returncode != 0 or not found:
                    sys.exit(
                        f"first_render --check-frames: the {build} build's process failed:\n"
                        + done.stderr[-3000:]
                    )
                result = json.loads(found[-1][len(RESULT) :])
                if "skipped" in result:
                    return {"skipped": result["skipped"]}
                result["folder"] = str(folder)
                results[build].append(result)
        same = {}
        for name in ("full", "foveated"):
            images = [np.load(Path(r["folder"]) / f"{name}.npy") for b in results for r in results[b]]
            same[name] = all(np.array_equal(images[0], image) for image in images[1:])
    rows = [
        [
            build,
            " ".join(runs[0]["flags"]),
            _median([r["build_s"] for r in runs]),
            _median([r["full_ms"] for r in runs]),
            _median([r["foveated_ms"] for r in runs]),
            _median([r["full_cpu_ms"] for r in runs]),
            _median([r["foveated_cpu_ms"] for r in runs]),
        ]
        for build, runs in results.items()
    ]
    return {"rows": rows, "bit_for_bit": same}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="fresh-cache runs per variant (default 3)")
    ap.add_argument("--baseline", default=None, metavar="REV", help="also run this git revision's command")
    ap.add_argument(
        "--prebuilt",
        action="store_true",
        help="also run this tree with the native handlers already in the (otherwise empty) cache",
    )
    ap.add_argument("--check-frames", action="store_true", help="compare the handlers' two builds instead")
    ap.add_argument("--frames", type=int, default=3, help="--check-frames: timed frames of each kind")
    ap.add_argument("--args", nargs=argparse.REMAINDER, default=[], help="arguments of `fovjax render`")
    ap.add_argument("--child-frames", choices=("parallel", "plain"), help=argparse.SUPPRESS)
    ap.add_argument("--child-folder", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.repeats < 1 or args.frames < 1:
        ap.error(f"--repeats and --frames must be at least 1, got {args.repeats} and {args.frames}")
    if args.child_frames:
        frames_child(args.child_frames, Path(args.child_folder), args.frames)
        return 0
    if args.check_frames:
        found = check_frames(args.frames, args.repeats)
        if "skipped" in found:
            print(f"first_render --check-frames: {found['skipped']}; nothing to compare")
            return 0
        print(
            f"the handlers built two ways, atrium 2 x 1280x1024 (medians of {args.repeats} processes each):"
        )
        for build, flags, build_s, full_ms, foveated_ms, full_cpu, foveated_cpu in found["rows"]:
            print(
                f"  {build:8s} build {build_s:5.1f} s; full {full_ms:6.1f} ms ({full_cpu:6.1f} ms of CPU), "
                f"foveated {foveated_ms:6.1f} ms ({foveated_cpu:6.1f} ms of CPU)  [{flags}]"
            )
        print(f"bit for bit the same images: {found['bit_for_bit']}; load average {_load()}")
        table = {
            "title": "The native handlers built two ways (GCC's parallel link-time back end; the plain "
            "unity build): build seconds and the atrium's frames, 2 x 1280x1024 SPP 1, ms (wall, and "
            "CPU time of every thread)",
            "columns": [
                "build",
                "flags",
                "build s",
                "full ms",
                "foveated ms",
                "full CPU ms",
                "foveated CPU ms",
            ],
            "rows": found["rows"],
        }
        write_record(
            "first_render",
            {"tables": [table], "bit_for_bit": found["bit_for_bit"]},
            note=f"images equal bit for bit: {found['bit_for_bit']}; the machine was shared with other "
            f"work (load average {_load()} at the end)",
        )
        return 0
    variants = {THIS_TREE: REPO}
    runs: dict[str, list[dict]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        handlers = {}
        if args.baseline:
            variants = {args.baseline: export(args.baseline, tmp / "baseline"), **variants}
        if args.prebuilt:
            variants[PREBUILT] = REPO
            handlers[PREBUILT] = prebuild(tmp / "prebuilt")
        for i in range(args.repeats):
            order = list(variants) if i % 2 == 0 else list(reversed(variants))
            for name in order:
                folder = tmp / f"run-{i}-{list(variants).index(name)}"
                folder.mkdir()
                result = run_once(variants[name], args.args, folder, handlers.get(name))
                runs.setdefault(name, []).append(result)
                _say(name, result)
                if name == THIS_TREE:  # again with what the first run left in the cache
                    result = run_once(REPO, args.args, folder)
                    runs.setdefault(LATER, []).append(result)
                    _say(LATER, result)
    rows = [row for name in [*variants, LATER] for row in summary(name, runs[name])]
    command = " ".join(["fovjax render", *args.args])
    print(f"\n{command}, a fresh cache each run; medians of {args.repeats} (each run's figure after):")
    for name, phase, median, each in rows:
        print(f"  {name:14s} {phase:36s} {'-' if median is None else f'{median:6.1f}'} s   [{each}]")
    print(f"load average now {_load()}; the machine is shared, so the figures vary run to run")
    table = {
        "title": f"`{command}` from an empty cache (a fresh clone): seconds, median of {args.repeats} runs",
        "columns": ["tree", "phase", "median s", "each run s"],
        "rows": rows,
    }
    loads = [r["load_before"] for name in runs for r in runs[name]]
    write_record(
        "first_render",
        {"tables": [table], "runs": runs},
        note=f"The machine was shared with other work: load averages before the runs {loads} "
        f"(on {os.cpu_count()} cores).",
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
