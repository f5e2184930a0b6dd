"""`fovjax fit-stability`: the acuity solvers' stability sweep, written as tables and a chart."""

from __future__ import annotations


def register(subparsers) -> None:
    s = subparsers.add_parser(
        "fit-stability",
        help="sweep solvers × starts × noise × sizes × ranges; write a table and chart",
    )
    s.add_argument("-o", "--output", default="fits/stability", help="output folder")
    s.add_argument("--runs", action="store_true", help="also write runs.csv, one row per run")
    s.add_argument("--seed", type=int, default=0)
    s.set_defaults(func=run_stability)


def run_stability(args) -> int:
    from fovjax import cli
    from fovjax.acuity import SweepConfig, write_sweep

    cli.output(args.output, "-o", directory=True)
    cli.seed(args.seed)
    with cli.deferred_interrupt():
        out = write_sweep(args.output, SweepConfig(seed=args.seed), write_runs=args.runs)
        cli.wrote(args.output)
    print(
        f"{out['runs']} fits in {out['seconds']:.1f} s; wrote {args.output}/summary.csv, "
        "by_solver_range.csv, "
        f"by_start.csv, stability.png"
    )
    print(
        f"{'solver':<20} {'ω_max':>6} {'ok':>6} "
        + " ".join(
            f"{k:>14}" for k in ("step_limit", "stalled", "diverged", "singular_step", "unidentifiable")
        )
    )
    for row in out["by_solver_range"]:
        print(
            f"{row['solver']:<20} {row['wmax']:>6g} {row['success_rate']:>6.1%} "
            + " ".join(
                f"{row[k]:>14}"
                for k in ("step_limit", "stalled", "diverged", "singular_step", "unidentifiable")
            )
        )
    return 0
