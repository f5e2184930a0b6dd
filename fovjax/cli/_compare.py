"""`fovjax compare`: cost against accuracy of fovea thresholds, written as CSV and charts."""

from __future__ import annotations

import argparse

from fovjax import cli


def _two_numbers(what: str):
    """An argparse type for "A,B" whose error says what the pair is (`what`)."""

    def parse(text: str) -> tuple[float, float]:
        try:
            a, b = (float(x) for x in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{what}, got {text!r}") from None
        return a, b

    return parse


_pair = _two_numbers("a threshold pair is FOVEA,PERIPHERY in degrees")
_gaze_point = _two_numbers("a gaze point is X,Y in normalised display coordinates (0..1 each)")


def _distributed(text: str) -> tuple[str, int, int]:
    """COORDINATOR_HOST:PORT,NUM_PROCESSES,PROCESS_ID for `jax.distributed.initialize`."""
    try:
        address, num_processes, process_id = text.split(",")
        num_processes, process_id = int(num_processes), int(process_id)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--distributed is HOST:PORT,NUM_PROCESSES,PROCESS_ID (e.g. 10.0.0.1:1234,2,0), got {text!r}"
        ) from None
    if ":" not in address or num_processes < 1 or not 0 <= process_id < num_processes:
        raise argparse.ArgumentTypeError(
            f"--distributed {text!r}: need HOST:PORT of process 0, NUM_PROCESSES >= 1 and "
            "0 <= PROCESS_ID < NUM_PROCESSES"
        )
    return address, num_processes, process_id


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compare",
        help="compare fovea thresholds: cost (rays, ms) against accuracy (PSNR, SSIM, FLIP, FovVideoVDP)",
        description="Render every threshold pair foveated and the full frame, for a few gaze points and "
        "keys; write comparison.csv and charts (cost against accuracy with the Pareto front, "
        "per-threshold bars, error and rays by eccentricity ring) and name the cheapest configuration "
        "within the criterion.",
    )
    p.add_argument("--scene", default="atrium")
    p.add_argument(
        "--thresholds", type=_pair, nargs="+", default=[(5, 10), (7.5, 15), (10, 20), (12.5, 25), (15, 30)]
    )
    p.add_argument("--spp", type=int, nargs="+", default=[1, 4])
    p.add_argument("--width", type=int, default=640, help="pixels per eye (the HMD has 1280)")
    p.add_argument("--height", type=int, default=512)
    p.add_argument(
        "--gazes", type=_gaze_point, nargs="+", default=[(0.5, 0.5), (0.3, 0.4)], help="X,Y per gaze point"
    )
    p.add_argument("--keys", type=int, nargs="+", default=[0])
    p.add_argument("--criterion", default="flip", help="metric that must stay below --threshold")
    p.add_argument("--threshold", type=float, default=0.05)
    p.add_argument("--max-depth", type=int, default=5)
    cli.add_backend(p)
    p.add_argument("--no-perceptual", action="store_true", help="skip FovVideoVDP even if installed")
    p.add_argument(
        "--fidelity",
        default=None,
        help="'auto': also plan each configuration's shading fidelity per region (plan_fidelity) "
        "and add it to the table and charts beside plain foveation",
    )
    p.add_argument(
        "--fidelity-threshold",
        type=float,
        default=0.01,
        help="with --fidelity auto: the FLIP a plan may add per 5° eccentricity ring over plain foveation",
    )
    p.add_argument(
        "--fidelity-frame-tolerance",
        type=float,
        default=None,
        help="with --fidelity auto: the FLIP a plan may also add to the whole frame (mean over gazes "
        "and keys) over plain foveation, e.g. 0.005 for equal FLIP within 0.005 (default: the rings "
        "alone decide)",
    )
    p.add_argument(
        "--shard",
        action="store_true",
        help="render each configuration's frames in one program sharded over jax.devices() "
        "(ms per frame = batch time / frames)",
    )
    p.add_argument(
        "--distributed",
        type=_distributed,
        metavar="HOST:PORT,N,ID",
        help="run on N processes (hosts) with jax.distributed: the same command on every host, "
        "ID 0..N-1, HOST:PORT the address of process 0; implies --shard, process 0 writes the results",
    )
    from fovjax.foveate import METHODS

    p.add_argument(
        "--methods",
        nargs="+",
        default=["thesis"],
        help="foveation methods to sweep with every threshold pair (the registered methods, "
        f"fovjax.foveate.METHODS: {', '.join(METHODS)}); one table and one chart across them",
    )
    p.add_argument(
        "--video",
        metavar="RECORDING",
        default=None,
        help="compare on an animated sequence instead of still frames: the gaze of this recording "
        "(.csv or .jsonl) replayed frame by frame with run_session's tracking fallback, every method "
        "x threshold pair judged by FovVideoVDP in video mode against the full render of the same "
        "frames; writes video_comparison.csv and video_comparison.png (--gazes, --keys after the "
        "first, --criterion and --threshold are not used)",
    )
    p.add_argument("--frames", type=int, default=None, help="with --video: frames (default 60)")
    p.add_argument("--fps", type=float, default=None, help="with --video: frames per second (default 30)")
    p.add_argument(
        "--start",
        type=float,
        default=None,
        help="with --video: the first frame's time in the recording, s (default 0)",
    )
    p.add_argument(
        "--blocks",
        type=int,
        default=None,
        help="with --video: consecutive blocks of frames the JOD's interval is measured over "
        "(default 4; 0: no interval)",
    )
    p.add_argument("-o", "--output", default="out/compare")
    cli.add_overwrite(p)
    cli.add_size_check(p)
    cli.add_regions(p)
    p.set_defaults(func=run)


