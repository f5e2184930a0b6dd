"""`fovjax fit`: fit an acuity model to a CSV, with its uncertainty and a chart."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path


def _fixed(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"--fix expects NAME=VALUE, got {text!r}")
    try:
        return name.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--fix {text!r}: {value!r} is not a number") from None


# Spelled out so that building the `fovjax` parser does not import jax/optimistix; a test checks
# them against `fovjax.acuity.MODEL_FAMILIES` and `SOLVERS`.
MODEL_NAMES = ("exponential", "linear_mar", "power_mar")
SOLVER_NAMES = ("levenberg_marquardt", "gauss_newton", "dogleg", "bfgs")


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "fit",
        help="fit an acuity model to a CSV and write fits/NAME.json and fits/NAME.png",
        description="Fit an acuity model V(ω) to a CSV in the acuity schema "
        "(eccentricity_deg, acuity|mar_arcmin, sd, n, condition, source).",
    )
    p.add_argument("data", help="CSV file")
    p.add_argument("--model", default="exponential", choices=MODEL_NAMES)
    p.add_argument("--solver", default="levenberg_marquardt", choices=SOLVER_NAMES)
    p.add_argument(
        "--fix",
        type=_fixed,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="hold a parameter fixed (repeatable), e.g. --fix a=1 for relative acuity",
    )
    p.add_argument("--condition", default=None, help="the condition to fit when the file has several")
    p.add_argument(
        "--mar-reference",
        default="1",
        help="for mar_arcmin files: reference MAR in arcmin (1 = decimal acuity) or 'fovea'",
    )
    p.add_argument(
        "--posterior",
        nargs="?",
        const="emcee",
        default=None,
        choices=("emcee", "bootstrap"),
        help="add posterior intervals and band (emcee by default, or bootstrap)",
    )
    p.add_argument("--nsteps", type=int, default=5000, help="emcee steps per walker")
    p.add_argument("--nwalkers", type=int, default=32)
    p.add_argument("--n-boot", type=int, default=1000, help="bootstrap resamples")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--compare", action="store_true", help="also rank exponential, linear_mar, power_mar")
    p.add_argument("--plot-max", type=float, default=None, help="draw the curves out to this eccentricity")
    p.add_argument(
        "-o", "--output", default=None, help="output stem, e.g. fits/NAME (default fits/<csv stem>)"
    )
    p.set_defaults(func=run_fit)


def _command(args) -> str:
    parts = ["fovjax", "fit", args.data, "--model", args.model, "--solver", args.solver]
    for name, value in args.fix:
        parts += ["--fix", f"{name}={value:g}"]
    if args.condition is not None:
        parts += ["--condition", args.condition]
    if args.mar_reference != "1":
        parts += ["--mar-reference", args.mar_reference]
    if args.posterior == "emcee":
        parts += ["--posterior", "emcee", "--nsteps", str(args.nsteps), "--nwalkers", str(args.nwalkers)]
    elif args.posterior == "bootstrap":
        parts += ["--posterior", "bootstrap", "--n-boot", str(args.n_boot)]
    if args.compare:
        parts.append("--compare")
    if args.plot_max is not None:
        parts += ["--plot-max", f"{args.plot_max:g}"]
    parts += ["--seed", str(args.seed), "-o", args.output]
    return shlex.join(parts)


def validate_fit(args) -> None:
    """Every argument of `fovjax fit`, before the data are fitted."""
    import math

    from fovjax import cli
    from fovjax.acuity import MODEL_FAMILIES

    cli.input_file(args.data, "data", suffixes=(".csv",), text=True)
    family = MODEL_FAMILIES[args.model]
    for name, value in args.fix:
        if name not in family.param_names:
            raise cli.UsageError(
                f"--fix {name}={value:g}: {args.model} has no parameter {name!r} "
                f"(parameters: {', '.join(family.param_names)})"
            )
        cli.number(value, f"--fix {name}")
    if len(dict(args.fix)) == len(family.param_names):
        raise cli.UsageError(f"--fix: every parameter of {args.model} is fixed; nothing is left to fit")
    if args.mar_reference != "fovea":
        try:
            reference = float(args.mar_reference)
        except ValueError:
            reference = math.nan
        if not (math.isfinite(reference) and reference > 0):
            raise cli.UsageError(
                f"--mar-reference {args.mar_reference!r}: expected a MAR in arcmin > 0 or 'fovea'"
            )
    free = len(family.param_names) - len(dict(args.fix))
    cli.number(args.nsteps, "--nsteps", ge=1)
    cli.number(args.nwalkers, f"--nwalkers (2 per free parameter, {free} free)", ge=2 * free)
    cli.number(args.n_boot, "--n-boot", ge=2)
    cli.seed(args.seed)
    if args.plot_max is not None:
        cli.number(args.plot_max, "--plot-max", gt=0)
    stem = Path(args.output)
    for suffix in (".json", ".png", "_corner.png"):
        cli.output(stem.with_name(stem.name + suffix), "-o")


def run_fit(args) -> int:
    from fovjax import cli
    from fovjax.acuity import (
        AcuityDataError,
        EmceeOptions,
        FitError,
        PosteriorConvergenceError,
        bootstrap,
        compare,
        fit,
        fit_record,
        load_csv,
        plot_corner,
        plot_fit,
        sample_posterior,
        save_fit,
    )

    if args.output is None:
        args.output = str(Path("fits") / Path(args.data).stem)
    validate_fit(args)
    fixed = dict(args.fix)
    ref = args.mar_reference if args.mar_reference == "fovea" else float(args.mar_reference)
    try:
        data = load_csv(args.data, mar_reference_arcmin=ref)
    except AcuityDataError as err:  # a bad input file: FILE:LINE, exit status 2
        raise cli.UsageError(str(err)) from None
    if args.condition is not None and args.condition not in data.conditions:
        raise cli.UsageError(
            f"--condition {args.condition!r}: {args.data} has no such condition "
            f"(conditions: {', '.join(map(repr, data.conditions))})"
        )
    if args.condition is None and len(data.conditions) > 1:
        raise cli.UsageError(
            f"{args.data} has {len(data.conditions)} conditions "
            f"({', '.join(map(repr, data.conditions))}); choose one with --condition"
        )
    try:
        result = fit(data, args.model, solver=args.solver, fixed=fixed, condition=args.condition)
    except AcuityDataError as err:  # the data cannot fit this model (too few points, ...): the input
        raise cli.UsageError(str(err)) from None
    except FitError as err:  # the solver failed on valid data
        print(f"fovjax fit: {err}", file=sys.stderr)
        return 1
    print(result.summary())
    samples = None
    try:
        if args.posterior == "emcee":
            samples = sample_posterior(
                result.data,
                result.family,
                start=result,
                sampler=EmceeOptions(nwalkers=args.nwalkers, nsteps=args.nsteps),
                seed=args.seed,
            )
        elif args.posterior == "bootstrap":
            samples = bootstrap(result.data, result.family, start=result, n_boot=args.n_boot, seed=args.seed)
    except PosteriorConvergenceError as err:
        print(f"fovjax fit: {err}", file=sys.stderr)
        return 1
    if samples is not None:
        lo_hi = samples.intervals()
        print(
            f"  {samples.method} ({samples.draws.shape[0]} draws): "
            + ", ".join(
                f"{k} = {samples.median[k]:.6g} [{lo_hi[k][0]:.6g}, {lo_hi[k][1]:.6g}]" for k in samples.names
            )
        )
    comparison = None
    if args.compare:
        cmp = compare(result.data, fixed={args.model: fixed} if fixed else None, solver=args.solver)
        print(cmp.table())
        comparison = cmp.to_dict()
    stem = Path(args.output)
    record = fit_record(result, samples, comparison, command=_command(args))
    with cli.deferred_interrupt():
        json_path = save_fit(stem.with_name(stem.name + ".json"), record)
        cli.wrote(json_path)
    with cli.deferred_interrupt():
        png = plot_fit(result, stem.with_name(stem.name + ".png"), samples=samples, omega_max=args.plot_max)
        cli.wrote(png)
    written = [json_path, png]
    if samples is not None and len(samples.names) > 1:
        with cli.deferred_interrupt():
            written.append(plot_corner(samples, stem.with_name(stem.name + "_corner.png"), laplace=result))
            cli.wrote(written[-1])
    print("wrote " + ", ".join(map(str, written)))
    return 0
