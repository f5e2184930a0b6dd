"""`fovjax study`: the thesis's user study (pair, ramp and slider tests, appendix levels 5°/10°
to 15°/30°) answered by automatic observers from a `fovjax compare` table, or by people from
results files; written as figures 66-68 with their tables.

From measured metrics (FovVideoVDP JOD when the table has it, else FLIP):

    fovjax study --comparison out/compare -o out/study
    fovjax study --comparison out/compare/comparison.csv --metric flip --threshold 0.05 \\
        --spp 4 --model thesis --observers 15 --noise-sd 0.01 --seed 0 -o out/study

writes out/study/responses.csv (the results-file format, `RESULT_FIELDS`), pair_test.csv,
ramp_test.csv, slider_test.csv, majority.csv and fig66_pair_test.png, fig67_ramp_test.png,
fig68_slider_test.png, and prints per test the level the observers' majority accepts next to
the thesis's (12.5°/25°). For jod, d = 10 - mean JOD, seen when d > 1 (`JND_JOD`); for flip,
d = mean FLIP, seen when d > 0.05 (or --threshold).

From answers in the results-file format (.csv or .jsonl; several files are pooled; a folder
stands for its results files, e.g. the one `fovjax view --study` records into), with the
automatic observers of a comparison table beside them in the same figures (`--beside`):

    fovjax study --responses results/p01.csv results/p02.csv -o out/study
    fovjax study --responses out/study/responses.csv -o out/study_again
    fovjax study --responses study_dir --beside out/compare -o out/study_people

Answers recorded by `fovjax view --study` carry the durations the page actually showed: the
trials whose segments differ from the protocol by more than a display frame are listed and
written to timing.csv (`fovjax.eval.read_timing`).

From an animated sequence judged by FovVideoVDP in video mode (`fovjax.eval.video_study`; the
options and what is written: `fovjax.cli._video_study`):

    fovjax study --video [--scene atrium --width 160 --height 128 --frames 30 ...] -o out/video_study
"""

from __future__ import annotations

import argparse
from pathlib import Path

from . import _video_study as _video

# Options that only mean something with --comparison (their defaults, applied there).
_COMPARISON_DEFAULTS = {
    "metric": None,
    "threshold": None,
    "spp": 4,
    "model": None,
    "observers": 15,
    "noise_sd": 0.0,
    "seed": 0,
    "shuffle": False,
}


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def _non_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return value


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "study",
        help="the thesis's user study (pair, ramp, slider tests, figures 66-68) answered from a "
        "comparison table's metrics or from people's results files",
        description="Run the pair, ramp and slider tests at the appendix levels with automatic observers "
        "judging a `fovjax compare` metric (--comparison), or analyse answers in the results-file format "
        "(--responses); write the answers, the per-test tables and figures 66-68 into the output folder "
        "and print the level each test's majority accepts beside the thesis's 12.5°/25°.",
    )
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument(
        "--comparison",
        metavar="DIR_OR_CSV",
        help="comparison.csv written by `fovjax compare` (or its folder); every row is checked first "
        "(fovea_deg, periphery_deg, spp and the jod/flip cells), a bad cell is FILE:LINE and exit 2",
    )
    source.add_argument(
        "--responses",
        metavar="FILE_OR_DIR",
        nargs="+",
        help="results files (.csv/.jsonl, RESULT_FIELDS columns) or folders of them (fovjax view --study's)",
    )
    source.add_argument(
        "--video",
        action="store_true",
        help="render an animated sequence and judge it with FovVideoVDP in video mode (the study emulated)",
    )
    p.add_argument(
        "--beside",
        metavar="DIR_OR_CSV",
        help="with --responses: a comparison table whose automatic observers are drawn beside the people's "
        "answers in figures 66-68",
    )
    p.add_argument(
        "--metric",
        choices=("jod", "flip"),
        help="jod: d = 10 - FovVideoVDP JOD, threshold 1; flip: d = FLIP, threshold 0.05 "
        "(default: jod when the table has it, else flip)",
    )
    p.add_argument("--threshold", type=float, help="just-noticeable d (default: the metric's)")
    p.add_argument("--spp", type=int, help="samples per pixel of the rows to use (default 4, the thesis's)")
    p.add_argument("--model", help="acuity model of the rows to use (needed when the table has several)")
    p.add_argument("--observers", type=_positive_int, help="automatic observers (default 15, as the thesis)")
    p.add_argument(
        "--noise-sd",
        type=_non_negative,
        help="Gaussian noise on d per judgement, so observers differ (default 0: all answer alike)",
    )
    p.add_argument("--seed", type=int, help="seed of the observers' noise (each gets its own; default 0)")
    p.add_argument(
        "--shuffle",
        action="store_true",
        default=None,
        help="each observer its own trial order (from --seed) instead of the appendix's",
    )
    p.add_argument("-o", "--output", default="out/study")
    from fovjax import cli

    cli.add_overwrite(p)
    cli.add_size_check(p)
    _video.add_arguments(p)
    p.set_defaults(func=run)


