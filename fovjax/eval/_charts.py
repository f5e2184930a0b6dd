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


def _two_rows(fig, height_ratios):
    """The figure's two stacked sub-figures (matplotlib types them as one or an array)."""
    rows = fig.subfigures(2, 1, height_ratios=height_ratios)
    assert isinstance(rows, np.ndarray)  # two rows: always an array
    return rows[0], rows[1]


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
    line marks it and the cheapest configuration within it is ringed. Records with a true
    `planned` column (per-region fidelity planned by `plan_fidelity`) are drawn as diamonds
    over their point, apart from plain foveation's circles."""
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
    planned = np.array([bool(r.get("planned")) for r in records])
    if planned.any():
        ax.scatter(
            x[planned],
            y[planned],
            s=70,
            marker="D",
            facecolors="none",
            edgecolors="tab:purple",
            lw=1.6,
            zorder=4,
            label="planned fidelity (plan_fidelity)",
        )
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


PEOPLE_LABEL = "people"
OBSERVERS_LABEL = "automatic observers"


def _by_level(rows) -> dict:
    return {(r["fovea_deg"], r["periphery_deg"]): r for r in rows}


def plot_pair_test(
    rows: Sequence[dict],
    path,
    *,
    title: str | None = None,
    beside: Sequence[dict] | None = None,
    labels: tuple[str, str] = (PEOPLE_LABEL, OBSERVERS_LABEL),
) -> Path:
    """Figure 66 from `analyse_pair`: % of pair answers "same" per level, 95% Wilson intervals.
    `beside`: a second `analyse_pair` table (e.g. the automatic observers') drawn next to the
    first, `labels` naming the two."""
    if not rows:
        raise ValueError("plot_pair_test: no pair answers")
    fig = _figure((7, 4.5))
    ax = fig.add_subplot()
    levels = sorted(set(_by_level(rows)) | set(_by_level(beside or [])))
    pos = np.arange(len(levels))
    groups = [(rows, "tab:blue", labels[0] if beside else "same")]
    if beside:
        groups.append((beside, "0.55", labels[1]))
    width = 0.6 / len(groups)
    for k, (group, color, label) in enumerate(groups):
        by_level = _by_level(group)
        idx = [i for i, lv in enumerate(levels) if lv in by_level]
        offset = (k - (len(groups) - 1) / 2) * width
        _proportion_bars(ax, [by_level[levels[i]] for i in idx], pos[idx] + offset, width, color, label)
    ax.axhline(50, color="0.4", ls=":", lw=1)
    ax.set_xticks(pos, [f"{f:g}°/{p:g}°" for f, p in levels])
    ax.set_xlabel("foveation level (fovea / periphery)")
    ax.set_ylabel('answered "same" (% of answers)')
    ax.set_ylim(0, 100)
    if beside:
        ax.legend(fontsize=8)
    n = max(r["participants"] for r in rows)
    who = f"{n} participant(s)" + (
        f" beside {max(r['participants'] for r in beside)} {labels[1]}" if beside else ""
    )
    ax.set_title(title or f"Pair test (cf. thesis fig. 66): {who}, both orders")
    return _save(fig, path)


