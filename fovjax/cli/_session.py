"""`fovjax session`: render a foveated stereo sequence driven by gaze/head sources."""

from __future__ import annotations

import argparse
import sys

from fovjax import cli


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "session",
        help="render a foveated stereo sequence following a gaze (and head) source",
        description="Render frames of a foveated stereo session: PNG frames, session.csv (per-frame "
        "tracking state, latency, thresholds, rays, times) and session.json (the same plus a summary). "
        "Gaze sources: replay:FILE[@SPEED], synthetic:scanpath[:SEED], synthetic:pursuit "
        "(synthetic gaze: 120 Hz, noise-free, an idealised tracker; the thesis's ran at 60/30 Hz with "
        "0.25-1° accuracy), "
        "synthetic:fixed[:X,Y], serial:PORT[@BAUD], pupil:HOST:PORT, "
        "viewpoint[:LIB][@raw] (smoothed gaze, as the thesis, unless @raw); head sources: "
        "replay:FILE, synthetic:sway, serial:PORT, intersense[:LIB]. When the gaze goes stale the "
        "fovea is held, then widened step by step up to the whole screen, and narrowed again once "
        "good samples return.",
    )
    p.add_argument("--gaze", required=True, help="gaze source spec")
    p.add_argument("--head", default=None, help="head-pose source spec (default: head still)")
    n = p.add_mutually_exclusive_group(required=True)
    n.add_argument("--frames", type=int, help="number of frames")
    n.add_argument("--seconds", type=float, help="session length (frames = seconds x fps)")
    p.add_argument("--fps", type=float, default=30.0, help="frames per second of the timeline (30)")
    p.add_argument("--scene", default="atrium", help="atrium, cornell, spheres, or a scene file")
    p.add_argument("--triangles", type=int, default=262_000, help="atrium size (triangles)")
    p.add_argument("--width", type=int, default=640, help="pixels per eye (default 640)")
    p.add_argument("--height", type=int, default=512, help="pixels per eye (default 512)")
    p.add_argument("--fovea", type=float, default=5.0, help="fovea eccentricity in degrees (default 5)")

    cli.add_regions(p)
    p.add_argument("--periphery", type=float, default=10.0, help="periphery eccentricity (default 10)")
    p.add_argument("--spp", type=int, default=1, help="samples per pixel: 1, 4, 9, ... (default 1)")
    p.add_argument("--max-depth", type=int, default=5, help="reflection bounces (default 5)")
    cli.add_backend(p)
    p.add_argument(
        "--clock",
        choices=("auto", "virtual", "wall"),
        default="auto",
        help="virtual: frame k at k/fps on a simulated clock (deterministic); wall: as fast as it "
        "renders, for live devices; auto (default): wall for live devices, else virtual",
    )
    p.add_argument("--seed", type=int, default=0, help="PRNG seed of the sampling (default 0)")
    p.add_argument("--fixed-key", action="store_true", help="the same sampling pattern every frame")
    p.add_argument("--hold-for", type=float, default=None, help="seconds the last gaze is held (0.15)")
    p.add_argument("--widen-every", type=float, default=None, help="seconds per widening step (0.1)")
    p.add_argument("--widen-steps", type=int, default=None, help="steps to the full screen (4)")
    p.add_argument(
        "--smoothing", choices=("none", "ema", "one_euro"), default="none", help="gaze filter (default none)"
    )
    p.add_argument(
        "--show-samples", action="store_true", help="also write debug_*.png: regions and traced samples"
    )
    p.add_argument("--video", action="store_true", help="also write session.mp4 (needs imageio-ffmpeg)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--wait",
        type=float,
        default=None,
        metavar="SECONDS",
        help="how long a live device may take to connect before the session fails (default 3)",
    )
    p.add_argument("-o", "--output", required=True, help="output directory")
    cli.add_overwrite(p)
    cli.add_size_check(p)
    p.set_defaults(func=run)


# What a session writes into its folder (`fovjax.SessionOutput`): another run's are refused.
SESSION_FILES = ("frame_*.png", "debug_*.png", "session.csv", "session.json", "session.mp4")


def validate(args) -> None:
    """Every argument of `fovjax session`, before a scene is built or a device opened."""
    import importlib.util

    cli.source_spec(args.gaze, "gaze", "--gaze")
    cli.backend(args.backend)
    if args.head is not None:
        cli.source_spec(args.head, "head", "--head")
    cli.number(args.fps, "--fps", gt=0)
    if args.frames is not None:
        cli.number(args.frames, "--frames", ge=1)
    else:
        cli.number(args.seconds, "--seconds", gt=0)
        if round(args.seconds * args.fps) < 1:
            raise cli.UsageError(f"--seconds {args.seconds:g}: shorter than one frame at --fps {args.fps:g}")
    cli.scene(args.scene)
    cli.number(args.triangles, "--triangles", ge=1)
    cli.number(args.width, "--width", ge=1)
    cli.number(args.height, "--height", ge=1)
    cli.fovea_periphery(args.fovea, args.periphery, "--fovea/--periphery")
    cli.squares(args.spp, "--spp")
    cli.seed(args.seed)
    cli.number(args.max_depth, "--max-depth", ge=0)
    if args.hold_for is not None:
        cli.number(args.hold_for, "--hold-for", ge=0)
    if args.widen_every is not None:
        cli.number(args.widen_every, "--widen-every", gt=0)
    if args.widen_steps is not None:
        cli.number(args.widen_steps, "--widen-steps", ge=1)
    if args.wait is not None:
        cli.number(args.wait, "--wait", gt=0)
    if args.video and importlib.util.find_spec("imageio_ffmpeg") is None:
        raise cli.UsageError("--video: needs imageio-ffmpeg (pip install 'fovjax[video]')")
    cli.output_folder(args.output, "-o", SESSION_FILES, overwrite=args.overwrite)
    cli.frame_size(args, args.width, args.height, args.spp, kinds=("foveated",))


