"""`fovjax view --xr`: the foveated frames in a WebXR headset (`fovjax.view.XRViewer`).

The page offers "Enter VR"; in the immersive session the headset sends its pose and both eyes'
views every display frame, frames are rendered for the newest (the rig built from the views, at
the headset's resolution times `--xr-scale`), and the page draws the newest frame reprojected to
the current head pose. The gaze comes from `--gaze SPEC` (its gaze in the headset display's
coordinates) or, without one, each eye's view centre (fixed foveation). One line per frame is
logged: render time and rate, display rate, the rendered head pose's age at display and the
reprojection angle.
"""

from __future__ import annotations

import logging

from fovjax import cli

DEFAULT_SCALE = 1.0
MAX_SCALE = 4.0


def add_arguments(p) -> None:
    p.add_argument(
        "--xr",
        action="store_true",
        help="serve the headset page instead: in a WebXR headset (Enter VR) the frames follow the headset's "
        "pose, reprojected to the newest; gaze from --gaze or the view centre (see 'In a headset')",
    )
    p.add_argument(
        "--xr-scale",
        type=float,
        help=f"with --xr: rendered pixels per headset pixel along each side (default {DEFAULT_SCALE:g}: the "
        "headset's own resolution; e.g. 0.25 on a CPU)",
    )


def validate(args) -> None:
    """The --xr arguments (before `fovjax view`'s own defaults are filled in)."""
    if not args.xr:
        if args.xr_scale is not None:
            raise cli.UsageError("--xr-scale: only with --xr")
        return
    if args.study is not None:
        raise cli.UsageError(
            f"--xr with --study {args.study}: the study plays pre-rendered clips on the 2D page; choose one"
        )
    given = [
        name for name, value in (("--width", args.width), ("--height", args.height)) if value is not None
    ]
    if given:
        raise cli.UsageError(
            f"{'/'.join(given)} with --xr: the size per eye is the headset's own times --xr-scale"
        )
    if args.head != "keys":
        raise cli.UsageError(f"--head {args.head} with --xr: the head pose comes from the headset")
    if args.regions != "angle":
        raise cli.UsageError(
            f"--regions {args.regions} with --xr: 'thesis' is the SX111 display's planar reading; a "
            "headset's regions are measured as angles (--regions angle)"
        )
    if args.xr_scale is None:
        args.xr_scale = DEFAULT_SCALE
    cli.number(args.xr_scale, "--xr-scale", gt=0, le=MAX_SCALE)


def make(args, scene, foveation, config, on_save):
    """The renderer and the server of `fovjax view --xr` (the gaze source opened: an unreachable
    tracker is an error before anything is served)."""
    from fovjax.view import XRRenderer, XRViewer

    renderer = XRRenderer(
        scene,
        foveation,
        scale=args.xr_scale,
        config=config,
        gaze=None if args.gaze == "mouse" else args.gaze,
        seed=0 if args.seed is None else args.seed,
    )
    renderer.open()
    # The per-frame lines and the gaze: said in the log whether or not --verbose.
    logging.getLogger("fovjax.view.xr").setLevel(logging.INFO)
    logging.getLogger("fovjax.view.xr").info("gaze: %s", renderer.gaze_description)
    viewer = XRViewer(renderer, host=args.host, port=args.port, save_dir=args.save_dir, on_save=on_save)
    return renderer, viewer
