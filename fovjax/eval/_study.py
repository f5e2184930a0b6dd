"""The user study answered from measured metrics: a `fovjax compare` table (comparison.csv)
gives, per study level, the mean of a metric against the full render; that becomes the
difference d the automatic observers (`MetricObserver`) judge, and their answers go through the
same analysis as people's (figures 66-68).

    table = fe.read_csv("out/compare/comparison.csv")
    observers = fe.observers_from_comparison(table, metric="jod", spp=4, n=15, noise_sd=0.3, seed=0)
    responses = fe.run_study(observers)
    fe.study_majorities(responses)     # {"pair": 12.5, "ramp up": ..., "ramp down": ..., "slider": ...}

Metrics (`STUDY_METRICS`): "jod" (FovVideoVDP): d = 10 - mean JOD, threshold `JND_JOD` = 1;
"flip": d = mean FLIP, threshold 0.05 (`fovjax compare`'s default criterion). The mean is taken
over the level's rows at one spp (and one acuity model, when the table has several).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._compare import DEFAULT_CRITERION
from ._metrics import JND_JOD
from ._pareto import _parse, as_records
from ._protocols import (
    APPENDIX_LEVELS,
    RAMP_DIRECTIONS,
    MetricObserver,
    Response,
    Trial,
    _check_levels,
    _level_label,
    analyse_pair,
    analyse_ramp,
    analyse_slider,
    majority_level,
)

STUDY_METRICS: dict[str, tuple[str, float]] = {
    # metric column -> (how d is made from the level's mean, default threshold on d)
    "jod": ("d = 10 - mean FovVideoVDP JOD", JND_JOD),
    "flip": ("d = mean FLIP", float(DEFAULT_CRITERION[1])),
}
# The scale of each study metric's values: FLIP is an error in [0, 1]; FovVideoVDP's JOD is 10
# for an image identical to the reference and less the more visible the difference.
METRIC_SCALES: dict[str, tuple[float, float]] = {"flip": (0.0, 1.0), "jod": (-math.inf, 10.0)}
THESIS_LEVEL = (12.5, 25.0)
"""The level the thesis's participants chose (fovea, periphery in degrees, chapter 5.2)."""
MAJORITY_TESTS = ("pair", "ramp up", "ramp down", "slider")


def _difference(metric: str, mean: float) -> float:
    """d of `STUDY_METRICS`: larger means more visible."""
    return 10.0 - mean if metric == "jod" else mean


def default_metric(table) -> str:
    """The study's default metric: "jod" when the table has a FovVideoVDP JOD column with a value
    in it, else "flip" when it has a FLIP column; a ValueError naming the columns otherwise."""
    records = as_records(table)
    columns = _columns(records)
    if any(r.get("jod") is not None for r in records):
        return "jod"
    if "flip" in columns:
        return "flip"
    raise ValueError(f"comparison table has neither a 'jod' nor a 'flip' column (columns: {columns})")


def _columns(records: Sequence[dict]) -> list[str]:
    return list(dict.fromkeys(k for r in records for k in r))


def _sorted_values(values: Iterable) -> list:
    """Distinct values, numbers first in numeric order, then anything else as text."""
    distinct = set(values)
    numbers = sorted(v for v in distinct if isinstance(v, int | float) and not isinstance(v, bool))
    return numbers + sorted((v for v in distinct if v not in numbers), key=str)


def _same(a, b) -> bool:
    try:
        return math.isclose(float(a), float(b), rel_tol=0, abs_tol=1e-9)
    except (TypeError, ValueError):
        return False


@dataclass(frozen=True)
class LevelDifference:
    """A Trial -> float callable for `MetricObserver`: the difference d at the trial's level,
    from a comparison table. `means`: the metric's mean per level; `rows`: how many table rows
    each mean is over; `differences`: d per level, made from the means by `STUDY_METRICS`."""

    metric: str
    threshold: float
    spp: int
    model: str | None
    means: dict[tuple[float, float], float]
    rows: dict[tuple[float, float], int] = field(repr=False)

    @property
    def differences(self) -> dict[tuple[float, float], float]:
        return {level: _difference(self.metric, mean) for level, mean in self.means.items()}

    def __call__(self, trial: Trial) -> float:
        for level, d in self.differences.items():
            if _same(level[0], trial.fovea_deg) and _same(level[1], trial.periphery_deg):
                return d
        have = ", ".join(_level_label(*lv) for lv in self.differences)
        raise ValueError(
            f"no {self.metric} for level {_level_label(*trial.level)} ({trial.condition!r}); "
            f"the comparison gave levels {have}"
        )

    def seen(self, level: tuple[float, float]) -> bool:
        """Whether a noise-free observer sees the difference at `level` (d > threshold)."""
        return self.differences[level] > self.threshold


