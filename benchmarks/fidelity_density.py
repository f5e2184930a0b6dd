"""Sub-samples traded for pixel density outside the fovea, against plain foveation, same run:
FLIP against the full render and ms per frame.

    python benchmarks/fidelity_density.py                       # atrium 262k, 2 x 640x512, SPP 4
    python benchmarks/fidelity_density.py --width 320 --height 256

At SPP 4 plain foveation (thesis pair 0, blocks 2/4 px, the "either" rule) traces every
sub-sample of each block's top-left pixel. `Fidelity(spp=1)` in the periphery and outside keeps
one sub-sample per pixel there; with smaller `Foveation.blocks` the freed rays go to more
top-left pixels instead, which the fill pass reconstructs from. Configurations (all with the
fovea at full fidelity or depth 1, as named): plain foveation; the plan `plan_fidelity` found at
2 x 640x512 (depth 1, periphery and outside 1 SPP); blocks (2, 2) and (1, 3) with periphery and
outside at 1 SPP. Each is judged over gazes x keys (FLIP at the display's pixels per degree
against the full render of the same key, mean and 95% interval over the frames), then all are
rendered in turn over the frames `--repeats` times (compile excluded) and the median ms per
frame is printed with the ratio to plain's. The machine is noisy: read the same-run ratio.
Blocks are a `Foveation` field (sampling density), not a `Fidelity` one: `plan_fidelity` does
not search them.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics

import jax
import numpy as np
from _record import write_record

import fovjax
from fovjax.eval._plan import _interval, _Judge  # the planner's own judge: same frames, same FLIP
from fovjax.foveate import Fidelity, Foveation
from fovjax.render import RenderConfig, StereoRig, render_stereo
from fovjax.trace import build_bvh

GAZES = ((0.35, 0.45), (0.3, 0.4), (0.7, 0.65))


def configurations(spp: int) -> dict:
    base = Foveation.thesis(0, spp=spp)
    d1, one = Fidelity(max_depth=1), Fidelity(spp=1)
    d1_one = Fidelity(max_depth=1, spp=1)
    return {
        "plain foveation, blocks (2, 4)": base,
        "plan: d1 | d1 1spp | d1 1spp": dataclasses.replace(base, fidelity=(d1, d1_one, d1_one)),
        "blocks (2, 2): full | 1spp | 1spp": dataclasses.replace(
            base, blocks=(2, 2), fidelity=(Fidelity(), one, one)
        ),
        "blocks (1, 3): full | 1spp | 1spp": dataclasses.replace(
            base, blocks=(1, 3), fidelity=(Fidelity(), one, one)
        ),
        "blocks (1, 3): d1 | d1 1spp | d1 1spp": dataclasses.replace(
            base, blocks=(1, 3), fidelity=(d1, d1_one, d1_one)
        ),
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triangles", type=int, default=262_000)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=512)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--keys", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument(
        "--only", type=int, nargs="+", default=None, help="indices of configurations (0: plain, kept)"
    )
    args = ap.parse_args(argv)
    scene = fovjax.scenes.atrium(triangles=args.triangles)
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(scene), eye_width=args.width, eye_height=args.height
    )
    config, bvh = RenderConfig(), build_bvh(scene)
    configs = configurations(args.spp)  # bad blocks fail here, before any rendering
    if args.only is not None:
        names = list(configs)
        if any(not 0 <= i < len(names) for i in args.only):
            ap.error(f"--only: indices in [0, {len(names) - 1}], got {args.only}")
        configs = {n: configs[n] for i, n in enumerate(names) if i == 0 or i in args.only}
    with open("/proc/loadavg") as fh:
        load = " ".join(fh.read().split()[:3])
    print(
        f"atrium {args.triangles} triangles, 2 x {args.width}x{args.height}, SPP {args.spp}, thesis 5°/10°, "
        f"gazes {GAZES} x keys {args.keys}; load average {load}"
    )
    references = {
        k: render_stereo(scene, rig, spp=args.spp, key=jax.random.key(k), config=config, bvh=bvh).image
        for k in args.keys
    }
    frames = [(np.array([g, g], np.float32), k) for g in GAZES for k in args.keys]
    judge = _Judge(scene, rig, config, frames, references, "flip", bvh, {})
    print(f"{'configuration':40} {'FLIP mean [95%]':>26} {'rays/frame':>11}")
    judged = {}
    for name, foveation in configs.items():
        ev = judge(foveation)
        m = _interval(ev.metric)
        judged[name] = (f"{m[0]:.4f} [{m[1]:.4f}, {m[2]:.4f}]", round(statistics.mean(ev.rays)))
        print(f"{name:40} {m[0]:.4f} [{m[1]:.4f}, {m[2]:.4f}] {statistics.mean(ev.rays):>11,.0f}", flush=True)
    times: dict = {name: [] for name in configs}
    for _ in range(args.repeats):
        for gaze, key in frames:
            for name, foveation in configs.items():
                times[name].append(judge.render(foveation, gaze, key).stats.render_seconds)
    plain = statistics.median(times["plain foveation, blocks (2, 4)"])
    rows = []
    for name in configs:
        t = statistics.median(times[name])
        print(f"{name:40} {1e3 * t:8.0f} ms/frame  {plain / t:.2f}x plain's speed")
        rows.append([name, judged[name][0], judged[name][1], round(1e3 * t, 1), round(plain / t, 3)])
    with open("/proc/loadavg") as fh:
        end_load = " ".join(fh.read().split()[:3])
        print(f"load average at the end: {end_load}")
    title = (
        f"atrium {args.triangles} triangles, 2×{args.width}×{args.height}, SPP {args.spp}, thesis 5°/10°, "
        f"gazes {GAZES} × keys {args.keys}, {args.repeats} repeats"
    )
    cols = ["configuration", "FLIP mean [95%]", "rays / frame", "ms / frame", "vs plain"]
    write_record(
        "fidelity_density",
        {"tables": [{"title": title, "columns": cols, "rows": rows}]},
        note=f"load average at the start {load}, at the end {end_load}",
    )


if __name__ == "__main__":
    main()
