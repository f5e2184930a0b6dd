"""`fovjax session`: render a foveated stereo sequence driven by gaze/head sources."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "session",
        help="render a foveated stereo sequence following a gaze (and head) source",
        description="Render frames of a foveated stereo session. Gaze/head sources: "
        "replay:FILE, synthetic:scanpath[:SEED], synthetic:pursuit, synthetic:fixed, serial:PORT[@BAUD], "
        "pupil:HOST:PORT, viewpoint[:LIB], intersense[:LIB] (head: replay:FILE, synthetic:sway, serial:PORT, "
        "intersense[:LIB]).",
    )
    p.add_argument("--gaze", required=True, help="gaze source spec")
    p.add_argument("--head", default=None, help="head-pose source spec (default: head still)")
    n = p.add_mutually_exclusive_group(required=True)
    n.add_argument("--frames", type=int)
    n.add_argument("--seconds", type=float)
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of the session's timeline")
    p.add_argument("--scene", default="atrium")
    p.add_argument("--width", type=int, default=640, help="pixels per eye")
    p.add_argument("--height", type=int, default=512)
    p.add_argument("--fovea", type=float, default=5.0)
    p.add_argument("--periphery", type=float, default=10.0)
    p.add_argument("--spp", type=int, default=1)
    p.add_argument("--max-depth", type=int, default=5)
    p.add_argument("--clock", choices=("virtual", "wall"), default="virtual")
    p.add_argument("--fixed-key", action="store_true", help="the same sampling pattern every frame")
    p.add_argument("--video", action="store_true", help="also write session.mp4 (needs imageio-ffmpeg)")
    p.add_argument("-o", "--output", required=True, help="output directory")
    p.set_defaults(func=run)


def run(args) -> int:
    import fovjax
    from fovjax.foveate import Foveation
    from fovjax.render import RenderConfig, StereoRig

    if args.scene in fovjax.scenes.BUILTIN:
        scene = fovjax.scenes.BUILTIN[args.scene]()
    else:
        scene = fovjax.load_scene(args.scene)
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(scene), eye_width=args.width, eye_height=args.height
    )
    result = fovjax.run_session(
        scene,
        rig,
        gaze=args.gaze,
        head=args.head,
        foveation=Foveation(fovea_deg=args.fovea, periphery_deg=args.periphery, spp=args.spp),
        frames=args.frames,
        seconds=args.seconds,
        fps=args.fps,
        out=args.output,
        fresh_key_per_frame=not args.fixed_key,
        clock=args.clock,
        config=RenderConfig(max_depth=args.max_depth),
        video=args.video,
    )
    states = result.states()
    rays = sum(f.primary_rays + f.shadow_rays + f.reflection_rays for f in result.frames)
    render_s = sum(f.render_s for f in result.frames)
    print(
        f"{len(result.frames)} frames, {rays / len(result.frames) / 1e6:.3f} M rays per frame, "
        f"{render_s / len(result.frames):.2f} s per frame; tracking "
        + ", ".join(f"{s} {states.count(s)}" for s in ("ok", "holding", "degraded", "lost") if s in states)
    )
    print(f"wrote {result.out.resolve()}/ (frame_*.png, session.csv, session.json)")
    return 0