def plot_ramp_test(
    rows: Sequence[dict],
    path,
    *,
    title: str | None = None,
    beside: Sequence[dict] | None = None,
    labels: tuple[str, str] = (PEOPLE_LABEL, OBSERVERS_LABEL),
) -> Path:
    """Figure 67 from `analyse_ramp`: % of ramp answers "same" (equal to the reference) per
    level, upward and downward ramps side by side. `beside`: a second `analyse_ramp` table
    (e.g. the automatic observers'), drawn as markers on the first's bars."""
    if not rows:
        raise ValueError("plot_ramp_test: no ramp answers")
    levels = sorted({(r["fovea_deg"], r["periphery_deg"]) for r in [*rows, *(beside or [])]})
    fig = _figure((7.5, 4.5))
    ax = fig.add_subplot()
    pos = np.arange(len(levels))
    for k, (direction, color) in enumerate((("up", "tab:blue"), ("down", "tab:orange"))):
        low, high = f"{levels[0][0]:g}°", f"{levels[-1][0]:g}°"
        ramp = f"{low}→{high}" if direction == "up" else f"{high}→{low}"
        x = pos + (k - 0.5) * 0.38
        by_level = _by_level(r for r in rows if r["direction"] == direction)
        idx = [i for i, lv in enumerate(levels) if lv in by_level]
        if idx:
            who = f"{labels[0]}, " if beside else ""
            _proportion_bars(
                ax, [by_level[levels[i]] for i in idx], x[idx], 0.38, color, f"{who}ramp {direction} ({ramp})"
            )
        other = _by_level(r for r in (beside or []) if r["direction"] == direction)
        idx = [i for i, lv in enumerate(levels) if lv in other]
        if idx:
            ax.plot(
                x[idx],
                [other[levels[i]]["proportion_same"] * 100 for i in idx],
                "D",
                color="k",
                mfc="0.85" if direction == "up" else "0.45",
                ms=7,
                label=f"{labels[1]}, ramp {direction}",
            )
    ax.axhline(50, color="0.4", ls=":", lw=1)
    ax.set_xticks(pos, [f"{f:g}°/{p:g}°" for f, p in levels])
    ax.set_xlabel("foveation level (fovea / periphery)")
    ax.set_ylabel('answered "same" as the reference (%)')
    ax.set_ylim(0, 100)
    ax.legend(fontsize=8)
    ax.set_title(title or "Ramp test (cf. thesis fig. 67)")
    return _save(fig, path)


def plot_slider_test(
    rows: Sequence[dict],
    path,
    *,
    title: str | None = None,
    beside: Sequence[dict] | None = None,
    labels: tuple[str, str] = (PEOPLE_LABEL, OBSERVERS_LABEL),
) -> Path:
    """Figure 68 from `analyse_slider`: participants per chosen level. With `beside` (a second
    `analyse_slider` table, e.g. the automatic observers'), both as % of their participants,
    side by side."""
    if not rows:
        raise ValueError("plot_slider_test: no levels")
    fig = _figure((7, 4.5))
    ax = fig.add_subplot()
    pos = np.arange(len(rows))
    counts = [r["participants"] for r in rows]
    if beside:
        for k, (group, color, label) in enumerate(
            ((rows, "tab:green", labels[0]), (beside, "0.55", labels[1]))
        ):
            total = sum(r["participants"] for r in group)
            share = [100 * r["participants"] / total if total else 0.0 for r in group]
            ax.bar(pos + (k - 0.5) * 0.38, share, 0.38, color=color, alpha=0.85, label=f"{label} (n={total})")
        ax.set_ylabel("participants (%)")
        ax.legend(fontsize=8)
    else:
        ax.bar(pos, counts, 0.6, color="tab:green", alpha=0.85)
        ax.set_ylabel("participants")
        from matplotlib.ticker import MaxNLocator

        # The default locator's steps, whole participants only.
        ax.yaxis.set_major_locator(MaxNLocator(nbins="auto", steps=[1, 2, 2.5, 5, 10], integer=True))
    ax.set_xticks(pos, _level_names(rows))
    ax.set_xlabel("lowest level reported equivalent to the reference")
    ax.set_title(title or f"Slider test (cf. thesis fig. 68): {sum(counts)} participant(s)")
    return _save(fig, path)


