"""Each foveation method's frame time over the thesis method's, frame by frame in turn.

    python benchmarks/methods_frame.py                       # atrium 2 x 640x512, SPP 1, 16 frames
    python benchmarks/methods_frame.py --size 1280 1024 --frames 8

`benchmarks/compare_video.py` renders each method's frames one method after another, so a
change of the shared machine's load between methods moves their ratios; here every method
renders frame k (the same gaze, moving slowly to the right, and key) before any renders frame
k + 1, so each ratio compares frames made under the same load. One `FoveatedRenderer` per
method (depth 5, 5°/10°), its program compiled first (its compile seconds reported); the
ratios are of the medians. Writes a record (benchmarks/results/methods_frame-*.json).
"""

from __future__ import annotations

import argparse
import statistics

import jax
from _record import write_record

import fovjax
from fovjax.foveate import Foveation
from fovjax.render import RenderConfig, StereoRig

METHODS = ("thesis", "guenter2012", "patney2016", "weier2016")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, nargs=2, default=(640, 512), metavar=("W", "H"))
    p.add_argument("--frames", type=int, default=16)
    p.add_argument("--max-depth", type=int, default=5)
    args = p.parse_args()
    if args.frames < 1 or min(args.size) < 8:
        p.error(f"--frames must be positive and --size at least 8 x 8, got {args.frames}, {args.size}")
    w, h = args.size
    scene = fovjax.scenes.atrium()
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=w, eye_height=h)
    base = fovjax.FoveatedRenderer(scene, rig, config=RenderConfig(max_depth=args.max_depth))
    gazes = [((0.45 + 0.005 * k, 0.5), (0.42 + 0.005 * k, 0.5)) for k in range(args.frames + 1)]
    renderers, compile_s, ms = {}, {}, {m: [] for m in METHODS}
    for method in METHODS:
        r = base.with_foveation(Foveation(method=method, fovea_deg=5.0, periphery_deg=10.0), diagnostics=())
        r.reset_history()
        compile_s[method] = r.render(gazes[0], key=jax.random.key(0)).stats.compile_seconds
        renderers[method] = r
    for k in range(1, args.frames + 1):
        for method, r in renderers.items():
            ms[method].append(1000 * r.render(gazes[k], key=jax.random.key(k)).stats.render_seconds)
    thesis = statistics.median(ms["thesis"])
    rows = []
    for method in METHODS:
        median = statistics.median(ms[method])
        rows.append([method, round(median, 1), round(median / thesis, 2), round(compile_s[method], 2)])
        ratio, seconds = median / thesis, compile_s[method]
        print(f"{method:12s} {median:7.1f} ms  {ratio:5.2f} x thesis  compile {seconds:.2f} s")
    write_record(
        "methods_frame",
        {
            "tables": [
                {
                    "title": f"Foveation methods, atrium 2 × {w}×{h}, SPP 1, depth {args.max_depth}, 5°/10°, "
                    f"{args.frames} frames, the methods in turn per frame (median ms; ratio to the thesis's)",
                    "columns": ["method", "ms/frame", "/ thesis", "compile s"],
                    "rows": rows,
                }
            ],
            "ms": ms,
            "compile_s": compile_s,
        },
        note="CPU only (2 shared cores); the methods render each frame in turn, so read the ratios",
    )


if __name__ == "__main__":
    main()