def difference_from_comparison(
    table,
    *,
    metric: str | None = None,
    spp: int = 4,
    model: str | None = None,
    threshold: float | None = None,
    levels=APPENDIX_LEVELS,
    where: str = "comparison table",
    lines: Sequence[int] | None = None,
) -> LevelDifference:
    """For every study level (fovea, periphery), the mean of `metric` over the table's rows at
    that level, `spp` and `model` (needed only when the table has several models), turned into
    the difference d of `STUDY_METRICS`. `metric` defaults to `default_metric(table)`;
    `threshold` to the metric's default. `where` names the table in error messages (e.g. its
    path), and `lines` (from `read_comparison`) each record's line in it, so a bad row is
    FILE:LINE. ValueErrors name what is missing: a level (with the levels and spp values the table
    has), the metric column (with the columns), a model, or a row with a non-finite value."""
    records = as_records(table)
    if not records:
        raise ValueError(f"{where}: no rows")
    levels = _check_levels(levels, "difference_from_comparison")
    columns = _columns(records)
    metric = default_metric(records) if metric is None else metric
    if metric not in STUDY_METRICS:
        raise ValueError(f"{where}: metric must be one of {sorted(STUDY_METRICS)}, got {metric!r}")
    threshold = STUDY_METRICS[metric][1] if threshold is None else float(threshold)
    if not (math.isfinite(threshold) and threshold >= 0):
        raise ValueError(f"{where}: threshold must be a finite number >= 0, got {threshold}")
    for needed in ("fovea_deg", "periphery_deg", "spp", metric):
        if needed not in columns:
            raise ValueError(f"{where}: no column {needed!r} (columns: {columns})")

    spp_values = _sorted_values(r.get("spp") for r in records)
    at_spp = [(i, r) for i, r in enumerate(records) if _same(r.get("spp"), spp)]
    if not at_spp:
        raise ValueError(f"{where}: no rows at spp {spp} (spp values: {spp_values})")
    models = list(dict.fromkeys(r.get("model") for _, r in at_spp))
    if model is not None:
        if "model" not in columns:
            raise ValueError(f"{where}: model {model!r} asked for but there is no 'model' column")
        at_spp = [(i, r) for i, r in at_spp if r.get("model") == model]
        if not at_spp:
            raise ValueError(f"{where}: no rows with model {model!r} at spp {spp} (models: {models})")
    elif len(models) > 1:
        raise ValueError(f"{where}: several acuity models at spp {spp}: {models}; choose one (--model)")
    else:
        model = models[0]

    have = list(dict.fromkeys((float(r["fovea_deg"]), float(r["periphery_deg"])) for _, r in at_spp))
    which = f"spp {spp}" + ("" if model is None else f", model {model!r}")
    means, counts = {}, {}
    for level in levels:
        rows = [
            (i, r)
            for i, r in at_spp
            if _same(r["fovea_deg"], level[0]) and _same(r["periphery_deg"], level[1])
        ]
        if not rows:
            raise ValueError(
                f"{where}: study level {_level_label(*level)} (fovea/periphery degrees) has no rows "
                f"at {which}; the table has levels "
                f"[{', '.join(_level_label(*lv) for lv in have)}] there, spp values {spp_values}"
            )
        values = []
        for i, r in rows:
            v = r.get(metric)
            try:
                x = math.nan if v is None else float(v)
            except (TypeError, ValueError):
                x = math.nan
            label = f" (config {r['config']!r})" if "config" in r else ""
            row_at = f"{where}:{lines[i]}" if lines is not None else f"{where}: row {i + 1}"
            if not math.isfinite(x):
                raise ValueError(
                    f"{row_at}{label}: {metric} is {v!r}, not a finite number "
                    f"(level {_level_label(*level)}, {which})"
                )
            lo, hi = METRIC_SCALES[metric]
            if not lo - 1e-6 <= x <= hi + 1e-6:
                scale = f"[{lo:g}, {hi:g}]" if math.isfinite(lo) else f"at most {hi:g}"
                raise ValueError(
                    f"{row_at}{label}: {metric} is {v!r}, outside its scale {scale} "
                    f"(level {_level_label(*level)}, {which})"
                )
            values.append(x)
        means[level] = float(np.mean(values))
        counts[level] = len(values)
    return LevelDifference(metric, threshold, int(spp), model, means, counts)