def write_study_report(
    responses, out_dir, *, levels=None, beside=None, labels: tuple[str, str] = (PEOPLE_LABEL, OBSERVERS_LABEL)
) -> dict[str, Path]:
    """Analyse answers (human or automatic) and write the three summary tables (CSV) and
    figures 66-68 (PNG) into `out_dir`; returns the paths by name. `beside`: a second set of
    answers (e.g. the automatic observers' next to people's) analysed the same way, its tables
    written as `*_observers.csv` and drawn in the same figures, `labels` naming the two."""
    from ._pareto import write_csv
    from ._protocols import APPENDIX_LEVELS, analyse_pair, analyse_ramp, analyse_slider

    responses = list(responses)
    levels = APPENDIX_LEVELS if levels is None else levels
    out = Path(out_dir)
    paths: dict[str, Path] = {}
    pair, ramp = analyse_pair(responses), analyse_ramp(responses)
    slider = analyse_slider(responses, levels)
    other = None
    if beside is not None:
        beside = list(beside)
        other = {
            "pair": analyse_pair(beside),
            "ramp": analyse_ramp(beside),
            "slider": analyse_slider(beside, levels),
        }
        for name, rows in other.items():
            if rows and (name != "slider" or any(r["participants"] for r in rows)):
                paths[f"{name}_observers_csv"] = write_csv(rows, out / f"{name}_test_observers.csv")
    if pair:
        paths["pair_csv"] = write_csv(pair, out / "pair_test.csv")
        paths["pair_png"] = plot_pair_test(
            pair, out / "fig66_pair_test.png", beside=other["pair"] if other else None, labels=labels
        )
    if ramp:
        paths["ramp_csv"] = write_csv(ramp, out / "ramp_test.csv")
        paths["ramp_png"] = plot_ramp_test(
            ramp, out / "fig67_ramp_test.png", beside=other["ramp"] if other else None, labels=labels
        )
    if any(r["participants"] for r in slider):
        paths["slider_csv"] = write_csv(slider, out / "slider_test.csv")
        other_slider = other["slider"] if other else None
        if other_slider and not any(r["participants"] for r in other_slider):
            other_slider = None
        paths["slider_png"] = plot_slider_test(
            slider, out / "fig68_slider_test.png", beside=other_slider, labels=labels
        )
    return paths


# ---- temporal stability and failure cases (fovjax.eval._stability, fovjax.eval._failures) -----


def _rows(records, where: str, **match) -> list[dict]:
    rows = [r for r in as_records(records) if all(r.get(k) == v for k, v in match.items())]
    if not rows:
        raise ValueError(f"{where}: no records with {match}")
    return rows


def _mean_by(rows: Sequence[dict], by: str, value: str) -> tuple[list, np.ndarray]:
    """Distinct values of `by` (in order of appearance) and the mean of `value` for each."""
    keys = list(dict.fromkeys(r[by] for r in rows))
    means = [np.nanmean([float(r[value]) for r in rows if r[by] == k]) for k in keys]
    return keys, np.asarray(means, np.float64)


def _error_metrics(rows, *names) -> list[str]:
    """Those of `names` present in the records (FLIP columns exist only with flip-evaluator)."""
    return [n for n in names if n in rows[0]]