# What `fovjax study` writes into its folder: another run's are refused (--overwrite).
STUDY_FILES = (
    "responses.csv",
    "observers_responses.csv",
    "timing.csv",
    "majority.csv",
    "*_test.csv",
    "*_test_observers.csv",
    "fig6?_*_test.png",
    "video_study.csv",
)


def _comparison_csv(text: str, option: str = "--comparison") -> Path:
    """A comparison table `fovjax compare` wrote: comparison.csv, or the folder holding it."""
    from fovjax import cli

    path = Path(text)
    if path.is_dir():
        path = path / "comparison.csv"
        if not path.is_file():
            raise cli.UsageError(f"{option} {text}: a folder without comparison.csv (`fovjax compare -o`)")
    elif not path.exists():
        raise cli.UsageError(f"{option} {text}: no such file or folder")
    elif path.suffix.lower() != ".csv":
        raise cli.UsageError(
            f"{option} {text}: a {path.suffix or 'file without a suffix'!r} file; expected comparison.csv "
            "as `fovjax compare` writes it (or its folder)"
        )
    return cli.input_file(path, option, text=True)


def validate(args) -> None:
    """Every argument of `fovjax study` and the files it names, before anything is read or
    written."""
    from fovjax import cli

    cli.seed(args.seed)
    if args.threshold is not None:
        cli.number(args.threshold, "--threshold", ge=0)
    if args.spp is not None:
        cli.squares(args.spp, "--spp")
    # Options that do not go together first, then the files they name.
    if args.beside is not None and args.responses is None:
        raise cli.UsageError(
            "--beside: only with --responses (the observers are drawn beside people's answers)"
        )
    given = [k for k in _COMPARISON_DEFAULTS if getattr(args, k) is not None]
    if args.responses is not None and given and args.beside is None:
        names = ", ".join("--" + k.replace("_", "-") for k in given)
        raise cli.UsageError(f"{names}: only with --comparison (--responses files already hold the answers)")
    _video.validate(args)
    for name in args.responses or ():
        if not Path(name).exists():
            raise cli.UsageError(f"--responses {name}: no such file or folder")
        if Path(name).is_file():
            cli.input_file(name, "--responses", suffixes=(".csv", ".jsonl"), text=True)
        elif not response_files(name):
            raise cli.UsageError(f"--responses {name}: a folder without results files (.jsonl/.csv)")
        else:
            for path in response_files(name):
                cli.input_file(path, "--responses", text=True)
    if args.comparison is not None:
        _comparison_csv(args.comparison)
    if args.beside is not None:
        _comparison_csv(args.beside, "--beside")
    cli.output_folder(args.output, "-o", STUDY_FILES, overwrite=args.overwrite)
    if args.video:
        # Every level's sequence and the reference's are kept for FovVideoVDP.
        spp = 4 if args.spp is None else args.spp
        cli.frame_size(args, args.width, args.height, spp, kept_images=args.frames * 6)


