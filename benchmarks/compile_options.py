"""Frame programs compiled two ways, in alternating processes:

- `--compare emitters` (the default): XLA:CPU's fusion emitters (XLA's default) and its loop
  emitters (`fovjax.render.internal.LOOP_EMITTERS`, fovjax's choice for every frame program);
  FOVJAX_XLA_EMITTERS=fusion or =loop selects them.
- `--compare branches`: `backend="auto"` tracing a branch per platform it may lower for, CPU's
  and CUDA's (fovjax's default where JAX sees no other platform), and with the JAX traversal's
  branch for other platforms too (FOVJAX_AUTO_OTHER_PLATFORMS=1); only the CPU branch is
  compiled either way, so the frames are the same program and only tracing differs.

    python benchmarks/compile_options.py                   # the atrium, 2 x 1280x1024, SPP 1
    python benchmarks/compile_options.py --compare branches --rounds 4
    python benchmarks/compile_options.py --rounds 3 --size 64 48

Each process builds one `FoveatedRenderer` (the atrium, max depth 5, SPP 1) and, for the full
frame and the foveated 5°/10° frame at an off-centre gaze, compiles the program (compile
seconds: tracing, lowering and XLA, with the on-disk compile cache off), then times `--repeats`
frames. Printed per variant: median compile seconds and ms per frame, the ratios of fovjax's
choice to the other (< 1: faster), and how far the two variants' images are apart (the emitters
round some sums differently). Writes a record.
"""

from __future__ import annotations

import argparse
import os
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

# --compare: (the other variant, fovjax's choice), each with the environment that selects it.
COMPARISONS = {
    "emitters": {
        "fusion emitters": {"FOVJAX_XLA_EMITTERS": "fusion"},
        "loop emitters": {"FOVJAX_XLA_EMITTERS": "loop"},
    },
    "branches": {
        "+ JAX branch": {"FOVJAX_AUTO_OTHER_PLATFORMS": "1"},
        "CPU, CUDA": {"FOVJAX_AUTO_OTHER_PLATFORMS": "0"},
    },
}
SLUGS = {
    "fusion emitters": "fusion",
    "loop emitters": "loop",
    "+ JAX branch": "jax_branch",
    "CPU, CUDA": "cpu_cuda",
}
TITLES = {
    "emitters": "XLA:CPU's fusion emitters (XLA's default) and loop emitters (fovjax's frame programs)",
    "branches": (
        "\"auto\" tracing the CPU and CUDA branches (fovjax's default) and the JAX traversal's "
        "branch for other platforms too"
    ),
}


def child(args) -> None:
    """One process: compile each frame once, then time it `repeats` times; print one JSON line."""
    import jax
    import numpy as np

    from fovjax.render.internal import frame_compiler_options

    renderer, gaze = atrium_renderer(args.size), GAZE
    key = jax.random.key(3)
    frames = {
        "full": lambda: renderer.render_full(key=key),
        "foveated": lambda: renderer.render(gaze, key=key),
    }
    out = {}
    for name, render in frames.items():
        first = render()
        np.save(Path(args.child) / f"{name}.npy", np.asarray(first.image))
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            jax.block_until_ready(render().image)
            times.append(time.perf_counter() - t0)
        out[name] = [first.stats.compile_seconds, statistics.median(times)]
    options = {
        name: frame_compiler_options(entry) for name, entry in (("full", "stereo"), ("foveated", "foveated"))
    }
    print_result({"options": options, "frames": out})


def run_variant(name: str, args, folder: Path) -> dict:
    env = dict(os.environ, **COMPARISONS[args.compare][name], FOVJAX_COMPILE_CACHE="0")
    argv = ["--child", str(folder), "--repeats", str(args.repeats), "--size", *map(str, args.size)]
    return run_measuring_process("compile_options", __file__, argv, env)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(ap, repeats=5)
    ap.add_argument("--compare", choices=sorted(COMPARISONS), default="emitters", help="what to compare")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    check_arguments(ap, args)
    if args.child:
        child(args)
        return
    import numpy as np

    names = list(COMPARISONS[args.compare])
    other, chosen = names
    runs = {name: [] for name in names}
    with tempfile.TemporaryDirectory() as tmp:
        folders = {name: Path(tmp) / name.replace(" ", "_") for name in names}
        for folder in folders.values():
            folder.mkdir()
        for r in range(args.rounds):
            for name in names if r % 2 == 0 else names[::-1]:
                result = run_variant(name, args, folders[name])
                runs[name].append(result["frames"])
                f = result["frames"]
                print(
                    f"round {r + 1} {name:15s} full compile "
                    f"{f['full'][0]:.2f} s, {1e3 * f['full'][1]:.0f} ms; foveated compile "
                    f"{f['foveated'][0]:.2f} s, {1e3 * f['foveated'][1]:.0f} ms",
                    flush=True,
                )
        images = {
            frame: [np.load(folders[name] / f"{frame}.npy") for name in names]
            for frame in ("full", "foveated")
        }
    w, h = args.size
    rows, figures = [], {}
    for frame in ("full", "foveated"):
        med = {
            name: [statistics.median(run[frame][i] for run in runs[name]) for i in range(2)] for name in names
        }
        a, b = images[frame]
        diff = np.abs(a.astype(np.float64) - b.astype(np.float64))
        for name in names:
            rows.append([frame, name, round(med[name][0], 2), round(1e3 * med[name][1], 1)])
        figures[f"{frame}_compile_ratio"] = round(med[chosen][0] / med[other][0], 3)
        figures[f"{frame}_frame_ratio"] = round(med[chosen][1] / med[other][1], 3)
        for name in names:
            figures[f"{frame}_{SLUGS[name]}_compile_s"] = round(med[name][0], 2)
        figures[f"{frame}_image_max_abs_diff"] = float(f"{diff.max():.3g}")
        figures[f"{frame}_image_values_differing"] = round(float(np.mean(diff > 0)), 4)
    print(f"\n2 x {w}x{h}, SPP 1, the atrium; medians over {args.rounds} processes x {args.repeats} frames")
    print(f"  {'frame':9s} {'variant':15s} {'compile s':>9s} {'ms/frame':>9s}")
    for row in rows:
        print(f"  {row[0]:9s} {row[1]:15s} {row[2]:9.2f} {row[3]:9.1f}")
    for frame in ("full", "foveated"):
        print(
            f"  {frame}: {chosen} / {other}: compile {figures[f'{frame}_compile_ratio']:.3f}, "
            f"frame {figures[f'{frame}_frame_ratio']:.3f}; images: max |difference| "
            f"{figures[f'{frame}_image_max_abs_diff']:.3g}, values differing "
            f"{figures[f'{frame}_image_values_differing']:.4f}"
        )
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _record import write_record

    figures["tables"] = [
        {
            "title": (
                f"{TITLES[args.compare]}: "
                f"the atrium, 2 x {w}x{h}, SPP 1, full and foveated 5°/10° frames; medians of "
                f"{args.rounds} processes per variant, {args.repeats} frames each"
            ),
            "columns": ["frame", "variant", "compile s", "ms per frame"],
            "rows": rows,
        }
    ]
    figures["compare"] = args.compare
    write_record("compile_options", figures)


if __name__ == "__main__":
    main()
