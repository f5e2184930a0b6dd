"""Acuity data: the CSV schema, loading with validation, and the MAR → acuity conversion.

The schema (one row per eccentricity and condition; lines starting with `#` are comments):

    eccentricity_deg, acuity, sd, n, condition, source

- `eccentricity_deg`: retinal eccentricity in degrees, >= 0 (one meridian or an average; a signed
  nasal/temporal axis goes in `condition`, as magnitudes).
- `acuity`: decimal acuity (1 / MAR in arcmin, so 1.0 is a 1-arcmin gap) or relative acuity
  (acuity divided by the foveal acuity); > 0. Instead of `acuity` a file may give `mar_arcmin`,
  the minimum angle of resolution in arcminutes; see `mar_to_acuity`.
- `sd`: standard deviation of the measurements averaged into this row (blank if unknown). Give it
  for every row or for none.
- `n`: number of measurements averaged (blank = 1). A fit weights each row by its standard error
  sd/√n.
- `condition`: free text (e.g. "photopic"); a fit uses one condition at a time.
- `source`: citation of the figure or table the row was read from.

`eccentricity_deg` and `acuity` (or `mar_arcmin`) are required; `sd`, `n`, `condition` and
`source` may be left out (as blank cells: no sd, n = 1, one unnamed condition, no source).
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SCHEMA = ("eccentricity_deg", "acuity", "sd", "n", "condition", "source")
MAR_SCHEMA = ("eccentricity_deg", "mar_arcmin", "sd", "n", "condition", "source")
# Columns a file may leave out (each then blank on every row).
OPTIONAL_COLUMNS = ("sd", "n", "condition", "source")


class AcuityDataError(ValueError):
    """Bad acuity data; the message names the file, line and field."""


@dataclass(frozen=True, eq=False)
class AcuityData:
    """Validated acuity measurements (host NumPy float64). Build with `load_csv` or `from_arrays`."""

    eccentricity_deg: np.ndarray
    acuity: np.ndarray
    sd: np.ndarray | None
    n: np.ndarray
    condition: tuple[str, ...]
    source: tuple[str, ...]
    where: str = "arrays"
    sha256: str | None = None

    def __len__(self) -> int:
        return int(self.eccentricity_deg.shape[0])

    @property
    def weighted(self) -> bool:
        return self.sd is not None

    @property
    def se(self) -> np.ndarray | None:
        """Standard error of each row, sd/√n, or None for unweighted data."""
        return None if self.sd is None else self.sd / np.sqrt(self.n)

    @property
    def conditions(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(self.condition))

    def select(self, condition: str) -> AcuityData:
        """The rows of one condition."""
        mask = np.array([c == condition for c in self.condition])
        if not mask.any():
            raise AcuityDataError(
                f"{self.where}: no rows with condition {condition!r}; have {list(self.conditions)}"
            )
        return AcuityData(
            self.eccentricity_deg[mask],
            self.acuity[mask],
            None if self.sd is None else self.sd[mask],
            self.n[mask],
            tuple(c for c, m in zip(self.condition, mask, strict=True) if m),
            tuple(s for s, m in zip(self.source, mask, strict=True) if m),
            f"{self.where} [condition={condition!r}]",
            self.sha256,
        )


def mar_to_acuity(
    mar_arcmin: np.ndarray, sd_arcmin: np.ndarray | None = None, reference_arcmin: float | np.ndarray = 1.0
) -> tuple[np.ndarray, np.ndarray | None]:
    """Convert a minimum angle of resolution (arcmin) into acuity.

    acuity = reference / MAR. With the default reference of 1 arcmin this is decimal (Snellen)
    acuity (MAR 2' -> 0.5); with the foveal MAR as reference it is relative acuity (1 at the
    fovea). A standard deviation of MAR maps to first order (delta method) to
    sd_acuity = reference·sd_MAR / MAR², which understates the spread when sd_MAR is a large
    fraction of MAR (1/MAR is skewed); keep the MAR data if that matters.
    """
    mar = np.asarray(mar_arcmin, np.float64)
    acuity = reference_arcmin / mar
    sd = None if sd_arcmin is None else reference_arcmin * np.asarray(sd_arcmin, np.float64) / mar**2
    return acuity, sd


def from_arrays(
    eccentricity_deg,
    acuity,
    sd=None,
    n=None,
    condition: str | tuple[str, ...] = "",
    source: str | tuple[str, ...] = "",
    where: str = "arrays",
    sha256: str | None = None,
    lines: list[int] | None = None,
) -> AcuityData:
    """Validate arrays into `AcuityData`; errors name the row (or file line) and the field."""
    omega = np.atleast_1d(np.asarray(eccentricity_deg, np.float64))
    v = np.atleast_1d(np.asarray(acuity, np.float64))
    count = omega.shape[0]
    lines = lines if lines is not None else list(range(count))
    label = "line" if where != "arrays" else "row"

    def at(i: int) -> str:
        return f"{where}:{lines[i]}" if label == "line" else f"{where} row {i}"

    if count == 0:
        raise AcuityDataError(f"{where}: no data rows")
    if omega.ndim != 1 or v.shape != omega.shape:
        raise AcuityDataError(
            f"{where}: eccentricity_deg {omega.shape} and acuity {v.shape} must be equal 1-D"
        )
    sd_arr = None if sd is None else np.atleast_1d(np.asarray(sd, np.float64))
    n_arr = np.ones(count) if n is None else np.atleast_1d(np.asarray(n, np.float64))
    conds = (condition,) * count if isinstance(condition, str) else tuple(condition)
    srcs = (source,) * count if isinstance(source, str) else tuple(source)
    for field, arr in (("sd", sd_arr), ("n", n_arr), ("condition", conds), ("source", srcs)):
        if arr is not None and len(arr) != count:
            raise AcuityDataError(f"{where}: {field} has {len(arr)} entries for {count} rows")

    for i in range(count):
        if not math.isfinite(omega[i]):
            raise AcuityDataError(f"{at(i)}: eccentricity_deg is {omega[i]}, not a finite number")
        if omega[i] < 0:
            raise AcuityDataError(
                f"{at(i)}: eccentricity_deg = {omega[i]:g} is negative; "
                "give magnitudes (a meridian goes in condition)"
            )
        if not math.isfinite(v[i]):
            raise AcuityDataError(f"{at(i)}: acuity is {v[i]}, not a finite number")
        if v[i] <= 0:
            raise AcuityDataError(f"{at(i)}: acuity = {v[i]:g} must be > 0")
        if sd_arr is not None and not (math.isfinite(sd_arr[i]) and sd_arr[i] > 0):
            raise AcuityDataError(f"{at(i)}: sd = {sd_arr[i]:g} must be a finite number > 0")
        if not (math.isfinite(n_arr[i]) and n_arr[i] >= 1 and n_arr[i] == round(n_arr[i])):
            raise AcuityDataError(f"{at(i)}: n = {n_arr[i]:g} must be a whole number >= 1")

    seen: dict[tuple[float, str], int] = {}
    for i in range(count):
        key = (float(omega[i]), conds[i])
        if key in seen:
            raise AcuityDataError(
                f"{at(i)}: duplicate eccentricity_deg = {omega[i]:g} in condition {conds[i]!r} "
                f"(also at {at(seen[key])}); average repeated measurements into one row with sd and n"
            )
        seen[key] = i
    if count < 2:
        raise AcuityDataError(f"{where}: a single data row (eccentricity {omega[0]:g}) cannot define a curve")
    return AcuityData(omega, v, sd_arr, n_arr, conds, srcs, where, sha256)


def _parse_float(text: str, where: str, field: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise AcuityDataError(f"{where}: {field} = {text!r} is not a number") from None


def load_csv(path: str | Path, *, mar_reference_arcmin: float | str = 1.0) -> AcuityData:
    """Load a CSV in the acuity schema (see the module docstring), validating every row.

    A file with a `mar_arcmin` column instead of `acuity` is converted by `mar_to_acuity` with
    `mar_reference_arcmin` (1.0 -> decimal acuity; "fovea" -> relative acuity, dividing by each
    condition's MAR at eccentricity 0).
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise AcuityDataError(f"{path}: cannot read ({err.strerror})") from None
    digest = hashlib.sha256(raw).hexdigest()
    text = raw.decode("utf-8-sig")
    rows: list[tuple[int, list[str]]] = []
    for lineno, record in enumerate(csv.reader(io.StringIO(text)), start=1):
        if not record or not "".join(record).strip() or record[0].lstrip().startswith("#"):
            continue
        rows.append((lineno, [cell.strip() for cell in record]))
    if not rows:
        raise AcuityDataError(
            f"{path}: empty file (no header, no data rows); expected columns {', '.join(SCHEMA)}"
        )
    header_line, header = rows[0]
    is_mar = "mar_arcmin" in header
    expected = MAR_SCHEMA if is_mar else SCHEMA
    missing = [c for c in expected if c not in header and c not in OPTIONAL_COLUMNS]
    unknown = [c for c in header if c not in expected]
    repeated = sorted({c for c in header if header.count(c) > 1})
    if missing or unknown or repeated:
        parts = []
        if missing:
            parts.append(f"missing column(s) {missing}")
        if unknown:
            shown = unknown[:6] + ([f"... {len(unknown) - 6} more"] if len(unknown) > 6 else [])
            parts.append(f"unknown column(s) {shown}")
        if repeated:
            parts.append(f"repeated column(s) {repeated}")
        raise AcuityDataError(
            f"{path}:{header_line}: {'; '.join(parts)}; expected eccentricity_deg and acuity (or "
            f"mar_arcmin), optionally {', '.join(OPTIONAL_COLUMNS)}"
        )
    col = {name: header.index(name) for name in expected if name in header}

    def cell(cells: list[str], name: str) -> str:
        return cells[col[name]] if name in col else ""

    data_rows = rows[1:]
    if not data_rows:
        raise AcuityDataError(f"{path}: header only, no data rows")

    value_col = "mar_arcmin" if is_mar else "acuity"
    omega, value, sds, ns, conds, srcs, lines = [], [], [], [], [], [], []
    for lineno, cells in data_rows:
        where = f"{path}:{lineno}"
        if len(cells) != len(header):
            raise AcuityDataError(f"{where}: {len(cells)} fields, header has {len(header)}")
        omega.append(_parse_float(cells[col["eccentricity_deg"]], where, "eccentricity_deg"))
        value.append(_parse_float(cells[col[value_col]], where, value_col))
        sd_text, n_text = cell(cells, "sd"), cell(cells, "n")
        sds.append(_parse_float(sd_text, where, "sd") if sd_text else None)
        ns.append(_parse_float(n_text, where, "n") if n_text else 1.0)
        conds.append(cell(cells, "condition"))
        srcs.append(cell(cells, "source"))
        lines.append(lineno)

    given = [i for i, s in enumerate(sds) if s is not None]
    if given and len(given) != len(sds):
        blank = [lines[i] for i, s in enumerate(sds) if s is None]
        raise AcuityDataError(
            f"{path}: sd is given on line(s) {[lines[i] for i in given]} but blank on line(s) {blank}; "
            "give it for every row or for none"
        )
    sd_arr = np.array(sds, np.float64) if given else None
    value_arr = np.array(value, np.float64)
    if is_mar:
        for i, m in enumerate(value_arr):
            if not (math.isfinite(m) and m > 0):
                raise AcuityDataError(f"{path}:{lines[i]}: mar_arcmin = {m:g} must be a finite number > 0")
        if mar_reference_arcmin == "fovea":
            ref = np.empty_like(value_arr)
            for cond in dict.fromkeys(conds):
                idx = [i for i, c in enumerate(conds) if c == cond]
                zero = [i for i in idx if omega[i] == 0]
                if not zero:
                    raise AcuityDataError(
                        f"{path}: condition {cond!r} has no row at eccentricity 0 to normalise by"
                    )
                ref[idx] = value_arr[zero[0]]
        else:
            ref = float(mar_reference_arcmin)
        value_arr, sd_arr = mar_to_acuity(value_arr, sd_arr, ref)
    return from_arrays(omega, value_arr, sd_arr, ns, tuple(conds), tuple(srcs), str(path), digest, lines)


def save_csv(data: AcuityData, path: str | Path, comment: str = "") -> None:
    """Write `data` in the schema, with `comment` lines (prefixed by '# ') above the header."""
    buf = io.StringIO()
    for line in comment.splitlines():
        buf.write(f"# {line}\n" if line else "#\n")
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(SCHEMA)
    for i in range(len(data)):
        sd = "" if data.sd is None else repr(float(data.sd[i]))
        n = "" if data.n[i] == 1 and data.sd is None else str(int(data.n[i]))
        writer.writerow(
            [
                f"{data.eccentricity_deg[i]:g}",
                f"{data.acuity[i]:.10g}",
                sd,
                n,
                data.condition[i],
                data.source[i],
            ]
        )
    Path(path).write_text(buf.getvalue())