def response_files(name) -> list[Path]:
    """A --responses argument's results files: the file, or a folder's `*.jsonl`/`*.csv`."""
    from fovjax.eval import study_files

    path = Path(name)
    return study_files(path) if path.is_dir() else [path]


def _observers(args, levels):
    """The automatic observers of `--comparison` (or `--beside`) with the table's summary
    printed; returns them."""
    from fovjax.eval import (
        STUDY_METRICS,
        ObserverPanel,
        default_metric,
        observers_from_comparison,
        read_comparison,
    )

    option = "--comparison" if args.comparison is not None else "--beside"
    csv_path = _comparison_csv(args.comparison or args.beside, option)
    table, lines = read_comparison(csv_path)
    metric = args.metric
    if metric is None:
        metric = default_metric(table)
        why = (
            "the table has FovVideoVDP JOD"
            if metric == "jod"
            else "the table has no FovVideoVDP JOD (pyfvvdp was not installed for `fovjax compare`)"
        )
        print(f"note: metric {metric}: {why}; choose with --metric")
    observers = observers_from_comparison(
        table,
        metric=metric,
        spp=args.spp,
        model=args.model,
        observers=ObserverPanel(
            n=args.observers, noise_sd=args.noise_sd, threshold=args.threshold, seed=args.seed
        ),
        levels=levels,
        where=str(csv_path),
        lines=lines,
    )
    diff = observers[0].difference
    model = "" if diff.model is None else f", model {diff.model}"
    rule = f"{STUDY_METRICS[metric][0]}, seen when d > {diff.threshold:g}"
    print(f"{csv_path}: spp {diff.spp}{model}; {rule}")
    print(f"  {'level':>10s}  {'mean ' + metric:>10s}  {'d':>8s}  {'rows':>4s}  seen")
    for level in levels:
        seen = "yes" if diff.seen(level) else "no"
        print(
            f"  {f'{level[0]:g}/{level[1]:g}':>10s}  {diff.means[level]:10.4g}  "
            f"{diff.differences[level]:8.4g}  {diff.rows[level]:4d}  {seen}"
        )
    if args.noise_sd == 0 and all(diff.seen(level) for level in levels):
        # The slider cannot go past the last level: its answer then means "the best on
        # offer", not "equivalent to the reference".
        print(
            f"note: every level is seen (d > {diff.threshold:g}); the slider stops at the "
            "highest level, which is not an equivalence"
        )
    readings = sorted({str(r.get("regions") or "angle") for r in table})
    if readings != ["thesis"]:
        # The thesis's 12.5°/25° was chosen on its own regions, about twice the pixels per
        # threshold of fovjax's exact-angle ones on the 90° rig: not the same levels.
        print(
            f"note: the table's regions are {'/'.join(readings)} (a table without a regions column "
            "is angle), not the thesis's reading: the thesis column is not like-for-like; "
            "`fovjax compare --regions thesis` makes it so"
        )
    print(f"{len(observers)} observer(s), noise sd {args.noise_sd:g}, seed {args.seed}")
    return observers


def _timing(files) -> list[dict]:
    """The recorded answers' timings (`fovjax.eval.read_timing`), and say which trials were shown
    off the protocol by more than a frame; timing.csv is written from them later (`run`)."""
    from fovjax.eval import read_timing

    rows = [row for path in files for row in read_timing(path)]
    if not rows:
        return rows
    flagged = [r for r in rows if r["flagged"]]
    scales = sorted({r["time_scale"] for r in rows if r["time_scale"] is not None})
    print(
        f"timing: {len(flagged)} of {len(rows)} recorded answers had a segment shown off the protocol by "
        "more than a display frame" + (":" if flagged else "")
    )
    for r in flagged[:10]:
        print(f"  {r['file']}:{r['line']}: {r['participant']} {r['condition']}: {r['problems']}")
    if len(flagged) > 10:
        print(f"  ... and {len(flagged) - 10} more (timing.csv)")
    if scales != [1.0]:
        print(
            f"note: time scale(s) {', '.join(f'{x:g}' for x in scales)}: not the thesis's timings (testing)"
        )
    return rows


