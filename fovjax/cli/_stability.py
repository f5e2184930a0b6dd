"""`fovjax stability`: flicker in the periphery along a moving gaze, fresh against fixed key,
written as CSV and a chart."""

from __future__ import annotations

import argparse

from ._failures import _common, _setup, _validate_common


def register(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser(
        "stability",
        help="flicker in the periphery along a moving gaze, fresh against fixed key",
        description="Render a foveated sequence along a synthetic gaze with a fresh and with a fixed "
        "key per frame and the full render with a fresh key; write stability.csv, "
        "stability_summary.csv and stability.png.",
    )
    _common(s, "out/stability")
    s.add_argument("--gaze", choices=("scanpath", "pursuit", "still"), default="scanpath")
    s.add_argument("--frames", type=int, default=16)
    s.add_argument("--fps", type=float, default=90.0)
    s.add_argument("--seed", type=int, default=3, help="scanpath seed and first key")
    s.set_defaults(func=run_stability)


def validate_stability(args) -> None:
    """Every argument of `fovjax stability`, before anything is rendered."""
    from fovjax import cli

    _validate_common(args)
    cli.number(args.frames, "--frames", ge=2)
    cli.seed(args.seed)
    cli.number(args.fps, "--fps", gt=0)
    # The full and the foveated sequence are kept to be compared frame to frame.
    cli.frame_size(args, args.width, args.height, 1, kept_images=2 * args.frames)


def run_stability(args) -> int:
    from fovjax import cli
    from fovjax.devices import Scanpath, SmoothPursuit
    from fovjax.eval import FullRenders, HmdDisplay, temporal_stability

    validate_stability(args)
    scene, rig, foveation, config = _setup(args)
    if args.gaze == "scanpath":
        cam = rig.eye_cameras()[0]
        path = Scanpath(
            args.seed, display_fov_deg=(HmdDisplay.from_camera(cam).hfov_deg, float(cam.vfov_deg))
        )
        onset = next(start for kind, start, _, _ in path.segments_until(60.0) if kind == "saccade")
        start = max(0.0, onset - 4 / args.fps)
        gaze = lambda t: path.position(t + start)  # noqa: E731
    elif args.gaze == "pursuit":
        gaze = SmoothPursuit(centre=(0.5, 0.5), radius=(0.1, 0.1), frequency=0.5)
    else:
        gaze = (0.5, 0.5)
    bar = None
    progress = None
    if not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(unit="frame", desc="stability")

        def step() -> None:
            bar.update(1)

        progress = step

    result = temporal_stability(
        FullRenders(scene, rig, config),
        gaze,
        foveation,
        frames=args.frames,
        fps=args.fps,
        seed=args.seed,
        progress=progress,
    )
    if bar is not None:
        bar.close()
    with cli.deferred_interrupt():
        paths = result.write(args.output)
        cli.wrote(*paths.values())
    for row in result.summary:
        print(
            f"{row['key_mode']:>5s} key: flicker beyond the fovea {row['flicker_beyond_fovea']:.4f} "
            f"(full render, fresh key {row['full_fresh_flicker_beyond_fovea']:.4f}; same policy "
            f"{row['full_same_policy_flicker_beyond_fovea']:.4f}) ratio {row['ratio_beyond_fovea']:.3f}; "
            f"periphery band ratio {row['ratio_periphery']:.3f}"
        )
    print(f"wrote {paths['csv'].parent.resolve()}/")
    return 0
