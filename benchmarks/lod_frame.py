"""What geometry level of detail buys a foveated frame, and what it could buy at most: plain
foveation against the same frame with the periphery and outside traced on a coarser level,
same run, frames alternating, medians.

    python benchmarks/lod_frame.py                         # 2 x 640x512, SPP 1, levels 1 2 3
    python benchmarks/lod_frame.py --levels 2 --repeats 3

Rows (all at SPP 1 on the 262k atrium, thesis pair 0, gazes as benchmarks/plan_fidelity.py):
plain foveation; reflection depth 1 everywhere (the SPP-1 plan without level of detail);
depth 1 with `Fidelity(lod=k)` in the periphery and outside for each `--levels` k (the levels
of `fovjax.scene.lod_levels`, decimated and cached); and a **ceiling**: depth 1 with the
periphery and outside traced on `atrium(triangles=min_triangles())`, the atrium built at its
coarsest tessellation (every flat face two triangles, ~7.6k triangles), passed as a level of
detail. That stand-in is not a decimation of the scene (its curved parts differ by up to
centimetres, its floor is one material), so its images are not a valid plan; it bounds what any
decimation to well-shaped triangles could save per ray on this tracer. Prints ms per frame (median
over --repeats x gazes, compile excluded), the ratio to plain, rays per frame, and mean
|difference| from the plain frame outside the fovea.
"""

from __future__ import annotations

import argparse
import statistics

import jax
import numpy as np
from _record import write_record

import fovjax
from fovjax.foveate import Fidelity, Foveation, render_foveated
from fovjax.render import RenderConfig, StereoRig
from fovjax.scene import LODLevels, lod_levels
from fovjax.scene._atrium import min_triangles

GAZES = ((0.35, 0.45), (0.3, 0.4), (0.7, 0.65))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=512)
    ap.add_argument("--levels", type=int, nargs="*", default=[1, 2, 3])
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args(argv)
    scene = fovjax.scenes.atrium(262_000)
    levels = lod_levels(scene)
    ideal = fovjax.scenes.atrium(triangles=min_triangles())
    with_ideal = LODLevels(
        scenes=(*levels.scenes, ideal),
        ratios=(*levels.ratios, ideal.num_triangles / scene.num_triangles),
        errors=(*levels.errors, float("inf")),
        triangles=(*levels.triangles, ideal.num_triangles),
    )
    print(f"levels: triangles {levels.triangles}, error (m) {tuple(round(e, 4) for e in levels.errors)}")
    print(f"ceiling stand-in: atrium({ideal.num_triangles}) as level {len(levels)}")
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(scene), eye_width=args.width, eye_height=args.height
    )
    config = RenderConfig()

    def d1(**k):
        return Fidelity(max_depth=1, **k)

    configs = {
        "plain": Foveation.thesis(0, spp=1),
        "depth 1": Foveation.thesis(0, spp=1, fidelity=(d1(),) * 3),
    }
    for k in args.levels:
        configs[f"depth 1, lod {k} P+O"] = Foveation.thesis(0, spp=1, fidelity=(d1(), d1(lod=k), d1(lod=k)))
    configs["depth 1, ceiling P+O"] = Foveation.thesis(
        0, spp=1, fidelity=(d1(), d1(lod=len(levels)), d1(lod=len(levels)))
    )

    def frame(f, gaze, key):
        return render_foveated(
            scene, rig, gaze=(gaze, gaze), foveation=f, key=jax.random.key(key), config=config,
            lod_levels=with_ideal,
        )  # fmt: skip

    first = {name: frame(f, GAZES[0], 0) for name, f in configs.items()}  # compiles
    times = {name: [] for name in configs}
    for r in range(args.repeats):
        for gaze in GAZES:
            for name, f in configs.items():
                times[name].append(frame(f, gaze, r + 1).stats.render_seconds)
    plain = statistics.median(times["plain"])
    outside = np.concatenate([first["plain"].regions[0], first["plain"].regions[1]], axis=1) > 0
    print(f"2 x {args.width}x{args.height}, SPP 1, {args.repeats} x {len(GAZES)} frames each, alternating")
    print(f"{'configuration':24} {'ms':>8} {'vs plain':>9} {'rays':>9} {'|diff| P+O':>11}")
    rows = []
    for name in configs:
        ms = statistics.median(times[name])
        diff = np.abs(first[name].image - first["plain"].image).mean(axis=-1)[outside].mean()
        print(f"{name:24} {1e3 * ms:8.1f} {plain / ms:8.2f}x {first[name].stats.rays:9,} {diff:11.4f}")
        rows.append(
            [name, round(1e3 * ms, 1), round(plain / ms, 3), first[name].stats.rays, round(float(diff), 5)]
        )
    with open("/proc/loadavg") as f:
        print(f"load average: {f.read().strip()}")
    title = (
        f"Geometry LOD in a frame: 2×{args.width}×{args.height}, SPP 1, {args.repeats} × {len(GAZES)} frames "
        "each, alternating, median ms"
    )
    cols = ["configuration", "ms", "vs plain", "rays", "|diff| P+O"]
    write_record(
        "lod_frame",
        {
            "tables": [{"title": title, "columns": cols, "rows": rows}],
            "levels_triangles": list(levels.triangles),
            "levels_error_m": [round(e, 5) for e in levels.errors],
        },
    )


if __name__ == "__main__":
    main()
