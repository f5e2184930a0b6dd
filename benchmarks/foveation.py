"""The thesis's tables 2-5 re-measured: rays per frame and frame rate, foveated against full.

    python benchmarks/foveation.py                 # 640x512 per eye (a quarter of the pixels)
    python benchmarks/foveation.py --full          # the thesis's 2 x 1280x1024
    python benchmarks/foveation.py --spp 1 4       # a subset of SPP values
    python benchmarks/foveation.py --backend embree

For every SPP and every thesis (fovea, periphery) pair plus full rendering, on the atrium, in
stereo, gaze at each display's centre, head still: rays per frame (primary + shadow +
reflection rays actually traced), its reduction against full, frames per second (median of
--repeats timed frames after a warm-up, each with a fresh key) and the speed-up, printed in the
layout of the thesis's tables with the thesis's own figures beside ours. Compile time is
reported separately and is not in the frame times. The machine is noisy: read the ratios.
"""

from __future__ import annotations

import argparse
import statistics
import sys

import jax
import numpy as np

import fovjax
from fovjax.foveate import THESIS_PAIRS, Foveation, render_foveated
from fovjax.render import RenderConfig, StereoRig, render_stereo
from fovjax.trace import build_bvh

SPPS = (1, 4, 9, 16)
# Thesis tables 2 and 4 (Sponza, RTX 2060, OptiX, 2560x1024): rays per frame (1e6) and FPS.
THESIS_RPF = {
    (5.0, 10.0): (4.47, 5.47, 7.13, 9.46),
    (7.5, 15.0): (4.49, 6.74, 10.48, 15.71),
    (10.0, 20.0): (4.52, 8.53, 15.20, 24.54),
    (12.5, 25.0): (4.56, 10.76, 21.09, 35.55),
    (15.0, 30.0): (4.60, 13.11, 27.30, 47.17),
    "full": (5.21, 20.85, 46.91, 83.39),
}
THESIS_FPS = {
    (5.0, 10.0): (60.16, 57.84, 53.79, 48.15),
    (7.5, 15.0): (59.98, 54.02, 46.22, 39.40),
    (10.0, 20.0): (59.74, 50.27, 40.29, 31.57),
    (12.5, 25.0): (59.07, 48.39, 34.29, 25.11),
    (15.0, 30.0): (58.64, 47.26, 28.90, 19.84),
    "full": (103.88, 26.12, 17.24, 10.05),
}


def measure(render, repeats):
    frames = [render(jax.random.key(10_000))]  # warm-up (and compile)
    compile_s = frames[0].stats.compile_seconds
    times = []
    for i in range(repeats):
        frame = render(jax.random.key(i))
        times.append(frame.stats.render_seconds)
        frames.append(frame)
    rays = statistics.median(f.stats.rays for f in frames[1:])
    return rays, statistics.median(times), compile_s, frames[-1]


def speedup(ratio):
    return f"{pct((ratio - 1) * 100)} {ratio:4.1f}x"


def pct(x):
    return f"{x:+7.1f}%"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="2 x 1280x1024 (default: 2 x 640x512)")
    ap.add_argument("--spp", type=int, nargs="+", default=list(SPPS))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--backend", choices=("jax", "embree"), default="jax")
    ap.add_argument("--max-depth", type=int, default=5)
    args = ap.parse_args(argv)
    w, h = (1280, 1024) if args.full else (640, 512)
    scene = fovjax.scenes.atrium()
    bvh = build_bvh(scene)
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=w, eye_height=h)
    config = RenderConfig(max_depth=args.max_depth, backend=args.backend)
    gaze = ((0.5, 0.5), (0.5, 0.5))
    print(
        f"atrium {scene.num_triangles:,} triangles, stereo 2 x {w}x{h}, gaze at the display centres, "
        f"backend {args.backend}, max depth {args.max_depth}, "
        f"jax {jax.__version__} on {jax.devices()[0].platform}"
    )
    results = {}
    for spp in args.spp:
        rays, t, c, _ = measure(
            lambda k, spp=spp: render_stereo(scene, rig, spp=spp, key=k, config=config, bvh=bvh), args.repeats
        )
        results["full", spp] = (rays, t)
        print(
            f"  full          spp {spp:2d}: {rays / 1e6:7.3f} M rays  {1 / t:7.3f} fps  (compile {c:.1f} s)"
        )
        sys.stdout.flush()
        for pair in THESIS_PAIRS:
            f = Foveation.thesis(pair, spp=spp)
            rays, t, c, frame = measure(
                lambda k, f=f: render_foveated(
                    scene, rig, gaze=gaze, foveation=f, key=k, config=config, bvh=bvh
                ),
                args.repeats,
            )
            results[pair, spp] = (rays, t)
            fs = frame.foveation
            print(
                f"  {pair[0]:4.1f}/{pair[1]:4.1f}     spp {spp:2d}: "
                f"{rays / 1e6:7.3f} M rays  {1 / t:7.3f} fps  "
                f"(compile {c:.1f} s; primary by region {fs.primary_by_region}, budget {fs.budget:,}, "
                f"padding {fs.padding:,}, dropped {fs.dropped})"
            )
            sys.stdout.flush()

    rows = [*THESIS_PAIRS, "full"]

    def name(p):
        return "Full        " if p == "full" else f"{p[0]:4.1f}° {p[1]:4.1f}° "

    def table(title, cell, thesis=None):
        print(f"\n{title}")
        print("Foveal/Periph " + "".join(f"{'SPP ' + str(s):>24s}" for s in args.spp))
        print("              " + "".join(f"{'ours':>12s}{'thesis':>12s}" for _ in args.spp))
        for p in rows:
            cells = []
            for s in args.spp:
                ours = cell(p, s)
                theirs = thesis(p, s) if thesis else ""
                cells.append(f"{ours:>12s}{theirs:>12s}")
            print(name(p) + "  " + "".join(cells))

    idx = {s: SPPS.index(s) for s in args.spp}
    table(
        "Table 2: rays per frame (x 10^6)",
        lambda p, s: f"{results[p, s][0] / 1e6:.3f}",
        lambda p, s: f"{THESIS_RPF[p][idx[s]]:.2f}",
    )
    table(
        "Table 3: reduction of rays per frame (foveated / full - 1)",
        lambda p, s: pct((results[p, s][0] / results["full", s][0] - 1) * 100),
        lambda p, s: pct((THESIS_RPF[p][idx[s]] / THESIS_RPF["full"][idx[s]] - 1) * 100),
    )
    table(
        "Table 4: frames per second (median)",
        lambda p, s: f"{1 / results[p, s][1]:.3f}",
        lambda p, s: f"{THESIS_FPS[p][idx[s]]:.2f}",
    )
    table(
        "Table 5: speed-up in FPS (foveated / full - 1); x = ratio",
        lambda p, s: speedup(results["full", s][1] / results[p, s][1]),
        lambda p, s: pct((THESIS_FPS[p][idx[s]] / THESIS_FPS["full"][idx[s]] - 1) * 100),
    )
    return results


if __name__ == "__main__":
    np.set_printoptions(linewidth=200)
    main()
