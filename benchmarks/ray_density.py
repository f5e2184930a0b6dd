"""What ray density costs a tracer: ns per ray of full stereo frames at several resolutions, on
fovjax and on Mitsuba 3 in one run, beside the foveated frame's cost per ray.

    python benchmarks/ray_density.py                         # 1280x1024, 640x512, 320x256 per eye
    python benchmarks/ray_density.py --sizes 1280x1024 320x256 --repeats 5

A foveated frame traces its fovea densely and the rest of the screen sparsely (outside the
fovea, one traced pixel in 4 or 16 and a few more at random): a ray there lands among
neighbours a few pixels away, not next to them, so it shares less of the BVH and of the hit
triangles' data with the rays traced before it. The same scene rendered in full at a lower
resolution spreads the same sparsity over the whole screen, with no foveation code involved: its
cost per ray against the densest frame's is what sparser rays cost a tracer by itself — for
Mitsuba 3 (Embree's traversal, Dr.Jit's kernels) as for fovjax. The first size is the dense
reference; at that size the foveated frame (5°/10° at an off-centre gaze) is timed too, and its
cost per traced ray is compared with its full frame's (`benchmarks/foveation.py --speedup`'s
"cost per traced ray"). Each size runs `benchmarks/mitsuba_frame.py`'s frames (the same
scene, materials, light, rig, depth and samples on both renderers; PSNR printed), timed in
turn, median of `--repeats`. A frame's fixed costs (launches, per-frame set-up) are in its ns
per ray, a larger share of a small frame's. Writes a record (benchmarks/results/ray_density-*.json).
Needs the `[bench]` extra (Mitsuba 3) and a system libLLVM >= 16; without them it says so and
writes nothing.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from types import SimpleNamespace

import mitsuba_frame as mf


def _size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"(\d+)x(\d+)", text)
    if not m or int(m[1]) < 1 or int(m[2]) < 1:
        raise argparse.ArgumentTypeError(f"size {text!r}: expected WIDTHxHEIGHT per eye, e.g. 640x512")
    return int(m[1]), int(m[2])


def main(argv=None) -> dict | None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="atrium", help="a built-in scene (fovjax.scenes.BUILTIN)")
    ap.add_argument(
        "--sizes",
        type=_size,
        nargs="+",
        default=[(1280, 1024), (640, 512), (320, 256)],
        help="pixels per eye, WIDTHxHEIGHT, densest first (the reference)",
    )
    ap.add_argument("--spp", type=int, default=1)
    ap.add_argument("--max-depth", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--fovea", type=float, nargs=2, default=[5.0, 10.0], metavar=("FOVEA", "PERIPHERY"))
    args = ap.parse_args(argv)
    if args.repeats < 1 or args.max_depth < 0:
        ap.error("--repeats must be positive and --max-depth >= 0")
    if args.spp < 1 or round(args.spp**0.5) ** 2 != args.spp:
        ap.error(f"--spp {args.spp}: expected a positive square (1, 4, 9, ...), the samples' grid per pixel")

    try:
        mi, dr = mf.load_mitsuba()
    except mf.Unavailable as exc:
        print(f"ray_density: skipped: {exc}")
        return None

    import fovjax
    from fovjax.render import RenderConfig, StereoRig, scene_arrays
    from fovjax.render.internal import bvh_for, scene_scale

    config = RenderConfig(max_depth=args.max_depth)
    scene = fovjax.scenes.BUILTIN[args.scene]()
    arrays = scene_arrays(scene, background=config.background)
    bvh = bvh_for(scene, None)
    integrator = mf.MitsubaWhitted(mi, dr, arrays, config, config.ray_offset * float(scene_scale(arrays)))
    print(
        f"{args.scene}: {scene.num_triangles:,} triangles; fovjax backend "
        f"{fovjax.trace.describe_backend('auto')}; Mitsuba {mi.__version__} {mf.MITSUBA_VARIANT} "
        f"({dr.thread_count()} threads); SPP {args.spp}, depth {args.max_depth}, median of {args.repeats}"
    )
    sys.stdout.flush()

    runs = []
    for i, (w, h) in enumerate(args.sizes):
        rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=w, eye_height=h)
        run_args = SimpleNamespace(
            gaze=[*mf.DEFAULT_GAZE[0], *mf.DEFAULT_GAZE[1]],
            fovea=args.fovea,
            repeats=args.repeats,
            no_foveated=i > 0,
            max_depth=args.max_depth,
        )
        r = mf.run_spp(scene, rig, bvh, config, integrator, run_args, args.spp)
        mf.report(r, run_args)
        sys.stdout.flush()
        runs.append(r)

    dense = runs[0]
    dense_px = dense["width"] * dense["height"]

    def ns_per_ray(r, key):
        return r[f"{key}_ms"] * 1e6 / mf._rays(r[f"{key}_rays"])

    rows = []
    for r in runs:
        row = {
            "size": f"{r['width']}x{r['height']}",
            "pixel_density": r["width"] * r["height"] / dense_px,
            "psnr_db": r["psnr_db"],
        }
        for key in ("mitsuba_full", "fovjax_full"):
            row[f"{key}_rays"] = mf._rays(r[f"{key}_rays"])
            row[f"{key}_ms"] = r[f"{key}_ms"]
            row[f"{key}_ns_per_ray"] = ns_per_ray(r, key)
            row[f"{key}_cost_per_ray_over_dense"] = ns_per_ray(r, key) / ns_per_ray(dense, key)
        rows.append(row)
    foveated = {
        "size": f"{dense['width']}x{dense['height']}",
        "rays": mf._rays(dense["fovjax_foveated_rays"]),
        "ms": dense["fovjax_foveated_ms"],
        "ns_per_ray": ns_per_ray(dense, "fovjax_foveated"),
        "cost_per_ray_over_full": ns_per_ray(dense, "fovjax_foveated") / ns_per_ray(dense, "fovjax_full"),
    }
    foveated["ray_share"] = foveated["rays"] / mf._rays(dense["fovjax_full_rays"])

    print(f"\nCost per ray against ray density, 2 x WxH, SPP {args.spp} ({args.scene}; median frames)")
    print(
        f"  {'per eye':>10s} {'pixels':>7s} {'rays':>11s}   {'Mitsuba ns/ray':>14s} {'x dense':>7s}"
        f"   {'fovjax ns/ray':>13s} {'x dense':>7s}"
    )
    for row in rows:
        print(
            f"  {row['size']:>10s} {row['pixel_density']:7.4f} {row['fovjax_full_rays']:11,}   "
            f"{row['mitsuba_full_ns_per_ray']:14.1f} {row['mitsuba_full_cost_per_ray_over_dense']:7.2f}   "
            f"{row['fovjax_full_ns_per_ray']:13.1f} {row['fovjax_full_cost_per_ray_over_dense']:7.2f}"
        )
    print(
        f"  foveated {args.fovea[0]:g}°/{args.fovea[1]:g}° at {foveated['size']}: {foveated['rays']:,} rays "
        f"({foveated['ray_share']:.1%} of the full frame's), {foveated['ns_per_ray']:.1f} ns/ray, "
        f"{foveated['cost_per_ray_over_full']:.2f}x its full frame's cost per ray"
    )

    columns = [
        "per eye",
        "pixels / densest",
        "rays per frame",
        "Mitsuba 3 ns per ray",
        "Mitsuba 3 cost per ray / densest",
        "fovjax ns per ray",
        "fovjax cost per ray / densest",
        "PSNR Mitsuba vs fovjax (dB)",
    ]
    table_rows = [
        [
            row["size"],
            round(row["pixel_density"], 4),
            row["fovjax_full_rays"],
            round(row["mitsuba_full_ns_per_ray"], 1),
            round(row["mitsuba_full_cost_per_ray_over_dense"], 2),
            round(row["fovjax_full_ns_per_ray"], 1),
            round(row["fovjax_full_cost_per_ray_over_dense"], 2),
            round(row["psnr_db"], 1),
        ]
        for row in rows
    ]
    title = (
        f"Full stereo frames of the {args.scene} at falling resolution, SPP {args.spp}, depth "
        f"{args.max_depth}: cost per ray against the densest; the foveated {args.fovea[0]:g}°/"
        f"{args.fovea[1]:g}° frame at {foveated['size']}: {foveated['rays']:,} rays, "
        f"{foveated['ns_per_ray']:.1f} ns per ray, {foveated['cost_per_ray_over_full']:.2f}x its full frame's"
    )
    return {
        "scene": args.scene,
        "spp": args.spp,
        "max_depth": args.max_depth,
        "repeats": args.repeats,
        "rows": rows,
        "foveated": foveated,
        "frames": runs,
        "tables": [{"title": title, "columns": columns, "rows": table_rows}],
    }


if __name__ == "__main__":
    from _record import write_record

    import fovjax  # noqa: F401 -- first: kept memory before Mitsuba's threads (fovjax/_startup.py)

    figures = main()
    if figures is not None:
        write_record("ray_density", json.loads(json.dumps(figures, default=mf._json_default)))