# What `fovjax compare` writes into its folder: another run's are refused (--overwrite).
COMPARE_FILES = (
    "comparison.csv",
    "cost_accuracy_*_spp*.png",
    "bars_spp*.png",
    "rings.png",
    "video_comparison.csv",
    "video_comparison.png",
)


# Metrics a criterion can name, and the range of each one's values.
METRIC_RANGES = {"flip": (0.0, 1.0), "ssim": (-1.0, 1.0), "psnr": (0.0, None), "jod": (None, 10.0)}


VIDEO_OPTIONS = ("frames", "fps", "start", "blocks")
VIDEO_DEFAULTS = {"frames": 60, "fps": 30.0, "start": 0.0, "blocks": 4}


def _validate_video(args) -> None:
    """`--video` and its options: a readable recording, the frames, rate, start and blocks."""
    import importlib.util

    given = [name for name in VIDEO_OPTIONS if getattr(args, name) is not None]
    if args.video is None:
        if given:
            raise cli.UsageError(f"--{given[0]} needs --video RECORDING (it sets the animated sequence)")
        return
    for name, value in VIDEO_DEFAULTS.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    cli.input_file(args.video, "--video", suffixes=(".csv", ".jsonl"))
    cli.number(args.frames, "--frames", ge=2, integer=True)
    cli.number(args.fps, "--fps", gt=0.0)
    cli.number(args.start, "--start", ge=0.0)
    if args.blocks != 0:
        cli.number(args.blocks, "--blocks (0, or 2 to --frames / 2)", ge=2, le=args.frames // 2, integer=True)
    if args.shard or args.distributed or args.fidelity:
        raise cli.UsageError("--video: --shard, --distributed and --fidelity are for still frames")
    if not args.no_perceptual and importlib.util.find_spec("pyfvvdp") is None:
        raise cli.UsageError(
            "--video: JOD needs FovVideoVDP (pip install 'fovjax[fvvdp]'; or --no-perceptual)"
        )


def validate(args) -> None:
    """Every argument of `fovjax compare`, before anything is rendered."""
    import importlib.util

    cli.scene(args.scene)
    cli.backend(args.backend)
    for fovea, periphery in args.thresholds:
        cli.fovea_periphery(fovea, periphery, "--thresholds")
    cli.squares(args.spp, "--spp")
    for key in args.keys:
        cli.seed(key, "--keys")
    cli.number(args.width, "--width", ge=1)
    cli.number(args.height, "--height", ge=1)
    for gaze in args.gazes:
        cli.display_point(gaze, "--gazes")
    cli.number(args.max_depth, "--max-depth", ge=0)
    cli.choice(args.criterion, "--criterion", tuple(METRIC_RANGES))
    lo, hi = METRIC_RANGES[args.criterion]
    cli.number(args.threshold, f"--threshold (of {args.criterion})", ge=lo, le=hi)
    if args.fidelity is not None:
        cli.choice(args.fidelity, "--fidelity", ("auto",))
    cli.number(args.fidelity_threshold, "--fidelity-threshold (FLIP added per ring)", ge=0.0, le=1.0)
    tolerance = args.fidelity_frame_tolerance
    if tolerance is not None:
        cli.number(tolerance, "--fidelity-frame-tolerance (FLIP added to the frame)", ge=0.0)
        if args.fidelity != "auto":
            raise cli.UsageError(
                f"--fidelity-frame-tolerance {tolerance:g}: bounds a plan, needs --fidelity auto"
            )
    from fovjax.foveate import METHODS

    for method in args.methods:
        cli.choice(method, "--methods", tuple(METHODS))
    # A batch (--shard, --distributed) and a fidelity plan need a method that takes them.
    refusing = [
        m
        for m in args.methods
        if ((args.shard or args.distributed) and not METHODS[m].batches)
        or (args.fidelity and "fidelity" not in METHODS[m].thesis_options)
    ]
    if refusing:
        raise cli.UsageError(
            f"--methods {' '.join(refusing)}: --shard, --distributed and --fidelity are the thesis's method's"
        )
    cli.output_folder(args.output, "-o", COMPARE_FILES, overwrite=args.overwrite)
    _validate_video(args)
    # Every configuration's foveated frame and the full one, at the largest SPP; along a
    # recording, the full frames at every SPP and one configuration's are kept (and stacked).
    kept = args.frames * (len(args.spp) + 2) if args.video is not None else 0
    cli.frame_size(args, args.width, args.height, max(args.spp), kept_images=kept)
    if args.video is not None:
        return
    # Installed extras last: every row of tests/test_bad_inputs.py answers the same without them.
    if args.criterion == "flip" and importlib.util.find_spec("flip_evaluator") is None:
        raise cli.UsageError("--criterion flip: needs flip-evaluator (pip install 'fovjax[flip]')")
    if args.criterion == "jod" and (args.no_perceptual or importlib.util.find_spec("pyfvvdp") is None):
        why = "--no-perceptual skips it" if args.no_perceptual else "pip install 'fovjax[fvvdp]'"
        raise cli.UsageError(f"--criterion jod: needs FovVideoVDP ({why})")
    if args.fidelity == "auto" and importlib.util.find_spec("flip_evaluator") is None:
        raise cli.UsageError(
            "--fidelity auto: plans by FLIP, needs flip-evaluator (pip install 'fovjax[flip]')"
        )


def run(args) -> int:
    validate(args)
    if args.distributed is not None:
        import jax

        # Before anything touches a JAX backend: then jax.devices() lists every host's devices.
        address, num_processes, process_id = args.distributed
        jax.distributed.initialize(
            coordinator_address=address, num_processes=num_processes, process_id=process_id
        )
        args.shard = True
    import jax

    import fovjax
    from fovjax.eval import HIGHER_IS_BETTER, ThresholdSweep, compare_thresholds
    from fovjax.render import RenderConfig, StereoRig

    name = {"cornell": "cornell_box"}.get(args.scene, args.scene)  # the alias `render` takes
    scene = fovjax.scenes.BUILTIN[name]() if name in fovjax.scenes.BUILTIN else fovjax.load_scene(name)
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(scene), eye_width=args.width, eye_height=args.height
    )
    renderer = fovjax.FoveatedRenderer(
        scene, rig, config=RenderConfig(max_depth=args.max_depth, backend=args.backend)
    )
    if args.video is not None:
        return _run_video(args, renderer)
    sweep = ThresholdSweep(
        thresholds=args.thresholds,
        spp=args.spp,
        gazes=args.gazes,
        keys=args.keys,
        regions=args.regions,
        methods=args.methods,
    )
    result = compare_thresholds(
        renderer,
        sweep=sweep,
        criterion=(args.criterion, args.threshold),
        perceptual=False if args.no_perceptual else None,
        plan=("flip", args.fidelity_threshold, args.fidelity_frame_tolerance)
        if args.fidelity == "auto"
        else None,
        shard=args.shard,
    )
    if jax.process_index() != 0:  # every process holds the same results; one writes them
        return 0
    with cli.deferred_interrupt():
        if args.overwrite:
            cli.clear_outputs(args.output, COMPARE_FILES)
        paths = result.write(args.output)
        cli.wrote(*paths.values())
    cols = ["config", "rays_per_frame", "new_rays_per_frame", "ms_per_frame", "speedup"]
    cols += ["psnr", "ssim", "flip", "jod", "pareto"]
    cols = [c for c in cols if c in result.records[0]]
    print("  ".join(f"{c:>14s}" for c in cols))
    for r in result.records:
        cells = [f"{r[c]:14.4g}" if isinstance(r[c], float) else f"{r[c]!s:>14s}" for c in cols]
        print("  ".join(cells))
    for label, plan in result.plans.items():
        print(f"\n{label}:\n{plan}\n")
    for s, f in sorted(result.full.items()):
        print(f"full spp {s}: {f['rays_per_frame']:,.0f} rays, {f['ms_per_frame']:.0f} ms per frame")
    metric, threshold = result.criterion
    side = ("above", ">") if metric in HIGHER_IS_BETTER else ("below", "<")
    if result.choice is None:
        print(f"no configuration keeps {metric} {side[0]} {threshold:g} over its whole interval")
    else:
        print(f"cheapest with {metric} {side[1]} {threshold:g} (whole 95% interval): {result.choice.name}")
    print(f"wrote {paths['csv'].parent.resolve()}/")
    return 0