def _level_text(fovea: float | None, levels) -> str:
    if fovea is None:
        return "none (no level has a majority)"
    periphery = {f: p for f, p in levels}.get(fovea)
    return f"{fovea:g}°" if periphery is None else f"{fovea:g}°/{periphery:g}°"


def run(args) -> int:
    from fovjax import cli
    from fovjax.eval import (
        APPENDIX_LEVELS,
        MAJORITY_TESTS,
        THESIS_LEVEL,
        read_responses,
        run_study,
        study_majorities,
        write_csv,
        write_responses,
    )
    from fovjax.eval import write_study_report as report

    validate(args)
    if args.video:
        if args.overwrite:
            cli.clear_outputs(args.output, STUDY_FILES)
        return _video.run(args)
    levels = APPENDIX_LEVELS
    out = Path(args.output)
    for k, default in _COMPARISON_DEFAULTS.items():
        if getattr(args, k) is None:
            setattr(args, k, default)
    # Everything is read and checked first; nothing is written until all of it is.
    timing: list[dict] = []
    observers_beside = None
    if args.responses is not None:
        files = [f for name in args.responses for f in response_files(name)]
        responses = []
        for path in files:
            responses.extend(read_responses(path, levels=levels))
        if not responses:
            raise cli.UsageError(f"--responses {' '.join(args.responses)}: no answers in the file(s)")
        participants = len({r.participant for r in responses})
        print(f"read {len(responses)} answers from {participants} participant(s) in {len(files)} file(s)")
        timing = _timing(files)
        if args.beside is not None:
            observers = _observers(args, levels)
            observers_beside = run_study(observers, levels, seed=args.seed if args.shuffle else None)
    else:
        observers = _observers(args, levels)
        responses = run_study(observers, levels, seed=args.seed if args.shuffle else None)

    majorities = study_majorities(responses, levels)
    beside_majorities = None if observers_beside is None else study_majorities(observers_beside, levels)
    paths = {}
    with cli.deferred_interrupt():
        if args.overwrite:
            cli.clear_outputs(out, STUDY_FILES)
        if timing:
            paths["timing"] = write_csv(timing, out / "timing.csv")
            cli.wrote(paths["timing"])
        if observers_beside is not None:
            paths["observers"] = write_responses(observers_beside, out / "observers_responses.csv")
            cli.wrote(paths["observers"])
        if args.responses is None:
            paths["responses"] = write_responses(responses, out / "responses.csv")
            cli.wrote(paths["responses"])
        written = report(responses, out, levels=levels, beside=observers_beside)
        paths.update(written)
        cli.wrote(*written.values())
    thesis = _level_text(THESIS_LEVEL[0], levels)
    rows = []
    header = f"{'test':>10s}  {'majority accepts':<32s}  "
    if beside_majorities is not None:
        header += f"{'automatic observers':<32s}  "
    print(header + "thesis")
    for test in MAJORITY_TESTS:
        if test not in majorities:
            continue
        fovea = majorities[test]
        line = f"{test:>10s}  {_level_text(fovea, levels):<32s}  "
        row = {
            "test": test,
            "majority_fovea_deg": fovea,
            "majority_periphery_deg": None if fovea is None else dict(levels).get(fovea),
        }
        if beside_majorities is not None:
            auto = beside_majorities.get(test)
            line += f"{_level_text(auto, levels):<32s}  "
            row.update(
                observers_fovea_deg=auto,
                observers_periphery_deg=None if auto is None else dict(levels).get(auto),
            )
        print(line + thesis)
        row.update(thesis_fovea_deg=THESIS_LEVEL[0], thesis_periphery_deg=THESIS_LEVEL[1])
        rows.append(row)
    if rows:
        with cli.deferred_interrupt():
            paths["majority"] = write_csv(rows, out / "majority.csv")
            cli.wrote(paths["majority"])
    print(f"wrote {out.resolve()}/: {', '.join(sorted(p.name for p in paths.values()))}")
    return 0
