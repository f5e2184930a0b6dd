"""Foveation methods compared along the dropout recording (issue 30's measurement): the atrium
at 2 x 640x512, SPP 1, the thesis's method, Guenter 2012, Patney 2016 and Weier 2016 at the
thesis's 5°/10° pair, the gaze of data/recordings/synthetic_scanpath_seed1_dropout.csv replayed
frame by frame with run_session's tracking fallback (the tracker falls silent from 2.0 s to 3.0 s:
hold, widen, lost, recover), every configuration judged by FovVideoVDP in video mode against the
full render of the same frames (`fovjax.eval.compare_methods_on_recording`).

    python benchmarks/compare_video.py                       # 60 frames at 30 fps from 1.5 s
    python benchmarks/compare_video.py --frames 150 --start 0 --thresholds 5,10 10,20

Prints the table and the ratio of Weier's new primary rays per frame to the thesis's with both
JOD intervals, and whether Weier traces at most half the thesis's new rays at a JOD no lower
(Weier's interval reaches the thesis's), then writes a record (benchmarks/_record.py) and the
CSV and chart under -o.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from _record import write_record

import fovjax
from fovjax.eval import ThresholdSweep, compare_methods_on_recording
from fovjax.render import RenderConfig, StereoRig

ROOT = Path(__file__).resolve().parents[1]
RECORDING = ROOT / "data/recordings/synthetic_scanpath_seed1_dropout.csv"
METHODS = ("thesis", "guenter2012", "patney2016", "weier2016")


def _pair(text: str) -> tuple[float, float]:
    fovea, periphery = (float(x) for x in text.split(","))
    return fovea, periphery


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--start", type=float, default=1.5, help="first frame's time in the recording, s")
    p.add_argument("--blocks", type=int, default=4)
    p.add_argument("--thresholds", type=_pair, nargs="+", default=[(5.0, 10.0)])
    p.add_argument("--size", type=int, nargs=2, default=(640, 512), metavar=("W", "H"))
    p.add_argument("--max-depth", type=int, default=5)
    p.add_argument("--recording", default=str(RECORDING))
    p.add_argument("-o", "--output", default="out/compare_video")
    args = p.parse_args()

    started = time.perf_counter()
    scene = fovjax.scenes.atrium()
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(scene), eye_width=args.size[0], eye_height=args.size[1]
    )
    renderer = fovjax.FoveatedRenderer(scene, rig, config=RenderConfig(max_depth=args.max_depth))
    sweep = ThresholdSweep(thresholds=args.thresholds, spp=[1], keys=[0], methods=list(METHODS))
    result = compare_methods_on_recording(
        renderer,
        args.recording,
        sweep,
        frames=args.frames,
        fps=args.fps,
        start_s=args.start,
        blocks=args.blocks,
    )
    paths = result.write(args.output)
    wall = time.perf_counter() - started

    columns = ["config", "ms/frame", "new rays/frame", "new rays / full", "new rays/frame, ok"]
    columns += ["reused px/frame", "JOD [95% CI]"]
    rows = [
        [
            r["config"],
            round(r["ms_per_frame"], 1),
            round(r["new_rays_per_frame"]),
            round(r["new_rays_fraction"], 4),
            round(r["new_rays_per_frame_ok"]),
            round(r["reused_pixels_per_frame"]),
            f"{r['jod']:.3f} [{r['jod_lo']:.3f}, {r['jod_hi']:.3f}]",
        ]
        for r in result.records
    ]
    print("  ".join(f"{c:>22s}" for c in columns))
    for row in rows:
        print("  ".join(f"{c!s:>22s}" for c in row))
    states = [f["state"] for f in result.frames]
    tracking = {s: states.count(s) for s in dict.fromkeys(states)}
    resets = [f["frame"] for f in result.frames if f["reset"]]
    print(f"tracking: {tracking}; histories reset on frames {resets}")
    measurements = []
    for pair in args.thresholds:
        m = result.measure("weier2016", "thesis", pair)
        measurements.append(m)
        print(
            f"{pair[0]:g}/{pair[1]:g}: new rays per frame, weier2016 / thesis = {m['new_rays_ratio']:.3f} "
            f"(at most 0.5: {m['at_most_half']}; over the frames tracked ok after the first: "
            f"{m['new_rays_ratio_ok']:.3f}); JOD weier2016 {m['weier2016_jod']:.3f} "
            f"[{m['weier2016_jod_lo']:.3f}, {m['weier2016_jod_hi']:.3f}], thesis {m['thesis_jod']:.3f} "
            f"[{m['thesis_jod_lo']:.3f}, {m['thesis_jod_hi']:.3f}]; no lower within the intervals: "
            f"{m['jod_no_lower']}"
        )
    print(f"wall {wall:.0f} s; wrote {paths['csv']} and {paths['chart']}")
    eye = f"2 × {args.size[0]}×{args.size[1]}"
    write_record(
        "compare_video",
        {
            "tables": [
                {
                    "title": f"Methods along {Path(args.recording).name}, atrium {eye}, SPP 1, depth "
                    f"{args.max_depth}, {args.frames} frames at {args.fps:g} fps from {args.start:g} s "
                    f"(FovVideoVDP video mode against the full render; interval over {args.blocks} blocks)",
                    "columns": columns,
                    "rows": rows,
                }
            ],
            "weier_over_thesis": measurements,
            "records": result.records,
            "full": {str(k): v for k, v in result.full.items()},
            "tracking": tracking,
            "reset_frames": resets,
            "frames": args.frames,
            "fps": args.fps,
            "start_s": args.start,
            "eye": list(args.size),
            "wall_s": round(wall, 1),
        },
        note="CPU only (2 shared cores, niced); ms per frame are medians of this run, read the ratios",
    )


if __name__ == "__main__":
    main()