def run(args) -> int:
    import dataclasses

    import jax

    import fovjax
    from fovjax.cli._render import _load_scene
    from fovjax.devices import DEFAULT_CONNECT_TIMEOUT, ConnectTimeoutError, FallbackPolicy, GazeTracker
    from fovjax.foveate import Foveation
    from fovjax.render import RenderConfig, StereoRig

    validate(args)
    policy = FallbackPolicy()
    changes = {
        name: value
        for name, value in (
            ("hold_for", args.hold_for),
            ("widen_every", args.widen_every),
            ("widen_steps", args.widen_steps),
        )
        if value is not None
    }
    if "hold_for" in changes:
        changes["stale_after"] = min(policy.stale_after, changes["hold_for"])
    policy = dataclasses.replace(policy, **changes)
    tracker = GazeTracker(policy, smoothing=None if args.smoothing == "none" else args.smoothing)
    scene = _load_scene(args)
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(scene), eye_width=args.width, eye_height=args.height
    )
    foveation = cli.regions(
        Foveation(fovea_deg=args.fovea, periphery_deg=args.periphery, spp=args.spp), args, args.height
    )
    renderer = fovjax.FoveatedRenderer(
        scene, rig, foveation, RenderConfig(max_depth=args.max_depth, backend=args.backend)
    )
    session = fovjax.SessionConfig(
        frames=args.frames,
        seconds=args.seconds,
        fps=args.fps,
        clock=None if args.clock == "auto" else args.clock,
        fresh_key_per_frame=not args.fixed_key,
        wait=DEFAULT_CONNECT_TIMEOUT if args.wait is None else args.wait,
    )
    if args.overwrite:  # the earlier run's files go just before this one's are written
        cli.clear_outputs(args.output, SESSION_FILES)
    try:
        result = fovjax.run_session(
            renderer,
            gaze=args.gaze,
            head=args.head,
            session=session,
            out=fovjax.SessionOutput(args.output, video=args.video, debug=args.show_samples),
            tracker=tracker,
            key=jax.random.key(args.seed),
            progress=not args.no_progress,
        )
    except ConnectTimeoutError as err:
        raise ConnectTimeoutError(f"{err} (--wait SECONDS keeps trying longer)") from None
    s = result.summary
    written = _written(result, args)
    cli.wrote(*written)
    for warning in s["warnings"]:
        print(f"fovjax session: warning: {warning}", file=sys.stderr)
    if not result.frames:
        print("no frames rendered (interrupted)")
        raise KeyboardInterrupt
    states = ", ".join(f"{state} {count}" for state, count in s["tracking_states"].items())
    latency = "" if s["ok_latency_s_mean"] is None else f", ok latency {s['ok_latency_s_mean'] * 1e3:.1f} ms"
    print(
        f"{s['frames']} frames ({s['clock']} clock): {s['rays_per_frame_mean'] / 1e6:.3f} M rays and "
        f"{s['render_s_mean']:.3f} s per frame, compile {s['compile_s_total']:.1f} s; tracking {states}"
        f"{latency}{' (interrupted)' if s['interrupted'] else ''}"
    )
    for role, status in s["sources"].items():
        age = status["last_sample_age_s"]
        print(
            f"{role} {status['spec']}: {status['samples']} samples, {status['reconnects']} reconnect(s), "
            f"{status['errors']} error(s), last sample "
            + ("never" if age is None else f"{age * 1e3:.0f} ms before the last frame")
            + (f"; last error: {status['last_error']}" if status["last_error"] else "")
        )
    kinds = "frame_*.png, " + ("debug_*.png, " if args.show_samples else "") + "session.csv, session.json"
    if result.video is not None:
        kinds += ", session.mp4"
    if result.out is not None:  # the command always writes its frames
        print(f"wrote {result.out.resolve()}/ ({kinds})")
    if s["interrupted"]:
        raise KeyboardInterrupt
    return 1 if s["warnings"] else 0


def _written(result, args) -> list:
    """The files the session finished: its frames, its log and its video."""
    out = result.out
    if out is None:
        return []
    files = [f.path for f in result.frames if f.path]
    if args.show_samples:
        files += [str(out / f"debug_{f.frame:05d}.png") for f in result.frames]
    files += [p for p in (out / "session.csv", out / "session.json") if p.exists()]
    if result.video is not None and result.video.exists():
        files.append(result.video)
    return files
