"""`fovjax failures`: where foveation fails, written as CSV and charts per case (the options and
the set-up it shares with `fovjax stability` are here too)."""

from __future__ import annotations

import argparse

from fovjax import cli


def _resolution(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"a resolution is WIDTHxHEIGHT, got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"a resolution must be positive, got {text!r}")
    return w, h


def _common(p: argparse.ArgumentParser, output: str) -> None:
    p.add_argument("--scene", default="atrium", help="a built-in scene or a scene file")
    p.add_argument("--width", type=int, default=320, help="pixels per eye")
    p.add_argument("--height", type=int, default=256)
    p.add_argument("--max-depth", type=int, default=2, help="reflection bounces")
    cli.add_backend(p)
    p.add_argument("--fovea", type=float, default=10.0, help="fovea radius, degrees")
    p.add_argument("--periphery", type=float, default=20.0, help="periphery radius, degrees")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("-o", "--output", default=output)
    cli.add_regions(p)
    cli.add_size_check(p)


def register(sub: argparse._SubParsersAction) -> None:
    from fovjax.eval import FAILURE_CASES as CASES

    p = sub.add_parser(
        "failures",
        help="where foveation fails: corner gaze, tracker error, after a saccade, high spp, "
        "checkerboard, acuity models at an equal budget, scanpath flicker",
        description="Run each failure case and write NAME.csv and NAME.png per case and findings.csv "
        "into the output folder; print one finding per case.",
    )
    _common(p, "out/failures")
    cli.add_overwrite(p)
    p.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES))
    p.add_argument("--small", type=_resolution, default=(128, 96), help="per-eye resolution of high_spp")
    p.add_argument("--spp", type=int, nargs="+", default=[1, 16], help="samples per pixel for high_spp")
    p.add_argument(
        "--acuity-fit",
        metavar="JSON",
        default=None,
        help="the fitted linear-MAR curve the acuity models compare (a `fovjax fit` record; default the "
        "repository's fits/published_linear_mar.json, E2 2.35°); a missing file is an error",
    )
    p.set_defaults(func=run_failures)


def _validate_common(args) -> None:
    cli.scene(args.scene)
    cli.number(args.width, "--width", ge=1)
    cli.number(args.height, "--height", ge=1)
    cli.number(args.max_depth, "--max-depth", ge=0)
    cli.fovea_periphery(args.fovea, args.periphery, "--fovea/--periphery")
    cli.output(args.output, "-o", directory=True)


def validate_failures(args) -> None:
    """Every argument of `fovjax failures`, before anything is rendered."""
    from fovjax.eval import FITTED_MAR

    _validate_common(args)
    cli.backend(args.backend)
    cli.squares(args.spp, "--spp")
    fit = FITTED_MAR if args.acuity_fit is None else args.acuity_fit
    cli.input_file(fit, "--acuity-fit", suffixes=(".json",), text=True)
    cli.output_folder(args.output, "-o", failure_files(), overwrite=args.overwrite)
    cli.frame_size(args, args.width, args.height, 1)
    if "high_spp" in args.cases:
        width, height = args.small
        cli.frame_size(args, width, height, max(args.spp), option="--small")


def failure_files() -> tuple[str, ...]:
    """What `fovjax failures` writes into its folder: findings.csv, and NAME.csv and NAME.png
    per case; another run's are refused (--overwrite)."""
    from fovjax.eval import FAILURE_CASES

    return ("findings.csv", *(f"{case}.{ext}" for case in FAILURE_CASES for ext in ("csv", "png")))


def _setup(args):
    import fovjax
    from fovjax.foveate import Foveation
    from fovjax.render import RenderConfig, StereoRig

    name = {"cornell": "cornell_box"}.get(args.scene, args.scene)  # the alias `render` takes
    scene = fovjax.scenes.BUILTIN[name]() if name in fovjax.scenes.BUILTIN else fovjax.load_scene(name)
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(scene), eye_width=args.width, eye_height=args.height
    )
    foveation = cli.regions(Foveation(fovea_deg=args.fovea, periphery_deg=args.periphery), args, args.height)
    return scene, rig, foveation, RenderConfig(max_depth=args.max_depth, backend=args.backend)


def run_failures(args) -> int:
    from fovjax.eval import default_models, failure_cases

    validate_failures(args)
    models = default_models(args.acuity_fit)
    print(f"acuity models: {', '.join(models)}")
    scene, rig, foveation, config = _setup(args)
    report = failure_cases(
        scene,
        rig,
        foveation,
        cases=args.cases,
        config=config,
        small_resolution=args.small,
        high_spp_values=args.spp,
        models=models,
        progress=not args.no_progress,
    )
    with cli.deferred_interrupt():
        if args.overwrite:
            cli.clear_outputs(args.output, failure_files())
        paths = report.write(args.output)
        cli.wrote(*paths.values())
    for case in report.cases.values():
        print(f"{case.name} ({case.seconds:.0f} s): {case.finding}")
    print(f"wrote {paths['findings'].parent.resolve()}/")
    return 0
