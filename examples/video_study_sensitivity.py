"""How the video study's verdict depends on its assumptions, from one rendered sequence.

`fovjax study --video` renders the study's animation once and judges it on one display model.
This renders the same sequence (`fovjax.eval.study_sequence`, same defaults) and judges it again
without re-rendering: FovVideoVDP in video mode at other peak luminances (the thesis gives none;
the study assumes 100 cd/m²), and FovVideoVDP on single frames of the same sequence (image mode,
the still-frame judgement the issue contrasts with), at the same gaze.

    python examples/video_study_sensitivity.py                        # atrium, 2 x 160x128, 30 frames
    python examples/video_study_sensitivity.py --luminances 30 300 --stills 0 15 29 -o out/vs.csv

Prints one row per level: the video JOD at each peak luminance, the mean still-frame JOD over
the chosen frames, and the level the noise-free observers' pair test accepts for each column
(the lowest level with 10 - JOD <= 1; "none" when every level is seen).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import fovjax
import fovjax.eval as fe


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="atrium")
    p.add_argument("--width", type=int, default=160)
    p.add_argument("--height", type=int, default=128)
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--gaze", default="scanpath", choices=fe.VIDEO_GAZE_MODES)
    p.add_argument("--rule", default="either")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--luminances", type=float, nargs="+", default=[30.0, 300.0], help="cd/m², besides 100")
    p.add_argument("--stills", type=int, nargs="+", default=[0, 15, 29], help="frames judged as still images")
    p.add_argument("-o", "--output", help="CSV of the table")
    args = p.parse_args()
    if any(not 0 <= f < args.frames for f in args.stills):
        p.error(f"--stills {args.stills}: frames must be in 0..{args.frames - 1}")

    name = {"cornell": "cornell_box"}.get(args.scene, args.scene)
    scene = fovjax.scenes.BUILTIN[name]()
    start = time.perf_counter()
    animation = fe.StudyAnimation(
        eye_width=args.width,
        eye_height=args.height,
        frames=args.frames,
        gaze=args.gaze,
        rule=args.rule,
        seed=args.seed,
    )
    seq = fe.study_sequence(scene, animation)
    print(f"rendered {seq.frames} frames in {time.perf_counter() - start:.0f} s (traces {seq.traces})")
    columns: dict[str, dict] = {}
    for peak in [100.0, *args.luminances]:
        t = time.perf_counter()
        columns[f"video {peak:g} cd/m²"] = fe.judge_sequence(
            seq, fe.sx111_display(seq.eye_width, seq.eye_height, peak_luminance=peak)
        )
        print(f"video at {peak:g} cd/m²: {time.perf_counter() - t:.0f} s")
    display = fe.sx111_display(seq.eye_width, seq.eye_height)
    still = {}
    for level, images in seq.foveated.items():
        values = [
            float(fe.fovvdp(images[f], seq.reference[f], display, gaze_xy=seq.gaze[f])) for f in args.stills
        ]
        still[level] = float(np.mean(values))
    columns["still (mean of frames " + ",".join(map(str, args.stills)) + ")"] = still

    rows = []
    for level in seq.levels:
        row = {"fovea_deg": level[0], "periphery_deg": level[1]}
        row.update({name: float(values[level]) for name, values in columns.items()})
        rows.append(row)
    print(f"display: {display.width_px}x{display.height_px} per eye, {display.ppd:.2f} px/° at the centre")
    print("| level | " + " | ".join(columns) + " |")
    print("|---" * (len(columns) + 1) + "|")
    for row in rows:
        print(
            f"| {row['fovea_deg']:g}/{row['periphery_deg']:g} | "
            + " | ".join(f"{row[c]:.3f}" for c in columns)
            + " |"
        )
    accepted = []
    for c in columns:
        first = next((r for r in rows if 10.0 - r[c] <= fe.JND_JOD), None)
        accepted.append("none" if first is None else f"{first['fovea_deg']:g}/{first['periphery_deg']:g}")
    print("| pair test accepts | " + " | ".join(accepted) + " |")
    if args.output:
        fe.write_csv(rows, args.output)
        print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
