"""`fovjax study --video`: the thesis's user study emulated on video (`fovjax.eval.video_study`):
an animation through the scene at the HMD's frame rate with head motion and a gaze per frame,
rendered full and foveated at every appendix level, judged by FovVideoVDP (video mode, foveated,
the SX111 display model at the rendered resolution), and the pair, ramp and slider tests
answered by automatic observers from those JODs.

    fovjax study --video -o out/video_study
    fovjax study --video --scene atrium --width 160 --height 128 --frames 30 --fps 60 \\
        --gaze scanpath --rule either --peak-luminance 100 --observers 15 --seed 0 -o out/video_study

writes video_study.csv (per level: JOD per eye, d = 10 - JOD, rays), majority.csv (per test
beside the thesis's 12.5°/25°), responses.csv, the pair/ramp/slider tables and figures 66-68,
and prints the same.
"""

from __future__ import annotations

import time
from pathlib import Path

# Options of `fovjax study` that only mean something with --video, and their defaults there.
VIDEO_DEFAULTS = {
    "scene": "atrium",
    "width": 160,
    "height": 128,
    "frames": 30,
    "fps": 60.0,
    "gaze": "scanpath",
    "rule": "either",
    "regions": "thesis",
    "keys": "fresh",
    "method": "thesis",
    "walk_speed": 1.0,
    "peak_luminance": 100.0,
}
# Options of `fovjax study --comparison` that do not apply to --video.
NOT_WITH_VIDEO = ("metric", "model", "shuffle")


def add_arguments(p) -> None:
    """The --video options of `fovjax study` (all default None: applied in `run`)."""
    from fovjax.foveate import SAMPLING_RULES

    g = p.add_argument_group("--video (the study emulated on an animated sequence)")
    g.add_argument("--scene", help="scene of the animation (default atrium, the Sponza stand-in)")
    g.add_argument("--width", type=int, help="pixels per eye, horizontally (default 160; the SX111: 1280)")
    g.add_argument("--height", type=int, help="pixels per eye, vertically (default 128; the SX111: 1024)")
    g.add_argument("--frames", type=int, help="frames in the sequence (default 30)")
    g.add_argument("--fps", type=float, help="frames per second (default 60, the SX111's rate)")
    g.add_argument("--gaze", choices=("scanpath", "fixed"), help="scanpath (default) or the display centre")
    g.add_argument("--rule", choices=SAMPLING_RULES, help="the foveation's sampling rule (default either)")
    from fovjax import cli

    g.add_argument(
        "--regions",
        choices=("angle", "thesis"),
        help=f"{cli.REGIONS_HELP} (default thesis here, so the majority compares with the thesis's)",
    )
    g.add_argument(
        "--keys", choices=("fresh", "fixed"), help="sampling key: new every frame (default) or the same"
    )
    from fovjax.foveate import METHODS

    g.add_argument(
        "--method",
        help="foveation method of the foveated frames (the registered methods, fovjax.foveate.METHODS: "
        f"{', '.join(METHODS)}; default thesis); a temporal one carries its history frame to frame",
    )
    g.add_argument("--walk-speed", type=float, help="m/s along the view direction (default 1)")
    g.add_argument("--peak-luminance", type=float, help="the display's peak, cd/m² (default 100)")


def validate(args) -> None:
    """The --video options, before anything is rendered (called by `fovjax study`'s validate)."""
    from fovjax import cli

    video_only = [k for k in VIDEO_DEFAULTS if getattr(args, k, None) is not None]
    if not args.video:
        if video_only:
            names = ", ".join("--" + k.replace("_", "-") for k in video_only)
            raise cli.UsageError(f"{names}: only with --video")
        return
    wrong = [k for k in NOT_WITH_VIDEO if getattr(args, k, None) not in (None, False)]
    if wrong:
        names = ", ".join("--" + k for k in wrong)
        raise cli.UsageError(f"{names}: not with --video (the video study judges FovVideoVDP JOD)")
    for k, default in VIDEO_DEFAULTS.items():
        if getattr(args, k) is None:
            setattr(args, k, default)
    cli.scene(args.scene)
    cli.number(args.width, "--width", ge=8, integer=True)
    cli.number(args.height, "--height", ge=8, integer=True)
    cli.number(args.frames, "--frames", ge=2, integer=True)
    cli.number(args.fps, "--fps", gt=0)
    from fovjax.foveate import METHODS

    cli.choice(args.method, "--method", tuple(METHODS))
    cli.number(args.walk_speed, "--walk-speed", ge=0)
    cli.number(args.peak_luminance, "--peak-luminance", gt=0)
    if args.seed is not None:
        cli.number(args.seed, "--seed", ge=0, le=2**32 - 1 - args.frames, integer=True)


