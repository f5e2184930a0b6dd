"""One chart of the measured acuity data sets, their fits, and the thesis's curve.

    PYTHONPATH=. python fits/measured_acuity.py            # writes fits/measured_acuity.png

Every curve is drawn as relative acuity, V(ω)/V(0) of its own fit (the Yavuz et al. fits are
already relative, a = 1), so data sets measured in different units (decimal acuity from a
grating's pixels per degree; MAR in arcmin) share one axis. The thesis's curve is drawn the
same way, V(ω)/V(0) with V(0) = 0.918. Data points are divided by V(0) of the first fit listed for
their data set (the linear_mar fit). The fits are the committed records in fits/ (see
fits/README.md for the commands); this script only reads them.
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import numpy as np

import fovjax.acuity as fa
from fovjax.cli import build_parser

REPO = Path(__file__).resolve().parents[1]

# (record stem, label, colour); line style follows the model family.
RECORDS = (
    ("ashraf2025_achromatic_mean_linear_mar", "Ashraf et al. 2025, achromatic grating (mean)", "tab:blue"),
    ("ashraf2025_achromatic_mean_exponential", "Ashraf et al. 2025, achromatic grating (mean)", "tab:blue"),
    ("ashraf2025_red-green_linear_mar", "Ashraf et al. 2025, red-green grating", "tab:red"),
    ("ashraf2025_red-green_exponential", "Ashraf et al. 2025, red-green grating", "tab:red"),
    ("ashraf2025_yellow-violet_linear_mar", "Ashraf et al. 2025, yellow-violet grating", "goldenrod"),
    ("ashraf2025_yellow-violet_exponential", "Ashraf et al. 2025, yellow-violet grating", "goldenrod"),
    ("yavuz2009_linear_mar", "Yavuz et al. 2009, optotype MAR (70 eyes)", "tab:green"),
    ("yavuz2009_exponential", "Yavuz et al. 2009, optotype MAR (70 eyes)", "tab:green"),
)
# Also in the printed table, not drawn: the fits to the authors' medians (unweighted).
TABLE_ONLY = (
    "ashraf2025_achromatic_linear_mar",
    "ashraf2025_achromatic_exponential",
    "ashraf2025_achromatic_exponential_thesis_b",
    "ashraf2025_achromatic_mean_exponential_thesis_b",
)
STYLE = {"linear_mar": "-", "exponential": "--", "power_mar": "-."}
TABLE_ECC = (5.0, 10.0, 20.0)


def load(stem: str, fits_dir: Path = REPO / "fits"):
    """The fitted model, its data (the recorded condition, in the recorded acuity units) and record."""
    record = fa.read_fit(fits_dir / f"{stem}.json")
    args = build_parser().parse_args(shlex.split(record["command"])[1:])
    ref = args.mar_reference if args.mar_reference == "fovea" else float(args.mar_reference)
    data = fa.load_csv(REPO / args.data, mar_reference_arcmin=ref)
    if args.condition is not None:
        data = data.select(args.condition)
    return fa.load_fit(fits_dir / f"{stem}.json"), data, record


def relative(model, omega) -> np.ndarray:
    """V(ω)/V(0) of a fitted model, in float64 on the host."""
    omega = np.asarray(omega, np.float64)
    return np.asarray(model(omega), np.float64) / float(np.asarray(model(np.zeros(1)))[0])


def table(fits_dir: Path = REPO / "fits") -> list[dict]:
    """Relative acuity of every fit and of the thesis's curve at TABLE_ECC."""
    rows = [
        {
            "fit": "thesis V(ω)/V(0)",
            **{
                f"{e:g}": float(v)
                for e, v in zip(TABLE_ECC, relative(fa.THESIS_MODEL, TABLE_ECC), strict=True)
            },
        }
    ]
    for stem in [r[0] for r in RECORDS] + list(TABLE_ONLY):
        model, _, _ = load(stem, fits_dir)
        rel = relative(model, TABLE_ECC)
        rows.append({"fit": stem, **{f"{e:g}": float(v) for e, v in zip(TABLE_ECC, rel, strict=True)}})
    return rows


def chart(path: Path, fits_dir: Path = REPO / "fits", omega_max: float = 40.0) -> Path:
    from matplotlib.figure import Figure

    omega = np.linspace(0.0, omega_max, 401)
    fig = Figure(figsize=(12, 5.6), layout="constrained")
    axes = fig.subplots(1, 2)
    plotted_data: set[str] = set()
    for stem, label, colour in RECORDS:
        model, data, record = load(stem, fits_dir)
        scale = float(np.asarray(model(np.zeros(1)))[0])
        for ax in axes:
            ax.plot(
                omega,
                relative(model, omega),
                STYLE[record["model"]],
                color=colour,
                lw=1.5,
                label=f"{label}: {record['model']} fit",
            )
            if label not in plotted_data:
                err = None if data.se is None else data.se / scale
                ax.errorbar(data.eccentricity_deg, data.acuity / scale, yerr=err, fmt="o", color=colour, ms=5)
        plotted_data.add(label)
    pooled = fa.load_fit(fits_dir / "published_linear_mar.json")
    thesis = relative(fa.THESIS_MODEL, omega)
    for ax, log in zip(axes, (False, True), strict=True):
        ax.plot(
            omega,
            relative(pooled, omega),
            ":",
            color="0.45",
            lw=1.5,
            label="pooled published E2 figures: linear_mar",
        )
        ax.plot(
            omega, thesis, color="black", lw=2.2, label="thesis V(ω)/V(0) (fit to Mandelbaum & Sloan 1947)"
        )
        ax.set_xlabel("eccentricity ω (deg)")
        ax.set_ylabel("relative acuity V(ω)/V(0) of each fit")
        ax.grid(alpha=0.3)
        if log:
            ax.set_yscale("log")
            ax.set_ylim(3e-3, 1.5)
            ax.set_title("log axis")
        else:
            ax.set_ylim(0, 1.1)
            ax.set_title("measured acuity (points; error bars = s.e.) vs the thesis's curve")
    axes[0].legend(fontsize=7.5, loc="upper right")
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    out = Path(argv[0]) if argv else REPO / "fits" / "measured_acuity.png"
    rows = table()
    print(f"{'fit':<48} " + " ".join(f"{f'V({e:g}°)/V(0)':>12}" for e in TABLE_ECC))
    for r in rows:
        print(f"{r['fit']:<48} " + " ".join(f"{r[f'{e:g}']:>12.4f}" for e in TABLE_ECC))
    print(f"wrote {chart(out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
