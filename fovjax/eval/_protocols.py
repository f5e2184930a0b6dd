"""The thesis's user study (chapter 5.2 and its appendix): pair, ramp and slider tests, their
trial sequences, a results-file format, the analysis behind figures 66-68, and an automatic
observer that answers from a perceptual metric so the study also runs without people.

Levels (appendix): (fovea, periphery) = (5°, 10°), (7.5°, 15°), (10°, 20°), (12.5°, 25°),
(15°, 30°); Sponza, SPP 4, the NVIS SX111 (2560x1024 for both eyes), 15 participants.

- Pair test: for each level in increasing order, the non-foveated render then the foveated
  one, then the foveated then the non-foveated, separated by 0.5 s of black (10 trials). Answer:
  "first" (better), "second" (better) or "same".
- Ramp test: after the non-foveated reference, the level ramps up (5° -> 15°) in 5 steps of 5 s
  each, then down (15° -> 5°). Each step is answered "increase", "decrease" or "same".
  The appendix prints the third step of the downward ramp as (10°, 10°); every other listing of
  that level in the thesis (the upward ramp, tables 2-5, the pair test, chapter 5.2's "periphery
  levels from 10° to 30°") pairs 10° with 20°, so the sequence here uses (10°, 20°).
- Slider test: from (5°, 10°) the participant moves up or down the levels, showing the
  reference when they like, and reports the lowest level equivalent to the reference. The
  answer is that level's fovea in degrees, e.g. "12.5".

With `seed=None` the generators give the appendix's order exactly; with a seed, the pair trials
are shuffled and the ramp's two directions come in a random order (steps within a ramp keep
their order: that is what makes it a ramp).

Timings (`presentation`): the pair's two stimuli are separated by `PAIR_GAP_S` = 0.5 s of black;
each ramp step is shown `RAMP_STEP_S` = 5 s, the steps "separated by a short interval of black"
(chapter 5.2 gives no length: `RAMP_GAP_S`, the pair's 0.5 s). The thesis gives no length for a
pair's "short animated sequences": `PAIR_STIMULUS_S` is the ramp's step, so each level is seen as
long in both tests; the slider's reference is shown as long (`SLIDER_REFERENCE_S`).

Results file: one row per answer, CSV (`.csv`) or JSON lines (`.jsonl`), columns
`RESULT_FIELDS`: participant, test, trial (position in that participant's sequence of the test),
condition (a readable label, checked against the other columns on reading), fovea_deg,
periphery_deg, order (pair: reference_first / foveated_first), direction (ramp: up / down),
step (ramp: 0-4), answer, time_s (seconds from the stimulus's end to the answer; empty for the
automatic observer).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import warnings
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np

_T = TypeVar("_T")

APPENDIX_LEVELS: tuple[tuple[float, float], ...] = (
    (5.0, 10.0),
    (7.5, 15.0),
    (10.0, 20.0),
    (12.5, 25.0),
    (15.0, 30.0),
)
TESTS = ("pair", "ramp", "slider")
PAIR_ORDERS = ("reference_first", "foveated_first")
RAMP_DIRECTIONS = ("up", "down")
PAIR_ANSWERS = ("first", "second", "same")
RAMP_ANSWERS = ("increase", "decrease", "same")
PAIR_GAP_S = 0.5  # black between a pair's two sequences (chapter 5.2)
RAMP_STEP_S = 5.0  # each of the ramp's 5 steps (chapter 5.2)
RAMP_GAP_S = PAIR_GAP_S  # "a short interval of black" between ramp steps: no length given
PAIR_STIMULUS_S = RAMP_STEP_S  # a pair's "short animated sequences": no length given
SLIDER_REFERENCE_S = RAMP_STEP_S  # the slider's non-foveated reference, shown first
SEGMENT_KINDS = ("black", "reference", "foveated")
RESULT_FIELDS = (
    "participant",
    "test",
    "trial",
    "condition",
    "fovea_deg",
    "periphery_deg",
    "order",
    "direction",
    "step",
    "answer",
    "time_s",
)


class ResultsFileError(ValueError):
    """A results file has a bad row (the message names the file, line and field)."""


def _level_label(fovea: float, periphery: float) -> str:
    return f"{fovea:g}/{periphery:g}"


def _check_levels(levels, where: str) -> tuple[tuple[float, float], ...]:
    out = tuple((float(f), float(p)) for f, p in levels)
    if not out:
        raise ValueError(f"{where}: levels must not be empty")
    for f, p in out:
        if not (math.isfinite(f) and math.isfinite(p) and 0 <= f <= p):
            raise ValueError(
                f"{where}: each level must be (fovea, periphery) with 0 <= fovea <= periphery, got {(f, p)}"
            )
    if any(b[0] <= a[0] for a, b in zip(out, out[1:], strict=False)):
        raise ValueError(f"{where}: levels must be in increasing order of fovea, got {out}")
    return out


@dataclass(frozen=True)
class Trial:
    """One trial: which test, its position in the sequence, the foveation level shown (for the
    slider, the starting level), and the pair's order or the ramp's direction and step."""

    test: str
    index: int
    fovea_deg: float
    periphery_deg: float
    order: str | None = None
    direction: str | None = None
    step: int | None = None
    levels: tuple[tuple[float, float], ...] = APPENDIX_LEVELS  # the slider's range

    def __post_init__(self):
        if self.test not in TESTS:
            raise ValueError(f"Trial.test must be one of {TESTS}, got {self.test!r}")
        if (self.test == "pair") != (self.order is not None) or (
            self.order is not None and self.order not in PAIR_ORDERS
        ):
            raise ValueError(
                f"Trial: a pair trial needs order in {PAIR_ORDERS} (and only a pair trial), "
                f"got {self.order!r}"
            )
        ramp = self.test == "ramp"
        if ramp != (self.direction is not None) or ramp != (self.step is not None):
            raise ValueError(
                "Trial: a ramp trial needs direction and step (and only a ramp trial), "
                f"got {self.direction!r}, {self.step!r}"
            )
        if ramp and self.direction not in RAMP_DIRECTIONS:
            raise ValueError(f"Trial.direction must be one of {RAMP_DIRECTIONS}, got {self.direction!r}")

    @property
    def level(self) -> tuple[float, float]:
        return (self.fovea_deg, self.periphery_deg)

    @property
    def choices(self) -> tuple[str, ...]:
        if self.test == "pair":
            return PAIR_ANSWERS
        if self.test == "ramp":
            return RAMP_ANSWERS
        return tuple(f"{f:g}" for f, _ in self.levels)

    @property
    def condition(self) -> str:
        level = _level_label(self.fovea_deg, self.periphery_deg)
        if self.test == "pair":
            assert self.order is not None  # a pair trial has an order (checked when made)
            return f"pair {level} {self.order.replace('_', '-')}"
        if self.test == "ramp":
            return f"ramp {self.direction} step {self.step} {level}"
        return f"slider from {level}"


@dataclass(frozen=True)
class Segment:
    """One part of a trial's presentation: black, the non-foveated reference, or the foveated
    sequence at `level`, for `seconds` (None: until the participant acts, the slider's level)."""

    kind: str
    seconds: float | None
    level: tuple[float, float] | None = None

    def __post_init__(self):
        if self.kind not in SEGMENT_KINDS:
            raise ValueError(f"Segment.kind must be one of {SEGMENT_KINDS}, got {self.kind!r}")
        if (self.kind == "foveated") != (self.level is not None):
            raise ValueError(
                f"Segment: a level goes with a foveated segment only, got {self.kind!r}, {self.level}"
            )
        if self.seconds is not None and not (math.isfinite(self.seconds) and self.seconds > 0):
            raise ValueError(f"Segment.seconds must be > 0 or None, got {self.seconds}")

    @property
    def label(self) -> str:
        return self.kind if self.level is None else f"foveated {_level_label(*self.level)}"


def presentation(
    trial: Trial, *, previous: Trial | None = None, resumed: bool = False
) -> tuple[Segment, ...]:
    """What a trial shows, in order, with the protocol's timings (module docstring). Every trial
    starts from black, so consecutive trials are separated by a gap as the thesis's were.

    - pair: black, first sequence, black, second sequence (`order` says which is the reference);
    - ramp: the first step of a direction follows the non-foveated reference (black, reference,
      black, step); a later step follows the step before it, already shown (black, step) --
      except when `resumed` (the first trial after an interrupted session), when `previous`,
      the step before, is shown again first, since the answer compares with it;
    - slider: black, the reference, black, then the starting level until the participant acts.
    """
    gap = Segment("black", PAIR_GAP_S if trial.test == "pair" else RAMP_GAP_S)
    level = Segment("foveated", None, trial.level)
    if trial.test == "pair":
        stimulus = dataclasses.replace(level, seconds=PAIR_STIMULUS_S)
        reference = Segment("reference", PAIR_STIMULUS_S)
        first, second = (reference, stimulus) if trial.order == "reference_first" else (stimulus, reference)
        return (gap, first, gap, second)
    if trial.test == "ramp":
        step = dataclasses.replace(level, seconds=RAMP_STEP_S)
        if trial.step == 0:
            return (gap, Segment("reference", RAMP_STEP_S), gap, step)
        if resumed:
            if previous is None or previous.test != "ramp" or previous.direction != trial.direction:
                raise ValueError(
                    f"presentation: resuming at {trial.condition!r} needs the step before it in the same "
                    "ramp, "
                    f"got {None if previous is None else previous.condition!r}"
                )
            return (gap, Segment("foveated", RAMP_STEP_S, previous.level), gap, step)
        return (gap, step)
    return (gap, Segment("reference", SLIDER_REFERENCE_S), gap, level)


SLIDER_ACTIONS = ("lower", "higher", "reference")


def slider_presentation(
    trial: Trial, actions: Sequence[str]
) -> tuple[tuple[Segment, ...], tuple[float, float]]:
    """A slider trial's segments after the participant's `actions` (each one of
    `SLIDER_ACTIONS`), in order, and the level shown last: `presentation`'s, then per "lower" or
    "higher" black and the next level down or up, per "reference" black, the reference
    (`SLIDER_REFERENCE_S`), black and the level again. A step past either end is a ValueError."""
    if trial.test != "slider":
        raise ValueError(f"slider_presentation: {trial.condition!r} is not a slider trial")
    segments = list(presentation(trial))
    gap = segments[0]
    k = trial.levels.index(trial.level)
    for n, action in enumerate(actions):
        if action not in SLIDER_ACTIONS:
            raise ValueError(f"slider action {n}: {action!r} is not one of {SLIDER_ACTIONS}")
        if action == "reference":
            segments += [gap, Segment("reference", SLIDER_REFERENCE_S), gap]
        else:
            k += 1 if action == "higher" else -1
            if not 0 <= k < len(trial.levels):
                raise ValueError(f"slider action {n}: {action!r} steps past the last level")
            segments.append(gap)
        segments.append(Segment("foveated", None, trial.levels[k]))
    return tuple(segments), trial.levels[k]


def pair_trials(levels=APPENDIX_LEVELS, *, seed: int | None = None) -> list[Trial]:
    """The pair test: each level twice, reference first then foveated first, levels in
    increasing order (the appendix); shuffled when `seed` is given."""
    levels = _check_levels(levels, "pair_trials")
    specs = [(f, p, order) for f, p in levels for order in PAIR_ORDERS]
    if seed is not None:
        specs = [specs[i] for i in np.random.default_rng(seed).permutation(len(specs))]
    return [Trial("pair", i, f, p, order=o) for i, (f, p, o) in enumerate(specs)]


def ramp_trials(levels=APPENDIX_LEVELS, *, seed: int | None = None) -> list[Trial]:
    """The ramp test: the levels upwards, then downwards, one trial per step (the appendix);
    with a `seed`, the two directions in a random order."""
    levels = _check_levels(levels, "ramp_trials")
    runs = [("up", levels), ("down", levels[::-1])]
    if seed is not None and np.random.default_rng(seed).random() < 0.5:
        runs.reverse()
    trials = []
    for direction, seq in runs:
        for step, (f, p) in enumerate(seq):
            trials.append(Trial("ramp", len(trials), f, p, direction=direction, step=step))
    return trials


def slider_trial(levels=APPENDIX_LEVELS, *, start: int = 0) -> Trial:
    """The slider test: one trial starting at `levels[start]` (the appendix: the lowest)."""
    levels = _check_levels(levels, "slider_trial")
    if not 0 <= start < len(levels):
        raise ValueError(f"slider_trial: start {start} is not an index into {len(levels)} levels")
    f, p = levels[start]
    return Trial("slider", 0, f, p, levels=levels)


@dataclass(frozen=True)
class Response:
    """One answer to one trial. `time_s`: seconds from the stimulus's end to the answer (None
    when not measured, e.g. for the automatic observer)."""

    participant: str
    trial: Trial
    answer: str
    time_s: float | None = None

    def __post_init__(self):
        if not str(self.participant):
            raise ValueError("Response.participant must not be empty")
        if self.answer not in self.trial.choices:
            raise ValueError(
                f"Response: answer {self.answer!r} to {self.trial.condition!r} is not one of "
                f"{self.trial.choices}"
            )
        if self.time_s is not None and not (math.isfinite(self.time_s) and self.time_s >= 0):
            raise ValueError(f"Response.time_s must be a time >= 0 in seconds or None, got {self.time_s}")

    def row(self) -> dict:
        t = self.trial
        return {
            "participant": str(self.participant),
            "test": t.test,
            "trial": t.index,
            "condition": t.condition,
            "fovea_deg": t.fovea_deg,
            "periphery_deg": t.periphery_deg,
            "order": t.order,
            "direction": t.direction,
            "step": t.step,
            "answer": self.answer,
            "time_s": self.time_s,
        }


def write_responses(responses: Iterable[Response], path) -> Path:
    """Write answers as CSV (`.csv`) or JSON lines (`.jsonl`), columns `RESULT_FIELDS`."""
    path = Path(path)
    rows = [r.row() for r in responses]
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".jsonl":
        with path.open("w") as fh:
            for row in rows:
                fh.write(json.dumps(row) + "\n")
    elif path.suffix == ".csv":
        with path.open("w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=RESULT_FIELDS)
            writer.writeheader()
            for row in rows:
                writer.writerow({k: "" if v is None else v for k, v in row.items()})
    else:
        raise ValueError(f"write_responses: {path}: use a .csv or .jsonl file")
    return path


def _optional_field(row: dict, where: str, name: str, convert: Callable[[str], _T]) -> _T | None:
    """`row[name]` converted, None where it is missing or empty; a ResultsFileError naming the
    field, the value and `where` when it does not convert."""
    value = row.get(name)
    if value is None or value == "":
        return None
    try:
        return convert(value)
    except (TypeError, ValueError) as err:
        raise ResultsFileError(f"{where}: field {name!r}: bad value {value!r} ({err})") from None


def _field(row: dict, where: str, name: str, convert: Callable[[str], _T]) -> _T:
    """`_optional_field` that must be there."""
    value = _optional_field(row, where, name, convert)
    if value is None:
        raise ResultsFileError(f"{where}: field {name!r} is missing")
    return value


# The field readers are module functions, not closures of `_parse_row`: a closure is a new
# function per row (and, under the suite's type checks, a new checked wrapper per row).
def _parse_row(row: dict, where: str, levels) -> Response:
    missing = [k for k in RESULT_FIELDS if k not in row]
    if missing:
        raise ResultsFileError(f"{where}: missing columns {missing}")
    try:
        trial = Trial(
            test=_field(row, where, "test", str),
            index=_field(row, where, "trial", int),
            fovea_deg=_field(row, where, "fovea_deg", float),
            periphery_deg=_field(row, where, "periphery_deg", float),
            order=_optional_field(row, where, "order", str),
            direction=_optional_field(row, where, "direction", str),
            step=_optional_field(row, where, "step", int),
            levels=levels,
        )
        if trial.condition != row["condition"]:
            raise ValueError(
                f"condition {row['condition']!r} disagrees with the other columns ({trial.condition!r})"
            )
        return Response(
            _field(row, where, "participant", str),
            trial,
            _field(row, where, "answer", str),
            _optional_field(row, where, "time_s", float),
        )
    except ResultsFileError:
        raise
    except ValueError as err:
        raise ResultsFileError(f"{where}: {err}") from None


def jsonl_rows(path) -> list[tuple[int, dict]]:
    """(line number, object) per line of a JSON-lines results file, blank lines skipped. A last
    line that is cut off (no newline at its end, not JSON: the writer stopped inside it, as a
    crash mid-answer leaves it) is dropped with a warning naming it, as `fovjax view --study`
    does when it resumes; any other line that is not a JSON object is a ResultsFileError."""
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    lines = text.split("\n")
    rows = []
    for line_no, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except json.JSONDecodeError as err:
            if line_no == len(lines) and not text.endswith("\n"):
                warnings.warn(
                    f"{path}:{line_no}: the last line is cut off (the writer stopped inside it); left out",
                    stacklevel=2,
                )
                break
            raise ResultsFileError(f"{path}:{line_no}: not JSON ({err})") from None
        if not isinstance(row, dict):
            raise ResultsFileError(f"{path}:{line_no}: expected a JSON object per line")
        rows.append((line_no, row))
    return rows


def read_responses(path, *, levels=APPENDIX_LEVELS) -> list[Response]:
    """Read a results file written by `write_responses` (or by hand, or by a study UI), checking
    every row (a cut-off last line of a .jsonl is left out with a warning, `jsonl_rows`).
    `levels` gives the slider's range (its answers must be one of these foveas)."""
    path = Path(path)
    levels = _check_levels(levels, "read_responses")
    out = []
    if path.suffix == ".jsonl":
        for line_no, row in jsonl_rows(path):
            row = {k: ("" if v is None else v) for k, v in row.items()}
            out.append(_parse_row(row, f"{path}:{line_no}", levels))
    elif path.suffix == ".csv":
        with path.open(newline="") as fh:
            reader = csv.DictReader(fh)
            missing = [k for k in RESULT_FIELDS if k not in (reader.fieldnames or ())]
            if missing:  # the header's fault, said at the header
                raise ResultsFileError(
                    f"{path}:1: missing columns {missing}; expected a results file with the columns "
                    f"{', '.join(RESULT_FIELDS)}"
                )
            for line_no, row in enumerate(reader, 2):
                out.append(_parse_row(row, f"{path}:{line_no}", levels))
    else:
        raise ValueError(f"read_responses: {path}: use a .csv or .jsonl file")
    return out


# --- the automatic observer ------------------------------------------------------------------


DECISION_RULE = """\
d = difference(trial): the metric's difference between the foveated and the full render at the
trial's level (larger = more visible: e.g. 10 - FovVideoVDP JOD, or mean FLIP). A difference is
seen when d + e > threshold, e ~ Normal(0, noise_sd) drawn afresh per judgement (e = 0 when
noise_sd = 0, the default: a deterministic observer).
- pair: not seen -> "same"; seen -> the reference is better: "first" if it came first, else
  "second".
- ramp: not seen -> "same"; seen -> "increase" if d is below that of the stimulus before it in
  the ramp, else "decrease" (the first step follows the reference, d = 0, so it is "decrease").
- slider: from the starting level upwards, the first level whose difference is not seen; if
  every level's is seen, the highest level (the slider's end)."""


@dataclass(frozen=True)
class MetricObserver:
    """An automatic participant that answers each trial from a perceptual metric by
    `DECISION_RULE`. `difference(trial)` returns the metric difference from the full render
    for the trial's level (for the slider it is called with a trial per level visited);
    `threshold` is the just-noticeable value of that difference (for 10 - JOD, `JND_JOD` = 1).
    With `noise_sd` > 0, the observer's detections follow a cumulative-Gaussian psychometric
    function of d centred on the threshold, seeded by `seed`."""

    difference: Callable[[Trial], float]
    threshold: float
    name: str = "auto"
    noise_sd: float = 0.0
    seed: int | None = None

    def __post_init__(self):
        if not callable(self.difference):
            raise ValueError(
                f"MetricObserver.difference must be callable (Trial -> float), got {self.difference!r}"
            )
        if not math.isfinite(self.threshold):
            raise ValueError(f"MetricObserver.threshold must be finite, got {self.threshold}")
        if not (math.isfinite(self.noise_sd) and self.noise_sd >= 0):
            raise ValueError(f"MetricObserver.noise_sd must be >= 0, got {self.noise_sd}")

    def _d(self, trial: Trial) -> float:
        d = float(self.difference(trial))
        if not math.isfinite(d):
            raise ValueError(
                f"MetricObserver {self.name!r}: difference for {trial.condition!r} is {d}, not a number"
            )
        return d

    def answer(self, trials: Sequence[Trial]) -> list[Response]:
        """Answer a sequence of trials (any mix of tests) in order."""
        rng = np.random.default_rng(self.seed)

        def seen(d: float) -> bool:
            noise = rng.normal(0.0, self.noise_sd) if self.noise_sd > 0 else 0.0
            return d + noise > self.threshold

        out = []
        previous: dict[str, float] = {}  # ramp direction -> d of the last step shown
        for trial in trials:
            if trial.test == "pair":
                if not seen(self._d(trial)):
                    answer = "same"
                else:
                    answer = "first" if trial.order == "reference_first" else "second"
            elif trial.test == "ramp":
                assert trial.direction is not None  # a ramp trial has a direction (checked when made)
                d = self._d(trial)
                d_before = 0.0 if trial.step == 0 else previous.get(trial.direction, 0.0)
                previous[trial.direction] = d
                if not seen(d):
                    answer = "same"
                else:
                    answer = "increase" if d < d_before else "decrease"
            else:
                start = trial.levels.index(trial.level) if trial.level in trial.levels else 0
                chosen = trial.levels[-1]
                for f, p in trial.levels[start:]:
                    if not seen(self._d(dataclasses.replace(trial, fovea_deg=f, periphery_deg=p))):
                        chosen = (f, p)
                        break
                answer = f"{chosen[0]:g}"
            out.append(Response(self.name, trial, answer))
        return out


def study_trials(levels=APPENDIX_LEVELS, *, seed: int | None = None) -> list[Trial]:
    """All three tests in the thesis's order: pair, ramp, slider."""
    return [*pair_trials(levels, seed=seed), *ramp_trials(levels, seed=seed), slider_trial(levels)]


def run_study(
    observers: Sequence[MetricObserver], levels=APPENDIX_LEVELS, *, seed: int | None = None
) -> list[Response]:
    """Every observer through the whole study. With a `seed`, each observer gets its own trial
    order (seed + observer index), as participants would."""
    out = []
    for k, observer in enumerate(observers):
        out.extend(observer.answer(study_trials(levels, seed=None if seed is None else seed + k)))
    return out


# --- analysis (figures 66-68) ----------------------------------------------------------------


def wilson_interval(successes: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (default 95%); (nan, nan) when n = 0."""
    if n == 0:
        return (math.nan, math.nan)
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    # At 0 or n successes the bound is exactly 0 or 1; rounding would leave it a hair off.
    lo = 0.0 if successes == 0 else max(0.0, centre - half)
    hi = 1.0 if successes == n else min(1.0, centre + half)
    return (lo, hi)


def _by_test(responses: Iterable[Response], test: str) -> list[Response]:
    return [r for r in responses if r.trial.test == test]


def _levels_seen(responses: Sequence[Response]) -> list[tuple[float, float]]:
    return sorted({r.trial.level for r in responses})


def analyse_pair(responses: Iterable[Response]) -> list[dict]:
    """Figure 66: per level, how many pair answers were "same" (foveated indistinguishable
    from non-foveated), over both orders and all participants, with a 95% Wilson interval; also
    how often the reference or the foveated render was judged better."""
    pair = _by_test(responses, "pair")
    rows = []
    for level in _levels_seen(pair):
        rs = [r for r in pair if r.trial.level == level]
        same = sum(r.answer == "same" for r in rs)
        ref_better = sum(
            (r.answer == "first") == (r.trial.order == "reference_first") for r in rs if r.answer != "same"
        )
        lo, hi = wilson_interval(same, len(rs))
        rows.append(
            {
                "fovea_deg": level[0],
                "periphery_deg": level[1],
                "answers": len(rs),
                "participants": len({r.participant for r in rs}),
                "same": same,
                "reference_better": ref_better,
                "foveated_better": len(rs) - same - ref_better,
                "proportion_same": same / len(rs),
                "proportion_same_lo": lo,
                "proportion_same_hi": hi,
            }
        )
    return rows


def analyse_ramp(responses: Iterable[Response]) -> list[dict]:
    """Figure 67: per ramp direction and level, how many answers were "same" (quality equal to
    the non-foveated reference), with a 95% Wilson interval, and the other answers' counts."""
    ramp = _by_test(responses, "ramp")
    rows = []
    for direction in RAMP_DIRECTIONS:
        rd = [r for r in ramp if r.trial.direction == direction]
        for level in _levels_seen(rd):
            rs = [r for r in rd if r.trial.level == level]
            counts = {a: sum(r.answer == a for r in rs) for a in RAMP_ANSWERS}
            lo, hi = wilson_interval(counts["same"], len(rs))
            rows.append(
                {
                    "direction": direction,
                    "fovea_deg": level[0],
                    "periphery_deg": level[1],
                    "answers": len(rs),
                    **counts,
                    "proportion_same": counts["same"] / len(rs),
                    "proportion_same_lo": lo,
                    "proportion_same_hi": hi,
                }
            )
    return rows


def analyse_slider(responses: Iterable[Response], levels=APPENDIX_LEVELS) -> list[dict]:
    """Figure 68: per level, how many participants chose it as the lowest level equivalent to
    the reference (every level of the slider listed, chosen or not)."""
    levels = _check_levels(levels, "analyse_slider")
    slider = _by_test(responses, "slider")
    chosen = [float(r.answer) for r in slider]
    n = len(chosen)
    return [
        {
            "fovea_deg": f,
            "periphery_deg": p,
            "participants": sum(c == f for c in chosen),
            "proportion": (sum(c == f for c in chosen) / n) if n else math.nan,
        }
        for f, p in levels
    ]


def majority_level(rows: Sequence[dict], column: str = "proportion_same") -> float | None:
    """The lowest fovea at which more than half the answers (or participants) are in `column`,
    from an `analyse_pair`/`analyse_ramp` table (for the ramp, pass one direction's rows);
    None if no level has a majority."""
    for row in sorted(rows, key=lambda r: r["fovea_deg"]):
        if row[column] > 0.5:
            return float(row["fovea_deg"])
    return None
