"""Charts with matplotlib's object API on the Agg canvas (no pyplot, no global backend change)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._fit import FitResult
from ._models import THESIS_MODEL, AcuityModel
from ._posterior import Samples


def _save(fig, path: str | Path) -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=110)
    return path


def plot_fit(
    result: FitResult,
    path: str | Path,
    samples: Samples | None = None,
    reference: AcuityModel | None = THESIS_MODEL,
    reference_label: str = "thesis V(ω) (fit to Mandelbaum & Sloan 1947)",
    title: str | None = None,
    omega_max: float | None = None,
) -> Path:
    """Data, fitted curve, band (posterior if `samples` is given, else delta-method Laplace),
    an optional reference curve, on linear and log acuity axes, and the residuals. The curves
    run from 0 to `omega_max` (default: just past the last data point)."""
    from matplotlib.figure import Figure  # imported on use: matplotlib is slow to import

    data = result.data
    top = omega_max if omega_max is not None else float(data.eccentricity_deg.max()) * 1.05 or 1.0
    omega = np.linspace(0.0, top, 400)
    if samples is not None:
        centre, lo, hi = samples.band(omega)
        band_label = f"{100 * samples.level:.0f}% band ({samples.method})"
    else:
        centre, lo, hi = result.band(omega)
        band_label = f"{100 * result.level:.0f}% band (Laplace, delta method)"
    fitted = result.predict(omega)
    ref = None if reference is None else np.asarray(reference(omega))
    err = data.se

    fig = Figure(figsize=(11, 7.2), layout="constrained")
    grid = fig.add_gridspec(2, 2, height_ratios=(3, 1.3))
    axes = [fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[0, 1])]
    res_ax = fig.add_subplot(grid[1, :])
    for ax, log in zip(axes, (False, True), strict=True):
        ax.fill_between(omega, lo, hi, color="tab:blue", alpha=0.25, lw=0, label=band_label)
        ax.plot(omega, fitted, color="tab:blue", lw=1.8, label=f"fit: {result.family.formula}")
        if ref is not None:
            ax.plot(omega, ref, "--", color="0.4", lw=1.2, label=reference_label)
        ax.errorbar(
            data.eccentricity_deg,
            data.acuity,
            yerr=err,
            fmt="o",
            color="k",
            ms=4,
            capsize=2,
            label="data" + (" (± se)" if err is not None else ""),
        )
        ax.set_xlabel("eccentricity ω (deg)")
        ax.set_ylabel("acuity")
        if log:
            ax.set_yscale("log")
            curves = [data.acuity, fitted, lo] + ([] if ref is None else [ref])
            positive = np.concatenate([c[c > 0] for c in curves])
            ax.set_ylim(positive.min() / 2, positive.max() * 1.5)
            ax.set_title("log acuity")
        else:
            ax.set_ylim(bottom=min(0.0, float(np.min(lo))))
            ax.set_title(title or f"{result.family.name} fit to {Path(data.where).name}")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, loc="upper right")

    intervals = samples.intervals() if samples is not None else result.intervals()
    lines = []
    for k in result.family.param_names:
        if k in result.fixed:
            lines.append(f"{k} = {result.params[k]:.5g} (fixed)")
        else:
            a, b = intervals[k]
            lines.append(f"{k} = {result.params[k]:.5g}  [{a:.4g}, {b:.4g}]")
    m = result.metrics
    r2 = "undefined (constant data)" if not np.isfinite(m["r2"]) else f"{m['r2']:.5f}"
    lines.append(f"R² = {r2}, RMSE = {m['rmse']:.3g}, n = {m['n']}")
    axes[1].text(
        0.98,
        0.97,
        "\n".join(lines),
        transform=axes[1].transAxes,
        ha="right",
        va="top",
        fontsize=8,
        family="monospace",
        bbox={"facecolor": "white", "alpha": 0.85, "edgecolor": "0.7"},
    )

    res_ax.axhline(0, color="0.5", lw=1)
    res_ax.errorbar(data.eccentricity_deg, result.residuals, yerr=err, fmt="o", color="k", ms=4, capsize=2)
    res_ax.set_xlabel("eccentricity ω (deg)")
    res_ax.set_ylabel("data − fit")
    res_ax.set_xlim(axes[0].get_xlim())
    res_ax.grid(alpha=0.3)
    return _save(fig, path)


def plot_corner(samples: Samples, path: str | Path, laplace: FitResult | None = None) -> Path:
    """Corner-style chart: marginal histograms on the diagonal, pairwise 2-D histograms below,
    with the Laplace (least-squares covariance) 1σ and 2σ ellipses and optimum when given."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Ellipse

    names = samples.names
    k = len(names)
    fig = Figure(figsize=(2.6 * k + 0.6, 2.6 * k + 0.4), layout="constrained")
    axes = fig.subplots(k, k, squeeze=False)
    lo_hi = samples.intervals()
    for i in range(k):
        for j in range(k):
            ax = axes[i, j]
            if j > i:
                ax.set_axis_off()
                continue
            if i == j:
                ax.hist(samples.draws[:, i], bins=50, color="tab:blue", alpha=0.7, density=True)
                for q in lo_hi[names[i]]:
                    ax.axvline(q, color="k", ls=":", lw=1)
                ax.axvline(samples.median[names[i]], color="k", lw=1)
                if laplace is not None:
                    mu, sd = laplace.params[names[i]], laplace.stderr[names[i]]
                    x_lo, x_hi = ax.get_xlim()
                    x = np.linspace(x_lo, x_hi, 200)
                    ax.plot(
                        x,
                        np.exp(-0.5 * ((x - mu) / sd) ** 2) / (sd * np.sqrt(2 * np.pi)),
                        color="tab:red",
                        lw=1,
                    )
                ax.set_yticks([])
                ax.set_title(f"{names[i]} = {samples.median[names[i]]:.4g}", fontsize=9)
            else:
                ax.hist2d(samples.draws[:, j], samples.draws[:, i], bins=40, cmap="Blues")
                if laplace is not None:
                    pi = laplace.family.param_names.index(names[i])
                    pj = laplace.family.param_names.index(names[j])
                    cov = laplace.covariance[np.ix_([pj, pi], [pj, pi])]
                    vals, vecs = np.linalg.eigh(cov)
                    angle = np.degrees(np.arctan2(vecs[1, 1], vecs[0, 1]))
                    centre = (laplace.params[names[j]], laplace.params[names[i]])
                    for nsig in (1, 2):
                        w, h = 2 * nsig * np.sqrt(np.maximum(vals[::-1], 0))
                        ax.add_patch(Ellipse(centre, w, h, angle=angle, fill=False, color="tab:red", lw=1))
                    ax.plot(*centre, "+", color="tab:red")
            if i == k - 1:
                ax.set_xlabel(names[j])
            if j == 0 and i > 0:
                ax.set_ylabel(names[i])
    fig.suptitle(
        f"{samples.family.name}: {samples.method} draws ({samples.draws.shape[0]})"
        + ("; red = Laplace approximation" if laplace is not None else ""),
        fontsize=10,
    )
    return _save(fig, path)