def plot_flicker(records, path, *, summary: Sequence[dict] | None = None, title: str | None = None) -> Path:
    """Flicker per frame step (`temporal_stability` records): beyond the fovea and in the
    periphery band, foveated per key mode against the full render with a fresh key, and the
    gaze step per frame; the summary ratios in the legend."""
    rows = as_records(records)
    if not rows:
        raise ValueError("plot_flicker: no records")
    modes = list(dict.fromkeys(r["key_mode"] for r in rows))
    ratio = {r["key_mode"]: r for r in (summary or [])}
    fig = _figure((9, 8))
    axes = fig.subplots(3, 1, sharex=True)
    colours = {"fresh": "tab:red", "fixed": "tab:blue"}
    for ax, region in zip(axes[:2], ("beyond_fovea", "periphery"), strict=True):
        first = _rows(rows, "plot_flicker", key_mode=modes[0])
        t = [r["frame"] for r in first]
        ax.plot(
            t,
            [r[f"full_fresh_flicker_{region}"] for r in first],
            "k--",
            lw=1.4,
            label="full render, fresh key",
        )
        for mode in modes:
            mrows = _rows(rows, "plot_flicker", key_mode=mode)
            label = f"foveated, {mode} key"
            if mode in ratio:
                label += f" (ratio {ratio[mode][f'ratio_{region}']:.2f})"
            ax.plot(
                [r["frame"] for r in mrows],
                [r[f"flicker_{region}"] for r in mrows],
                "o-",
                color=colours.get(mode),
                ms=3,
                label=label,
            )
        ax.set_ylabel(f"mean |Δ| {region.replace('_', ' ')}\n(sRGB, 0-1)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[2].bar(t, [r["gaze_step_deg"] for r in first], color="0.5")
    axes[2].set_ylabel("gaze step (deg)")
    axes[2].set_xlabel("frame")
    axes[2].grid(alpha=0.3)
    fig.suptitle(title or "flicker frame to frame, foveated against the full render")
    return _save(fig, path)


def plot_scanpath_flicker(records, path, *, title: str | None = None) -> Path:
    """`plot_flicker` for the scanpath failure case (ratios recomputed from the records)."""
    rows = as_records(records)
    summary = []
    for mode in dict.fromkeys(r["key_mode"] for r in rows):
        mrows = [r for r in rows if r["key_mode"] == mode]
        row = {"key_mode": mode}
        for region in ("beyond_fovea", "periphery"):
            fov = np.nanmean([r[f"flicker_{region}"] for r in mrows])
            full = np.nanmean([r[f"full_fresh_flicker_{region}"] for r in mrows])
            row[f"ratio_{region}"] = fov / full if full > 0 else math.nan
        summary.append(row)
    return plot_flicker(rows, path, summary=summary, title=title)


def _ring_panels(
    fig,
    rows,
    group: str,
    metrics: Sequence[str],
    labels: Mapping[str, str] | None = None,
    styles: Mapping[str, dict] | None = None,
):
    axes = fig.subplots(len(metrics), 1, sharex=True, squeeze=False)[:, 0]
    for ax, metric in zip(axes, metrics, strict=True):
        for g in dict.fromkeys(r[group] for r in rows):
            grows = [r for r in rows if r[group] == g and r.get("ring_pixels", 1) > 0]
            lower, means = _mean_by(grows, "ring_lower_deg", metric)
            width = float(grows[0]["ring_upper_deg"] - grows[0]["ring_lower_deg"])
            edges = np.append(np.asarray(lower, float), float(lower[-1]) + width)
            style = {"lw": 1.6, **(styles or {}).get(g, {})}
            ax.stairs(means, edges, label=(labels or {}).get(g, str(g)), **style)
        ax.set_ylabel({"abs_error": "mean |error| (sRGB)", "flip": "mean FLIP"}.get(metric, metric))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[-1].set_xlabel("eccentricity from the gaze (degrees)")
    return axes


def plot_corner_gaze(records, path, *, title: str | None = None) -> Path:
    """Error (and FLIP) per eccentricity ring for the centre and the corner gaze."""
    rows = as_records(records)
    if not rows:
        raise ValueError("plot_corner_gaze: no records")
    labels = {}
    for g in dict.fromkeys(r["gaze"] for r in rows):
        grows = [r for r in rows if r["gaze"] == g]
        extra = (
            f", frame FLIP {np.mean([r['frame_flip'] for r in grows]):.4f}"
            if "frame_flip" in grows[0]
            else ""
        )
        labels[g] = f"{g} ({grows[0]['gaze_x']:.2f}, {grows[0]['gaze_y']:.2f}){extra}"
    fig = _figure((8.5, 7))
    _ring_panels(fig, rows, "gaze", _error_metrics(rows, "abs_error", "flip"), labels)
    fig.suptitle(title or "corner gaze against centre gaze")
    return _save(fig, path)


def plot_tracking_error(records, path, *, title: str | None = None) -> Path:
    """Error around the true gaze against the tracker error, one line per fovea size (mean
    over directions and keys; each direction a faint point), inside the true fovea and the
    central 2°, and the share of the true fovea the rendered fovea covers."""
    rows = as_records(records)
    if not rows:
        raise ValueError("plot_tracking_error: no records")
    metrics = _error_metrics(rows, "flip_true_fovea", "flip_central") or ["abs_true_fovea", "abs_central"]
    metrics = [*metrics, "true_fovea_covered"]
    fig = _figure((8.5, 3.0 * len(metrics)))
    axes = fig.subplots(len(metrics), 1, sharex=True)
    for ax, metric in zip(axes, metrics, strict=True):
        for fovea in dict.fromkeys(r["fovea_deg"] for r in rows):
            frows = [r for r in rows if r["fovea_deg"] == fovea]
            errs, means = _mean_by(frows, "tracker_error_deg", metric)
            line = ax.plot(
                errs,
                means,
                "o-",
                lw=1.6,
                label=f"fovea {fovea:g}° (periphery {frows[0]['periphery_deg']:g}°)",
            )
            ax.scatter(
                [r["tracker_error_deg"] for r in frows],
                [r[metric] for r in frows],
                s=10,
                color=line[0].get_color(),
                alpha=0.4,
            )
            ax.axvline(fovea, color=line[0].get_color(), ls=":", lw=1)
        ax.set_ylabel(metric.replace("_", " "))
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("tracker error (degrees; dotted: the fovea radius)")
    fig.suptitle(title or "error around the true gaze against tracker error")
    return _save(fig, path)


def _policy_style(row, latencies) -> dict:
    colour = {"perfect": "tab:blue", "latest": "tab:orange", "predicted": "tab:green"}.get(row["policy"])
    rank = latencies.index(row["latency_ms"]) if row.get("latency_ms") in latencies else 0
    return {"color": colour, "ls": ("-", "--", ":", "-.")[rank % 4], "marker": "o"}


def plot_after_saccade(records, path, *, title: str | None = None) -> Path:
    """Per display policy, frame by frame around the saccade: the angle between the shown
    and the true gaze, and the error around the true gaze (central 2° and the true fovea);
    the saccade shaded."""
    rows = as_records(records)
    if not rows:
        raise ValueError("plot_after_saccade: no records")
    metrics = [
        "gaze_error_deg",
        *(_error_metrics(rows, "flip_central", "flip_true_fovea") or ["abs_central", "abs_true_fovea"]),
    ]
    fig = _figure((8.5, 8))
    axes = fig.subplots(len(metrics), 1, sharex=True)
    latencies = sorted({r.get("latency_ms", 0.0) for r in rows if r["policy"] != "perfect"})
    sacc = [r["since_landing_ms"] for r in rows if r["phase"] == "saccade"]
    onset = min(sacc, default=0.0)
    for ax, metric in zip(axes, metrics, strict=True):
        for display in dict.fromkeys(r.get("display", r["policy"]) for r in rows):
            prows = [r for r in rows if r.get("display", r["policy"]) == display]
            ax.plot(
                [r["since_landing_ms"] for r in prows],
                [r[metric] for r in prows],
                **_policy_style(prows[0], latencies),
                ms=3,
                label=display,
            )
        ax.axvspan(onset, 0.0, color="0.85", zorder=0)
        ax.set_ylabel(metric.replace("_", " "))
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, title="gaze the frame is foveated on")
    axes[-1].set_xlabel("time since the saccade landed (ms; grey: frames shown during the saccade)")
    fig.suptitle(title or "frames around a saccade")
    return _save(fig, path)