def _run_video(args, renderer) -> int:
    """`fovjax compare --video`: the methods along the recording, one table and one chart."""
    from fovjax.eval import ThresholdSweep, compare_methods_on_recording

    sweep = ThresholdSweep(
        thresholds=args.thresholds,
        spp=args.spp,
        keys=args.keys[:1],
        regions=args.regions,
        methods=args.methods,
    )
    result = compare_methods_on_recording(
        renderer,
        args.video,
        sweep,
        frames=args.frames,
        fps=args.fps,
        start_s=args.start,
        blocks=args.blocks,
        perceptual=not args.no_perceptual,
    )
    with cli.deferred_interrupt():
        if args.overwrite:
            cli.clear_outputs(args.output, COMPARE_FILES)
        paths = result.write(args.output)
        cli.wrote(*paths.values())
    metric = result.metric
    cols = ["config", "ms_per_frame", "new_rays_per_frame", "reused_pixels_per_frame", metric]
    cols += [f"{metric}_lo", f"{metric}_hi", "pareto"]
    print("  ".join(f"{c:>16s}" for c in cols))
    for r in result.records:
        cells = [f"{r[c]:16.4g}" if isinstance(r[c], float) else f"{r[c]!s:>16s}" for c in cols]
        print("  ".join(cells))
    states = [f["state"] for f in result.frames]
    summary = ", ".join(f"{s} {states.count(s)}" for s in dict.fromkeys(states))
    print(
        f"tracking over {len(states)} frames: {summary}; "
        f"histories reset on {result.records[0]['resets']} frame(s)"
    )
    for s, f in sorted(result.full.items()):
        print(
            f"full spp {s}: {f['primary_rays_per_frame']:,.0f} primary rays, "
            f"{f['ms_per_frame']:.0f} ms per frame"
        )
    methods = {r["method"] for r in result.records}
    if "thesis" in methods:
        for r in result.records:
            if r["method"] == "thesis":
                continue
            m = result.measure(r["method"], "thesis", (r["fovea_deg"], r["periphery_deg"]), r["spp"])
            a, b = f"{r['method']}_{metric}", f"thesis_{metric}"
            print(
                f"new rays, {r['method']} / thesis at "
                f"{r['fovea_deg']:g}/{r['periphery_deg']:g} spp{r['spp']}: "
                f"{m['new_rays_ratio']:.3f} (frames tracked ok after the first: "
                f"{m['new_rays_ratio_ok']:.3f}); "
                f"{metric} {m[a]:.3f} [{m[a + '_lo']:.3f}, {m[a + '_hi']:.3f}] "
                f"against {m[b]:.3f} [{m[b + '_lo']:.3f}, {m[b + '_hi']:.3f}]"
            )
    print(f"wrote {paths['csv'].parent.resolve()}/")
    return 0