# The columns of a comparison table the study reads, and what each must hold.
COMPARISON_COLUMNS = ("fovea_deg", "periphery_deg", "spp")


def _cell_number(text: str, where: str, column: str, expected: str, *, whole: bool = False) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or (whole and not value.is_integer()):
        raise ValueError(f"{where}: {column} is {text!r}, not {expected}")
    return value


def _shown(header, most: int = 8) -> str:
    """A header's first columns, for a message (a file that is not a table has any number)."""
    names = [repr(c if len(c) <= 30 else c[:27] + "...") for c in header[:most]]
    more = f", ... {len(header) - most} more" if len(header) > most else ""
    return f"[{', '.join(names)}{more}]"


def read_comparison(path) -> tuple[list[dict], list[int]]:
    """Read a `fovjax compare` table (comparison.csv) for the study, checking every cell the
    study reads before any is used: the columns `COMPARISON_COLUMNS` and a metric column ("jod"
    or "flip"); per row fovea_deg and periphery_deg numbers of degrees with
    0 <= fovea <= periphery <= 180, spp a whole number >= 1, and each metric cell empty (not
    measured) or a number within its scale (`METRIC_SCALES`). Returns the records (cells as
    `read_csv` gives them) and each record's line in the file. A bad table is a ValueError
    naming FILE:LINE, the column, the value and what was expected."""
    path = Path(path)
    with path.open(newline="", encoding="utf-8-sig") as fh:
        reader = csv.DictReader(fh)
        header = reader.fieldnames
        if not header:
            raise ValueError(f"{path}:1: empty file; expected a comparison table (`fovjax compare`)")
        if header[0].lstrip().startswith(("{", "[")):
            raise ValueError(
                f"{path}:1: JSON, not a comparison table (the CSV `fovjax compare` writes, comparison.csv)"
            )
        missing = [c for c in COMPARISON_COLUMNS if c not in header]
        if missing:
            raise ValueError(
                f"{path}:1: no column {', '.join(map(repr, missing))} (columns: {_shown(header)}); "
                "expected a comparison table written by `fovjax compare`"
            )
        if not any(m in header for m in METRIC_SCALES):
            raise ValueError(f"{path}:1: neither a 'jod' nor a 'flip' column (columns: {_shown(header)})")
        records, lines = [], []
        for row in reader:
            line = reader.line_num  # where the row ends: its line, for a row without quoted newlines
            where = f"{path}:{line}"
            if None in row or any(v is None for v in row.values()):
                fields = len(header) + len(row.get(None) or ()) - sum(v is None for v in row.values())
                raise ValueError(f"{where}: {fields} fields, the header has {len(header)}")
            fovea = _cell_number(row["fovea_deg"], where, "fovea_deg", "a number of degrees")
            periphery = _cell_number(row["periphery_deg"], where, "periphery_deg", "a number of degrees")
            if not 0 <= fovea <= periphery <= 180:
                raise ValueError(
                    f"{where}: fovea_deg {row['fovea_deg']}, periphery_deg {row['periphery_deg']}: "
                    "expected 0 <= fovea <= periphery <= 180 degrees"
                )
            spp = _cell_number(row["spp"], where, "spp", "a whole number of samples per pixel", whole=True)
            if spp < 1:
                raise ValueError(f"{where}: spp is {row['spp']!r}, not a whole number >= 1")
            for metric, (lo, hi) in METRIC_SCALES.items():
                text = row.get(metric)
                if text is None or text == "":
                    continue
                x = _cell_number(text, where, metric, "a number")
                if not lo - 1e-6 <= x <= hi + 1e-6:
                    scale = f"[{lo:g}, {hi:g}]" if math.isfinite(lo) else f"at most {hi:g}"
                    raise ValueError(f"{where}: {metric} is {text}, outside its scale {scale}")
            records.append({k: _parse(v) for k, v in row.items()})
            lines.append(line)
    if not records:
        raise ValueError(f"{path}: header only, no rows")
    return records, lines