def plot_high_spp(records, path, *, title: str | None = None) -> Path:
    """Per spp: ms per frame of the full and the foveated render (speed-up annotated), and
    the error of the foveated frame against the full one and of both against a converged
    image."""
    rows = as_records(records)
    if not rows:
        raise ValueError("plot_high_spp: no records")
    m = "flip" if "flip_foveated_vs_full" in rows[0] else "abs"
    spp, full_ms = _mean_by(rows, "spp", "full_ms")
    _, fov_ms = _mean_by(rows, "spp", "foveated_ms")
    fig = _figure((8.5, 7))
    ax0, ax1 = fig.subplots(2, 1, sharex=True)
    ax0.plot(spp, full_ms, "s-", color="k", label="full")
    ax0.plot(spp, fov_ms, "o-", color="tab:red", label="foveated")
    for s, a, b in zip(spp, full_ms, fov_ms, strict=True):
        ax0.annotate(f"{a / b:.1f}x", (s, b), xytext=(4, -12), textcoords="offset points", fontsize=9)
    ax0.set_yscale("log")
    ax0.set_ylabel("ms per frame (compile excluded)")
    ax0.legend(fontsize=8)
    ax0.grid(alpha=0.3, which="both")
    for col, style, label in (
        (f"{m}_foveated_vs_full", "o-", "foveated vs full (same spp, key)"),
        (f"{m}_foveated_vs_converged", "o--", "foveated vs converged"),
        (f"{m}_full_vs_converged", "s--", "full vs converged"),
    ):
        ax1.plot(spp, _mean_by(rows, "spp", col)[1], style, label=label)
    ax1.set_ylabel(f"mean {m.upper() if m == 'flip' else '|error|'}")
    ax1.set_xscale("log", base=2)
    ax1.set_xticks(spp, [str(s) for s in spp])
    ax1.set_xlabel("samples per pixel")
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3)
    fig.suptitle(title or "samples per pixel: time and error")
    return _save(fig, path)


