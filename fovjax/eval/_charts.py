"""Charts with matplotlib's object API on the Agg canvas (no pyplot, no global backend change):
cost against accuracy with the Pareto front, per-configuration bars, error by eccentricity ring,
and the user study's figures 66-68."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from ._metrics import RingErrors
from ._pareto import CI_SUFFIXES, _column, as_records, cheapest_within, pareto_front


def _figure(size):
    from matplotlib.figure import Figure  # imported on use: matplotlib is slow to import

    return Figure(figsize=size, layout="constrained")


def _save(fig, path) -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=110)
    return path


def _interval(records, name: str, where: str) -> np.ndarray | None:
    """(2, n) error-bar half-widths from `name_lo`/`name_hi` columns, or None if absent."""
    lo_name, hi_name = (name + s for s in CI_SUFFIXES)
    if not all(lo_name in r and hi_name in r for r in records):
        return None
    mid = _column(records, name, where)
    lo, hi = _column(records, lo_name, where), _column(records, hi_name, where)
    return np.clip(np.nan_to_num(np.stack([mid - lo, hi - mid]), nan=0.0, posinf=0.0, neginf=0.0), 0.0, None)


def _labels(records, label: str) -> list[str]:
    return [str(r[label]) if label in r else str(i) for i, r in enumerate(records)]


def plot_cost_accuracy(
    table,
    path,
    *,
    cost: str,
    accuracy: str,
    sense: str,
    label: str = "config",
    threshold: float | None = None,
    log_cost: bool = False,
    title: str | None = None,
) -> Path:
    """Cost (x) against accuracy (y) for every record, each point labelled, confidence
    intervals as error bars where `accuracy_lo/_hi` exist, the Pareto front (minimum cost;
    `sense` "min" or "max" accuracy) as filled points joined by a step line. With a
    `threshold` on the accuracy column (an upper bound for "min", a lower bound for "max"), a
    line marks it and the cheapest configuration within it is ringed."""
    records = as_records(table)
    if not records:
        raise ValueError("plot_cost_accuracy: the table is empty")
    x = _column(records, cost, "plot_cost_accuracy")
    y = _column(records, accuracy, "plot_cost_accuracy")
    front = pareto_front(records, {cost: "min", accuracy: sense})
    err = _interval(records, accuracy, "plot_cost_accuracy")

    fig = _figure((8.5, 6))
    ax = fig.add_subplot()
    ax.errorbar(x, y, yerr=err, fmt="none", ecolor="0.6", elinewidth=1, capsize=2, zorder=1)
    ax.scatter(
        x[~front], y[~front], s=36, facecolors="white", edgecolors="tab:blue", zorder=2, label="dominated"
    )
    ax.scatter(x[front], y[front], s=44, color="tab:red", zorder=3, label="Pareto front")
    order = np.argsort(x[front], kind="stable")
    fx, fy = x[front][order], y[front][order]
    ax.step(fx, fy, where="post", color="tab:red", lw=1.2, zorder=2)
    for xi, yi, name in zip(x, y, _labels(records, label), strict=True):
        if math.isfinite(xi) and math.isfinite(yi):
            ax.annotate(name, (xi, yi), xytext=(4, 4), textcoords="offset points", fontsize=8)
    if threshold is not None:
        ax.axhline(threshold, color="0.3", ls="--", lw=1, label=f"threshold {threshold:g}")
        choice = cheapest_within(
            records, cost=cost, metric=accuracy, threshold=threshold, below=sense == "min", label=label
        )
        if choice is not None:
            ax.scatter(
                [x[choice.index]],
                [y[choice.index]],
                s=220,
                facecolors="none",
                edgecolors="tab:green",
                lw=2,
                zorder=4,
                label=f"cheapest within threshold: {choice.name}",
            )
    if log_cost:
        ax.set_xscale("log")
    ax.set_xlabel(cost)
    ax.set_ylabel(f"{accuracy} ({'lower' if sense == 'min' else 'higher'} is better)")
    ax.set_title(title or f"{accuracy} against {cost}")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_metric_bars(
    table, path, *, metrics: Sequence[str], label: str = "config", title: str | None = None
) -> Path:
    """One panel per metric column, one bar per record (e.g. per fovea threshold), with
    confidence-interval whiskers where `metric_lo/_hi` exist."""
    records = as_records(table)
    if not records or not metrics:
        raise ValueError("plot_metric_bars: need records and at least one metric column")
    names = _labels(records, label)
    fig = _figure((max(6.0, 0.6 * len(records) + 2), 2.6 * len(metrics) + 0.6))
    axes = fig.subplots(len(metrics), 1, sharex=True, squeeze=False)[:, 0]
    pos = np.arange(len(records))
    for ax, metric in zip(axes, metrics, strict=True):
        values = _column(records, metric, "plot_metric_bars")
        ax.bar(pos, np.nan_to_num(values, nan=0.0, posinf=0.0), color="tab:blue", alpha=0.8)
        err = _interval(records, metric, "plot_metric_bars")
        if err is not None:
            ax.errorbar(pos, values, yerr=err, fmt="none", ecolor="k", capsize=3, lw=1)
        for p, v in zip(pos, values, strict=True):
            if not math.isfinite(v):
                ax.annotate(f"{v}", (p, 0), ha="center", va="bottom", fontsize=8)
        ax.set_ylabel(metric)
        ax.grid(axis="y", alpha=0.3)
    axes[-1].set_xticks(pos, names, rotation=30, ha="right")
    fig.suptitle(title or "metrics per configuration")
    return _save(fig, path)


def _edges(rings: RingErrors) -> np.ndarray:
    return np.append(rings.lower_deg, rings.upper_deg[-1])


def plot_ring_errors(
    rings: Mapping[str, RingErrors],
    path,
    *,
    rays: Mapping[str, Sequence[float]] | None = None,
    title: str | None = None,
) -> Path:
    """Mean error per eccentricity ring, one step line per configuration (constant over each
    ring); with `rays` (per configuration, rays traced per ring, same rings), a second panel."""
    if not rings:
        raise ValueError("plot_ring_errors: no configurations given")
    fig = _figure((8.5, 7 if rays else 4.5))
    axes = fig.subplots(2 if rays else 1, 1, sharex=True, squeeze=False)[:, 0]
    units = set()
    for name, r in rings.items():
        axes[0].stairs(r.mean_error, _edges(r), lw=1.6, label=name)
        units.add(f"{r.error} [{r.units}]")
    axes[0].set_ylabel("mean error per pixel")
    axes[0].set_title(title or "error by eccentricity ring: " + "; ".join(sorted(units)), fontsize=9)
    axes[0].legend(fontsize=8)
    axes[0].grid(alpha=0.3)
    if rays:
        for name, counts in rays.items():
            if name not in rings:
                raise ValueError(f"plot_ring_errors: rays given for {name!r}, which has no ring errors")
            r = rings[name]
            counts = np.asarray(counts, np.float64)
            if counts.shape != r.lower_deg.shape:
                raise ValueError(
                    f"plot_ring_errors: {name!r}: {counts.size} ray counts for {r.lower_deg.size} rings"
                )
            axes[1].stairs(counts, _edges(r), lw=1.6, label=name)
        axes[1].set_ylabel("rays per ring")
        axes[1].set_yscale("log")
        axes[1].grid(alpha=0.3)
    ring = next(iter(rings.values()))
    axes[-1].set_xlabel(f"eccentricity (degrees; rings of {float(ring.upper_deg[0] - ring.lower_deg[0]):g}°)")
    return _save(fig, path)


def _proportion_bars(ax, rows, pos, width, color, label):
    p = np.array([r["proportion_same"] for r in rows]) * 100
    lo = np.array([r["proportion_same_lo"] for r in rows]) * 100
    hi = np.array([r["proportion_same_hi"] for r in rows]) * 100
    ax.bar(pos, p, width, color=color, alpha=0.85, label=label)
    yerr = np.clip(np.stack([p - lo, hi - p]), 0.0, None)
    ax.errorbar(pos, p, yerr=yerr, fmt="none", ecolor="k", capsize=3, lw=1)
    for x, y, r in zip(pos, p, rows, strict=True):
        inside = y >= 10  # white inside a tall bar, black just above a short one
        ax.annotate(
            f"{r['same']}/{r['answers']}",
            (x, y - 1.5 if inside else y + 1),
            ha="center",
            va="top" if inside else "bottom",
            fontsize=7,
            color="white" if inside else "black",
        )


def _level_names(rows) -> list[str]:
    return [f"{r['fovea_deg']:g}°/{r['periphery_deg']:g}°" for r in rows]


def plot_pair_test(rows: Sequence[dict], path, *, title: str | None = None) -> Path:
    """Figure 66 from `analyse_pair`: % of pair answers "same" per level, 95% Wilson intervals."""
    if not rows:
        raise ValueError("plot_pair_test: no pair answers")
    fig = _figure((7, 4.5))
    ax = fig.add_subplot()
    pos = np.arange(len(rows))
    _proportion_bars(ax, rows, pos, 0.6, "tab:blue", "same")
    ax.axhline(50, color="0.4", ls=":", lw=1)
    ax.set_xticks(pos, _level_names(rows))
    ax.set_xlabel("foveation level (fovea / periphery)")
    ax.set_ylabel('answered "same" (% of answers)')
    ax.set_ylim(0, 100)
    n = max(r["participants"] for r in rows)
    ax.set_title(title or f"Pair test (cf. thesis fig. 66): {n} participant(s), both orders")
    return _save(fig, path)


def plot_ramp_test(rows: Sequence[dict], path, *, title: str | None = None) -> Path:
    """Figure 67 from `analyse_ramp`: % of ramp answers "same" (equal to the reference) per
    level, upward and downward ramps side by side."""
    if not rows:
        raise ValueError("plot_ramp_test: no ramp answers")
    levels = sorted({(r["fovea_deg"], r["periphery_deg"]) for r in rows})
    fig = _figure((7.5, 4.5))
    ax = fig.add_subplot()
    pos = np.arange(len(levels))
    for k, (direction, color) in enumerate((("up", "tab:blue"), ("down", "tab:orange"))):
        by_level = {(r["fovea_deg"], r["periphery_deg"]): r for r in rows if r["direction"] == direction}
        idx = [i for i, lv in enumerate(levels) if lv in by_level]
        if idx:
            low, high = f"{levels[0][0]:g}°", f"{levels[-1][0]:g}°"
            ramp = f"{low}→{high}" if direction == "up" else f"{high}→{low}"
            _proportion_bars(
                ax,
                [by_level[levels[i]] for i in idx],
                pos[idx] + (k - 0.5) * 0.38,
                0.38,
                color,
                f"ramp {direction} ({ramp})",
            )
    ax.axhline(50, color="0.4", ls=":", lw=1)
    ax.set_xticks(pos, [f"{f:g}°/{p:g}°" for f, p in levels])
    ax.set_xlabel("foveation level (fovea / periphery)")
    ax.set_ylabel('answered "same" as the reference (%)')
    ax.set_ylim(0, 100)
    ax.legend(fontsize=8)
    ax.set_title(title or "Ramp test (cf. thesis fig. 67)")
    return _save(fig, path)


def plot_slider_test(rows: Sequence[dict], path, *, title: str | None = None) -> Path:
    """Figure 68 from `analyse_slider`: participants per chosen level."""
    if not rows:
        raise ValueError("plot_slider_test: no levels")
    fig = _figure((7, 4.5))
    ax = fig.add_subplot()
    pos = np.arange(len(rows))
    counts = [r["participants"] for r in rows]
    ax.bar(pos, counts, 0.6, color="tab:green", alpha=0.85)
    ax.set_xticks(pos, _level_names(rows))
    ax.set_xlabel("lowest level reported equivalent to the reference")
    ax.set_ylabel("participants")
    ax.yaxis.get_major_locator().set_params(integer=True)
    ax.set_title(title or f"Slider test (cf. thesis fig. 68): {sum(counts)} participant(s)")
    return _save(fig, path)


def write_study_report(responses, out_dir, *, levels=None) -> dict[str, Path]:
    """Analyse answers (human or automatic) and write the three summary tables (CSV) and
    figures 66-68 (PNG) into `out_dir`; returns the paths by name."""
    from ._pareto import write_csv
    from ._protocols import APPENDIX_LEVELS, analyse_pair, analyse_ramp, analyse_slider

    responses = list(responses)
    out = Path(out_dir)
    paths: dict[str, Path] = {}
    pair, ramp = analyse_pair(responses), analyse_ramp(responses)
    slider = analyse_slider(responses, APPENDIX_LEVELS if levels is None else levels)
    if pair:
        paths["pair_csv"] = write_csv(pair, out / "pair_test.csv")
        paths["pair_png"] = plot_pair_test(pair, out / "fig66_pair_test.png")
    if ramp:
        paths["ramp_csv"] = write_csv(ramp, out / "ramp_test.csv")
        paths["ramp_png"] = plot_ramp_test(ramp, out / "fig67_ramp_test.png")
    if any(r["participants"] for r in slider):
        paths["slider_csv"] = write_csv(slider, out / "slider_test.csv")
        paths["slider_png"] = plot_slider_test(slider, out / "fig68_slider_test.png")
    return paths