def observer_seeds(n: int, seed: int | None) -> list[int | None]:
    """`n` independent seeds derived from `seed` (all None when `seed` is None)."""
    if seed is None:
        return [None] * n
    return [int(s.generate_state(1)[0]) for s in np.random.SeedSequence(seed).spawn(n)]


@dataclass(frozen=True)
class ObserverPanel:
    """Automatic observers who answer the study's tests: `n` of them ("auto01", ...), each
    seeing a level when its difference exceeds `threshold` (None: the metric's default, e.g.
    `JND_JOD` for JOD), with noise of `noise_sd` drawn from its own seed derived from `seed`
    (None: fresh seeds); with `noise_sd` 0 they all answer alike.

    Raises:
        ValueError: a bad field, naming it, its value and what was expected.
    """

    n: int = 15
    noise_sd: float = 0.0
    threshold: float | None = None
    seed: int | None = 0

    def __post_init__(self):
        def number(x) -> bool:
            return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)

        if isinstance(self.n, bool) or not isinstance(self.n, int) or self.n < 1:
            raise ValueError(f"ObserverPanel: n (observers) must be a whole number >= 1, got {self.n!r}")
        if not (number(self.noise_sd) and self.noise_sd >= 0):
            raise ValueError(f"ObserverPanel: noise_sd must be a finite number >= 0, got {self.noise_sd!r}")
        if self.threshold is not None and not (number(self.threshold) and self.threshold >= 0):
            raise ValueError(
                f"ObserverPanel: threshold must be None or a finite number >= 0, got {self.threshold!r}"
            )
        if self.seed is not None and (
            isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0
        ):
            raise ValueError(f"ObserverPanel: seed must be None or a whole number >= 0, got {self.seed!r}")


def observers_from_comparison(
    table,
    *,
    metric: str | None = None,
    spp: int = 4,
    model: str | None = None,
    observers: ObserverPanel | None = None,
    levels=APPENDIX_LEVELS,
    where: str = "comparison table",
    lines: Sequence[int] | None = None,
) -> list[MetricObserver]:
    """The automatic `observers` (`ObserverPanel`, default `ObserverPanel()`) judging the
    difference of `difference_from_comparison` (same arguments; the panel's threshold) against
    its threshold."""
    panel = ObserverPanel() if observers is None else observers
    if not isinstance(panel, ObserverPanel):
        raise TypeError(
            f"observers_from_comparison: observers must be an ObserverPanel, got {type(panel).__name__}"
        )
    difference = difference_from_comparison(
        table,
        metric=metric,
        spp=spp,
        model=model,
        threshold=panel.threshold,
        levels=levels,
        where=where,
        lines=lines,
    )
    return [
        MetricObserver(
            difference, difference.threshold, name=f"auto{k + 1:02d}", noise_sd=panel.noise_sd, seed=s
        )
        for k, s in enumerate(observer_seeds(panel.n, panel.seed))
    ]


def study_majorities(responses: Iterable[Response], levels=APPENDIX_LEVELS) -> dict[str, float | None]:
    """Per test, the lowest fovea (degrees) the majority accepts, None if none: pair and each
    ramp direction, the lowest level where more than half the answers are "same"
    (`majority_level`); slider, the lowest level that more than half the participants accept,
    i.e. whose chosen level is at or below it (the median choice). Tests without answers are
    left out."""
    responses = list(responses)
    out: dict[str, float | None] = {}
    pair = analyse_pair(responses)
    if pair:
        out["pair"] = majority_level(pair)
    ramp = analyse_ramp(responses)
    for direction in RAMP_DIRECTIONS:
        rows = [r for r in ramp if r["direction"] == direction]
        if rows:
            out[f"ramp {direction}"] = majority_level(rows)
    slider = analyse_slider(responses, levels)
    if any(r["participants"] for r in slider):
        total = sum(r["participants"] for r in slider)
        cumulative, accepted = 0, []
        for r in slider:
            cumulative += r["participants"]
            accepted.append({"fovea_deg": r["fovea_deg"], "accepted": cumulative / total})
        out["slider"] = majority_level(accepted, "accepted")
    return out