def plot_checkerboard(records, path, *, title: str | None = None) -> Path:
    """Error per ring, checkerboard against smooth wall, and the flicker ratios (foveated /
    full fresh-key render, beyond the fovea) per key mode."""
    rows = as_records(records)
    rings = [r for r in rows if r.get("kind") == "ring"]
    flick = [r for r in rows if r.get("kind") == "flicker"]
    if not rings or not flick:
        raise ValueError("plot_checkerboard: need both 'ring' and 'flicker' records")
    metrics = _error_metrics(rings, "abs_error", "flip")
    fig = _figure((8.5, 3.0 * (len(metrics) + 1)))
    sub = _two_rows(fig, [len(metrics), 1])
    _ring_panels(sub[0], rings, "scene", metrics)
    ax = sub[1].subplots()
    scenes = list(dict.fromkeys(r["scene"] for r in flick))
    bars = [("full render, fresh key", "full_fresh_flicker_beyond_fovea", "fresh", "0.3")]
    bars += [
        (f"foveated, {m} key", "flicker_beyond_fovea", m, c)
        for m, c in (("fresh", "tab:red"), ("fixed", "tab:blue"))
    ]
    width = 0.8 / len(bars)
    for j, (label, col, mode, colour) in enumerate(bars):
        vals = [
            next((r[col] for r in flick if r["scene"] == s and r["key_mode"] == mode), math.nan)
            for s in scenes
        ]
        pos = np.arange(len(scenes)) + (j - (len(bars) - 1) / 2) * width
        drawn = ax.bar(pos, np.maximum(np.nan_to_num(vals), 1e-6), width, color=colour, label=label)
        ax.bar_label(drawn, labels=[f"{v:.2g}" for v in vals], fontsize=8)
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(scenes)), scenes)
    ax.set_ylabel("flicker beyond the fovea\n(mean |Δ| per frame, sRGB)")
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    fig.suptitle(title or "fine checkerboard periphery against a smooth wall")
    return _save(fig, path)