def run(args) -> int:
    import fovjax
    from fovjax import cli
    from fovjax.eval import ObserverPanel, StudyAnimation, require_extra, video_study

    require_extra("pyfvvdp", "fvvdp", "fovjax study --video (FovVideoVDP)")
    spp = 4 if args.spp is None else args.spp
    observers = 15 if args.observers is None else args.observers
    noise_sd = 0.0 if args.noise_sd is None else args.noise_sd
    seed = 0 if args.seed is None else args.seed
    threshold = 1.0 if args.threshold is None else args.threshold
    out = Path(args.output)
    name = {"cornell": "cornell_box"}.get(args.scene, args.scene)
    scene = fovjax.scenes.BUILTIN[name]() if name in fovjax.scenes.BUILTIN else fovjax.load_scene(name)
    seconds = args.frames / args.fps
    print(
        f"video study: {args.scene}, {args.frames} frames at {args.fps:g} fps ({seconds:.3g} s), "
        f"2 x {args.width}x{args.height}, SPP {spp}, gaze {args.gaze}, rule {args.rule}, "
        f"regions {args.regions}, keys {args.keys}, method {args.method}, "
        f"walk {args.walk_speed:g} m/s, peak {args.peak_luminance:g} cd/m²"
    )
    start = time.perf_counter()
    animation = StudyAnimation(
        eye_width=args.width,
        eye_height=args.height,
        frames=args.frames,
        fps=args.fps,
        spp=spp,
        gaze=args.gaze,
        rule=args.rule,
        regions=args.regions,
        keys=args.keys,
        method=args.method,
        walk_speed=args.walk_speed,
        seed=seed,
    )
    study = video_study(
        scene,
        animation,
        observers=ObserverPanel(n=observers, noise_sd=noise_sd, threshold=threshold, seed=seed),
        peak_luminance=args.peak_luminance,
        progress=lambda text: print(f"  {text} ({time.perf_counter() - start:.0f} s)", flush=True),
    )
    total = time.perf_counter() - start
    seq, display = study.sequence, study.display
    print(
        f"rendered in {seq.render_seconds:.1f} s (+ {seq.compile_seconds:.1f} s compiling; programs traced: "
        f"{seq.traces}), FovVideoVDP {study.metric_seconds:.1f} s, {total:.0f} s in all"
    )
    print(
        f"display: SX111 model, {display.width_px}x{display.height_px} per eye over "
        f"{display.hfov_deg:.1f}° x {display.vfov_deg:.1f}° ({display.ppd:.2f} px/° at the centre)"
    )
    if study.reference_jod is not None:
        print(f"full render against itself: {float(study.reference_jod):.3f} JOD")
    print(f"  {'level':>8s}  {'JOD':>6s}  {'d':>6s}  seen  {'rays/frame':>10s}")
    for row in study.records():
        level = f"{row['fovea_deg']:g}/{row['periphery_deg']:g}"
        seen = "yes" if row["seen"] else "no"
        rays = row["primary_rays_per_frame"]
        print(f"  {level:>8s}  {row['jod']:6.3f}  {row['d']:6.3f}  {seen:>4s}  {rays:10,.0f}")
    with cli.deferred_interrupt():
        paths = study.write(out)
        cli.wrote(*paths.values())
    levels = dict(seq.levels)
    print(f"{'test':>10s}  {'majority accepts':<32s}  thesis")
    for test, fovea in study.majorities.items():
        text = "none (no level has a majority)" if fovea is None else f"{fovea:g}°/{levels[fovea]:g}°"
        print(f"{test:>10s}  {text:<32s}  12.5°/25°")
    if all(row["seen"] for row in study.records()):
        print("note: every level is seen; the slider stops at the highest level, which is not an equivalence")
    print(f"wrote {out.resolve()}/: {', '.join(sorted(p.name for p in paths.values()))}")
    return 0
