"""Tables of configurations: the Pareto front of cost against accuracy, the cheapest
configuration within a perceptual threshold, and CSV files.

A table is a list of dicts (one record per configuration) or a NumPy structured array. A
metric column `m` may come with a confidence interval in the columns `m_lo` and `m_hi`.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SENSES = ("min", "max")
CI_SUFFIXES = ("_lo", "_hi")


def as_records(table) -> list[dict]:
    """A list of dicts from a list of dicts/mappings or a structured array (copies; NumPy
    scalars become Python numbers)."""
    if isinstance(table, np.ndarray):
        if table.dtype.names is None:
            raise ValueError(
                f"as_records: expected a structured array with named columns, got dtype {table.dtype}"
            )
        names = table.dtype.names
        return [
            {n: row[n].item() if hasattr(row[n], "item") else row[n] for n in names}
            for row in np.atleast_1d(table)
        ]
    records = []
    for i, rec in enumerate(table):
        if not isinstance(rec, Mapping):
            raise ValueError(
                f"as_records: record {i} is a {type(rec).__name__}, not a mapping of column -> value"
            )
        records.append(dict(rec))
    return records


def _column(records: Sequence[dict], name: str, where: str) -> np.ndarray:
    values = []
    for i, rec in enumerate(records):
        if name not in rec:
            raise ValueError(f"{where}: record {i} has no column {name!r} (columns: {sorted(rec)})")
        v = rec[name]
        try:
            values.append(math.nan if v is None else float(v))
        except (TypeError, ValueError):
            raise ValueError(f"{where}: record {i}, column {name!r}: {v!r} is not a number") from None
    return np.asarray(values, np.float64)


def pareto_front(table, objectives: Mapping[str, str]) -> np.ndarray:
    """Boolean mask of the records on the Pareto front for `objectives`, a mapping column ->
    "min" or "max" (e.g. {"rays_per_frame": "min", "flip": "min"} or {"ms_per_frame": "min",
    "ssim": "max"}). A record is on the front when no other record is at least as good in every
    objective and strictly better in one; equal records are all on it. Records with a NaN or
    missing value in an objective are not on the front and dominate nothing."""
    records = as_records(table)
    if not objectives:
        raise ValueError("pareto_front: give at least one objective (column -> 'min' or 'max')")
    cols = []
    for name, sense in objectives.items():
        if sense not in SENSES:
            raise ValueError(f"pareto_front: objective {name!r} must be 'min' or 'max', got {sense!r}")
        values = _column(records, name, "pareto_front")
        cols.append(values if sense == "min" else -values)  # everything minimised from here
    if not records:
        return np.zeros(0, bool)
    x = np.stack(cols, axis=1)
    valid = np.asarray(np.isfinite(x).all(axis=1))
    front = valid.copy()
    for i in np.flatnonzero(valid):
        others = x[valid]
        dominated = bool(np.any(np.all(others <= x[i], axis=1) & np.any(others < x[i], axis=1)))
        front[i] = not dominated
    return front


@dataclass(frozen=True)
class Choice:
    """The configuration `cheapest_within` picked, and why."""

    index: int
    record: dict
    name: str
    criterion: str

    def __str__(self) -> str:
        return f"{self.name} ({self.criterion})"


def cheapest_within(
    table,
    *,
    cost: str,
    metric: str,
    threshold: float,
    below: bool = True,
    use_interval: bool = True,
    label: str = "config",
) -> Choice | None:
    """The record with the lowest `cost` whose `metric` stays below `threshold` (or above it,
    with `below=False`, for a higher-is-better metric). With `use_interval` and a
    `metric_hi` (`metric_lo` for above) column, the whole confidence interval must stay on the
    right side; without such a column the point value is used. Ties in cost go to the better
    metric value, then to the earlier record. None when no record qualifies. The choice is
    named by its `label` column (else by its index)."""
    records = as_records(table)
    if not math.isfinite(threshold):
        raise ValueError(f"cheapest_within: threshold must be finite, got {threshold}")
    if not records:
        return None
    bound_col = metric + (CI_SUFFIXES[1] if below else CI_SUFFIXES[0])
    bound_name = bound_col if use_interval and all(bound_col in r for r in records) else metric
    costs = _column(records, cost, "cheapest_within")
    bound = _column(records, bound_name, "cheapest_within")
    value = _column(records, metric, "cheapest_within")
    ok = np.isfinite(costs) & np.isfinite(bound) & ((bound < threshold) if below else (bound > threshold))
    if not ok.any():
        return None
    candidates = np.flatnonzero(ok)
    # Lexicographic: cost, then the metric (better first), then the index.
    better = value if below else -value
    best = min(candidates, key=lambda i: (costs[i], better[i], i))
    rec = records[best]
    name = str(rec[label]) if label in rec else f"record {best}"
    relation = "<" if below else ">"
    criterion = (
        f"lowest {cost} = {costs[best]:g} with {bound_name} = {bound[best]:g} {relation} {threshold:g}"
    )
    return Choice(int(best), rec, name, criterion)


def write_csv(table, path, *, columns: Sequence[str] | None = None) -> Path:
    """Write a table as CSV: the union of the records' columns in order of first appearance
    (or `columns`), None as an empty cell, floats at full precision."""
    records = as_records(table)
    if columns is None:
        seen: dict[str, None] = {}
        for rec in records:
            seen.update(dict.fromkeys(rec))
        columns = list(seen)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(columns), extrasaction="raise")
        writer.writeheader()
        for rec in records:
            writer.writerow({k: _cell(rec.get(k)) for k in columns})
    return path


def _cell(v):
    if v is None:
        return ""
    if isinstance(v, float | np.floating):
        return repr(float(v))
    return v


def _parse(cell: str):
    if cell == "":
        return None
    if cell in ("True", "False"):
        return cell == "True"
    try:
        return int(cell)
    except ValueError:
        pass
    try:
        return float(cell)
    except ValueError:
        return cell


def read_csv(path) -> list[dict]:
    """Read a table written by `write_csv`: numbers back to int/float, empty cells to None,
    True/False to bool, anything else stays a string."""
    with Path(path).open(newline="") as fh:
        return [{k: _parse(v) for k, v in row.items()} for row in csv.DictReader(fh)]


def mean_interval(samples: Iterable[float], *, level: float = 0.95) -> tuple[float, float, float]:
    """Mean and a Student-t confidence interval of the mean (e.g. over gaze positions and keys):
    (mean, lo, hi). One sample, or an infinite one (PSNR of identical frames), gives no interval
    (nan, nan); NaN samples are an error."""
    from scipy import stats

    x = np.asarray(list(samples), np.float64)
    if x.size == 0:
        raise ValueError("mean_interval: no samples")
    if np.isnan(x).any():
        raise ValueError(f"mean_interval: samples contain NaN: {x.tolist()}")
    if not 0 < level < 1:
        raise ValueError(f"mean_interval: level must be in (0, 1), got {level}")
    m = float(x.mean())
    if x.size == 1 or not np.isfinite(x).all():
        return m, math.nan, math.nan
    half = float(stats.t.ppf(0.5 + level / 2, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size))
    return m, m - half, m + half