def plot_acuity_models(records, path, *, title: str | None = None) -> Path:
    """Acuity models at an equal ray budget: error and primary rays per ring per model, and
    frame FLIP (or |error|) per model with its realised rays."""
    rows = as_records(records)
    rings = [r for r in rows if r.get("kind") == "ring"]
    frames = [r for r in rows if r.get("kind") == "frame"]
    if not rings or not frames:
        raise ValueError("plot_acuity_models: need both 'ring' and 'frame' records")
    metric = "flip" if "flip" in rings[0] else "abs_error"
    fig = _figure((9, 10))
    sub = _two_rows(fig, [2, 1])
    group = "arm" if "arm" in rings[0] else "model"
    models = list(dict.fromkeys(r["model"] for r in rings))
    rules = list(dict.fromkeys(r.get("rule", "") for r in rings))
    colours = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")
    styles = {
        r[group]: {
            "color": colours[models.index(r["model"]) % 6],
            "ls": ("-", "--", ":")[rules.index(r.get("rule", "")) % 3],
        }
        for r in rings
    }
    axes = _ring_panels(sub[0], rings, group, [metric, "ring_primary_rays"], styles=styles)
    axes[1].set_yscale("log")
    axes[1].set_ylabel("primary rays per ring")
    ax = sub[1].subplots()
    fm = "frame_flip" if "frame_flip" in frames[0] else "frame_abs_error"
    names, vals = _mean_by(frames, group, fm)
    _, rays = _mean_by(frames, group, "primary_rays")
    bars = ax.bar(np.arange(len(names)), vals, color=[styles[n]["color"] for n in names], alpha=0.8)
    ax.bar_label(
        bars, labels=[f"{v:.4f}\n{r:,.0f} rays" for v, r in zip(vals, rays, strict=True)], fontsize=8
    )
    ax.set_xticks(np.arange(len(names)), names, rotation=20, ha="right", fontsize=8)
    ax.set_ylabel(f"mean {fm.replace('_', ' ')}")
    ax.set_ylim(0, float(np.nanmax(vals)) * 1.35 if np.isfinite(vals).any() else 1)
    ax.grid(axis="y", alpha=0.3)
    fig.suptitle(title or "acuity models at an equal ray budget")
    return _save(fig, path)


def plot_methods_cost_quality(
    table,
    path,
    *,
    costs: Sequence[str] = ("new_rays_per_frame", "ms_per_frame"),
    quality: str = "jod",
    method: str = "method",
    label: str = "config",
    title: str | None = None,
) -> Path:
    """One panel per cost column (x) against the `quality` column (y, higher is better), one
    colour and marker per `method`, intervals as error bars where `quality_lo/_hi` exist, and
    in each panel the Pareto front (least cost, best quality) across methods ringed and joined
    by a step line; every point labelled with its `label` column."""
    records = as_records(table)
    if not records or not costs:
        raise ValueError("plot_methods_cost_quality: need records and at least one cost column")
    y = _column(records, quality, "plot_methods_cost_quality")
    err = _interval(records, quality, "plot_methods_cost_quality")
    methods = list(dict.fromkeys(str(r.get(method, "")) for r in records))
    colours = ("tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:pink", "tab:olive")
    markers = ("o", "s", "^", "D", "v", "P", "X")
    fig = _figure((6.0 * len(costs), 5.2))
    axes = fig.subplots(1, len(costs), squeeze=False)[0]
    names = _labels(records, label)
    for ax, cost in zip(axes, costs, strict=True):
        x = _column(records, cost, "plot_methods_cost_quality")
        for i, name in enumerate(methods):
            pick = np.array([str(r.get(method, "")) == name for r in records])
            yerr = None if err is None else err[:, pick]
            ax.errorbar(
                x[pick],
                y[pick],
                yerr=yerr,
                fmt=markers[i % len(markers)],
                color=colours[i % len(colours)],
                ecolor="0.6",
                capsize=2,
                ms=7,
                label=name,
                zorder=2,
            )
        front = pareto_front(records, {cost: "min", quality: "max"})
        order = np.argsort(x[front], kind="stable")
        ax.step(x[front][order], y[front][order], where="post", color="tab:red", lw=1.2, zorder=1)
        ax.scatter(
            x[front],
            y[front],
            s=180,
            facecolors="none",
            edgecolors="tab:red",
            lw=1.5,
            zorder=3,
            label="Pareto front",
        )
        for xi, yi, text in zip(x, y, names, strict=True):
            if math.isfinite(xi) and math.isfinite(yi):
                ax.annotate(text, (xi, yi), xytext=(4, 4), textcoords="offset points", fontsize=7)
        ax.set_xlabel(cost)
        ax.set_ylabel(f"{quality} (higher is better)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title or f"{quality} against cost by method", fontsize=10)
    return _save(fig, path)
