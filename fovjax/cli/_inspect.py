"""`fovjax inspect SCENE`: what a scene needs per region of a foveated frame (triangles per pixel
by eccentricity ring, radiance by reflection depth and by light), as a table or JSON."""

from __future__ import annotations

import argparse

from fovjax import cli

from ._render import SCENE_ALIASES, _gaze, _head


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "inspect",
        help="what a scene needs per region: triangles per pixel by ring, radiance by depth and light",
        description="For the thesis HMD at the scene's default viewpoint (or --width/--height per eye) "
        "and a gaze: triangles per pixel in each eccentricity ring per eye (triangle centroids in view, "
        "occluded included), and the share of radiance from each reflection depth (frames rendered at "
        "max depth 0..k, differenced) and from each light (one light at a time), in the fovea, the "
        "periphery and outside.",
    )
    p.add_argument("scene", help="atrium, cornell, spheres, or a path (OBJ, glTF/GLB, PLY)")
    p.add_argument("--width", type=int, default=320, help="pixels per eye (default 320)")
    p.add_argument("--height", type=int, default=256, help="pixels per eye (default 256)")
    p.add_argument("--triangles", type=int, default=262_000, help="atrium size (triangles)")
    p.add_argument(
        "--gaze",
        type=_gaze,
        default=((0.5, 0.5), (0.5, 0.5)),
        metavar="LX,LY,RX,RY",
        help="gaze per eye in normalised display coordinates, (0,0) top-left (default: the centres)",
    )
    p.add_argument(
        "--head", type=_head, default=(0.0, 0.0, 0.0), metavar="YAW,PITCH,ROLL", help="head pose in degrees"
    )
    p.add_argument("--fovea", type=float, default=5.0, help="fovea eccentricity in degrees (default 5)")
    cli.add_regions(p)
    p.add_argument("--periphery", type=float, default=10.0, help="periphery eccentricity (default 10)")
    p.add_argument("--max-depth", type=int, default=3, help="deepest reflection depth to split (default 3)")
    p.add_argument("--ring", type=float, default=5.0, help="eccentricity ring width in degrees (default 5)")
    p.add_argument("--spp", type=int, default=1, help="samples per pixel: 1, 4, 9, ... (default 1)")
    p.add_argument("--json", action="store_true", help="print the result as JSON instead of tables")
    cli.add_size_check(p)
    p.set_defaults(func=run)


def validate(args) -> None:
    """Every argument of `fovjax inspect`, before the scene is built or anything rendered."""
    cli.scene(args.scene, "SCENE")
    cli.number(args.width, "--width", ge=1)
    cli.number(args.height, "--height", ge=1)
    cli.number(args.triangles, "--triangles", ge=1)
    cli.head_gaze_fovea(args)
    cli.number(args.max_depth, "--max-depth", ge=0)
    cli.number(args.ring, "--ring", gt=0)
    cli.squares(args.spp, "--spp")
    # Full frames at max depth 0..k and per light, kept to be differenced (the lights are
    # not known before the scene is built: at least the depths' frames).
    cli.frame_size(args, args.width, args.height, args.spp, kinds=("full",), kept_images=args.max_depth + 2)


def run(args) -> int:
    validate(args)
    from pathlib import Path

    import fovjax
    from fovjax.eval import inspect_scene
    from fovjax.foveate import Foveation
    from fovjax.render import StereoRig

    name = SCENE_ALIASES.get(args.scene, args.scene)
    if name in fovjax.scenes.BUILTIN:
        kwargs = {"triangles": args.triangles} if name == "atrium" else {}
        scene = fovjax.scenes.BUILTIN[name](**kwargs)
    else:
        scene = fovjax.load_scene(Path(args.scene))
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(scene), eye_width=args.width, eye_height=args.height
    )
    result = inspect_scene(
        scene,
        rig,
        args.gaze,
        cli.regions(Foveation(fovea_deg=args.fovea, periphery_deg=args.periphery), args, args.height),
        head_pose=args.head,
        max_depth=args.max_depth,
        ring_deg=args.ring,
        spp=args.spp,
    )
    print(result.to_json() if args.json else result.table())
    return 0
