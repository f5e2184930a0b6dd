"""Where the solvers fail: a sweep over solver × start × noise × data size × eccentricity range.

Synthetic data come from the thesis's curve (a, b, c) = (0.90964, 2.9661°, 0.00792) at n points
evenly spaced on [0, ω_max]; noisy sets are V·(1 + σ·z), z ~ N(0, 1), fitted with sd = σ·V (the
noise is multiplicative so acuity stays positive). Every solver starts from every point of a grid
(and from the data-driven guess) on every data set. Each run gets the outcome `fit` would report:

    ok, step_limit, diverged, singular_step, stalled, unidentifiable, too_few_points
    (n ≤ 3 is rejected by `fit` before any solve; the raw solver outcome is kept as `raw`),
    local_minimum — passed every check but its χ² exceeds the best χ² any solver/start reached on
    the same data set by more than 1e-6 relative: a silent failure no check can see.

Run: `fovjax fit-stability [-o fits/stability] [--runs]`. Writes `summary.csv` (by solver × ω_max
× n × σ), `by_solver_range.csv`, `by_start.csv`, `stability.png`, and with `--runs` also
`runs.csv` (one row per run).
"""

from __future__ import annotations

import csv
import itertools
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ._fit import SOLVERS, SolverOptions, batch_fit
from ._models import THESIS_MODEL, Exponential

TRUTH = np.array([0.90964, 2.9661, 0.00792])
OUTCOME_ORDER = (
    "ok",
    "local_minimum",
    "step_limit",
    "stalled",
    "diverged",
    "singular_step",
    "unidentifiable",
    "too_few_points",
)


@dataclass(frozen=True)
class SweepConfig:
    solvers: tuple[str, ...] = tuple(SOLVERS)
    sizes: tuple[int, ...] = (2, 3, 4, 6, 10, 20)
    ranges: tuple[float, ...] = (40.0, 10.0, 3.0)
    noises: tuple[float, ...] = (0.0, 0.05, 0.15)
    seeds: int = 3  # noisy replicates per (n, ω_max, σ); σ = 0 has one
    start_a: tuple[float, ...] = (0.3, 0.9, 3.0)
    start_b: tuple[float, ...] = (0.3, 3.0, 30.0)
    start_c: tuple[float, ...] = (-0.1, 0.0, 0.3)
    max_steps: int = 500
    seed: int = 0


def _datasets(cfg: SweepConfig):
    rng = np.random.default_rng(cfg.seed)
    out = []
    for wmax, n, noise in itertools.product(cfg.ranges, cfg.sizes, cfg.noises):
        omega = np.linspace(0.0, wmax, n)
        with jax.enable_x64(True):
            clean = np.asarray(THESIS_MODEL(jnp.asarray(omega)))
        for rep in range(1 if noise == 0 else cfg.seeds):
            v = clean * (1.0 + noise * rng.standard_normal(n)) if noise else clean
            weight = 1.0 / (noise * clean) if noise else np.ones(n)
            out.append(
                {"wmax": wmax, "n": n, "noise": noise, "rep": rep, "omega": omega, "v": v, "w": weight}
            )
    return out


def run_sweep(cfg: SweepConfig = SweepConfig()) -> list[dict]:
    """One dict per run (solver × start × data set)."""
    sets = _datasets(cfg)
    grid = list(itertools.product(cfg.start_a, cfg.start_b, cfg.start_c))
    runs = []
    nmax = max(cfg.sizes)
    for solver in cfg.solvers:
        rows, om, vv, ww, starts = [], [], [], [], []
        for d_index, d in enumerate(sets):
            guess = Exponential.initial_guess(d["omega"], d["v"])
            start_list = [("data", np.array([float(guess.a), float(guess.b), float(guess.c)]))]
            start_list += [(f"a={a:g} b={b:g} c={c:g}", np.array([a, b, c])) for a, b, c in grid]
            n = d["n"]
            # Pad every set to the largest size with zero-weight points so one batch covers all.
            pad = nmax - n
            for label, p0 in start_list:
                rows.append(
                    {
                        "solver": solver,
                        "dataset": d_index,
                        "start": label,
                        **{k: d[k] for k in ("wmax", "n", "noise", "rep")},
                    }
                )
                om.append(np.pad(d["omega"], (0, pad), mode="edge"))
                vv.append(np.pad(d["v"], (0, pad), mode="edge"))
                ww.append(np.pad(d["w"], (0, pad)))
                starts.append(p0)
        t0 = time.perf_counter()
        out = batch_fit(
            Exponential,
            np.array(om),
            np.array(vv),
            np.array(ww),
            np.array(starts),
            options=SolverOptions(solver, max_steps=cfg.max_steps),
        )
        seconds = time.perf_counter() - t0
        with np.errstate(over="ignore", invalid="ignore"):
            chi2 = np.sum(out.r**2, axis=1)
        for i, row in enumerate(rows):
            row.update(
                raw=str(out.kind[i]),
                iterations=int(out.steps[i]),
                chi2=float(chi2[i]),
                a=float(out.p[i, 0]),
                b=float(out.p[i, 1]),
                c=float(out.p[i, 2]),
                batch_seconds=seconds,
            )
        runs.extend(rows)

    # The best χ² any solver and start reached on each data set, for the local-minimum test.
    best: dict[int, float] = {}
    for r in runs:
        if r["raw"] == "ok":
            best[r["dataset"]] = min(best.get(r["dataset"], np.inf), r["chi2"])
    for r in runs:
        outcome = r["raw"]
        if r["n"] <= 3:
            outcome = "too_few_points"
        elif outcome == "ok" and r["chi2"] > best[r["dataset"]] * (1 + 1e-6) + 1e-12:
            outcome = "local_minimum"
        r["outcome"] = outcome
        err = np.abs(np.array([r["a"], r["b"], r["c"]]) / TRUTH - 1.0)
        r["err_a"], r["err_b"], r["err_c"] = (float(e) for e in err)
    return runs


def _write_csv(path: Path, rows: list[dict], fields: list[str]) -> None:
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fields, extrasaction="ignore", lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})


def summarise(runs: list[dict], keys: tuple[str, ...]) -> list[dict]:
    groups: dict[tuple, list[dict]] = {}
    for r in runs:
        groups.setdefault(tuple(r[k] for k in keys), []).append(r)
    out = []
    for key, rs in groups.items():
        counts = Counter(r["outcome"] for r in rs)
        ok = [r for r in rs if r["outcome"] == "ok"]
        row = dict(zip(keys, key, strict=True))
        row["runs"] = len(rs)
        row["success_rate"] = len(ok) / len(rs)
        for o in OUTCOME_ORDER:
            row[o] = counts.get(o, 0)
        row["median_iterations"] = float(np.median([r["iterations"] for r in ok])) if ok else float("nan")
        for p in "abc":
            row[f"median_err_{p}"] = float(np.median([r[f"err_{p}"] for r in ok])) if ok else float("nan")
        out.append(row)
    return out


def plot_sweep(runs: list[dict], cfg: SweepConfig, path: Path) -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    solvers = cfg.solvers
    fig = Figure(figsize=(4.2 * len(solvers) + 1, 10.5), layout="constrained")
    grid = fig.add_gridspec(2, len(solvers), height_ratios=(2.2, 1))
    rows = [(w, n) for w in cfg.ranges for n in cfg.sizes if n > 3]
    colors = {
        "ok": "tab:green",
        "local_minimum": "gold",
        "step_limit": "tab:orange",
        "stalled": "tab:brown",
        "diverged": "tab:red",
        "singular_step": "tab:purple",
        "unidentifiable": "tab:gray",
    }
    image = None
    for s_i, solver in enumerate(solvers):
        ax = fig.add_subplot(grid[0, s_i])
        rate = np.zeros((len(rows), len(cfg.noises)))
        for r_i, (w, n) in enumerate(rows):
            for c_i, noise in enumerate(cfg.noises):
                sel = [
                    r
                    for r in runs
                    if r["solver"] == solver and r["wmax"] == w and r["n"] == n and r["noise"] == noise
                ]
                rate[r_i, c_i] = np.mean([r["outcome"] == "ok" for r in sel])
                ax.text(c_i, r_i, f"{100 * rate[r_i, c_i]:.0f}", ha="center", va="center", fontsize=8)
        image = ax.imshow(rate, vmin=0, vmax=1, cmap="RdYlGn", aspect="auto")
        ax.set_xticks(range(len(cfg.noises)), [f"σ={x:g}" for x in cfg.noises])
        ax.set_yticks(range(len(rows)), [f"ω≤{w:g}°, n={n}" for w, n in rows] if s_i == 0 else [])
        ax.set_title(f"{solver}: % ok", fontsize=10)

        bar = fig.add_subplot(grid[1, s_i])
        bottoms = np.zeros(len(cfg.ranges))
        for outcome, color in colors.items():
            heights = np.array(
                [
                    np.mean(
                        [
                            r["outcome"] == outcome
                            for r in runs
                            if r["solver"] == solver and r["wmax"] == w and r["n"] > 3
                        ]
                    )
                    for w in cfg.ranges
                ]
            )
            bar.bar(range(len(cfg.ranges)), heights, bottom=bottoms, color=color, label=outcome)
            bottoms += heights
        bar.set_xticks(range(len(cfg.ranges)), [f"ω≤{w:g}°" for w in cfg.ranges])
        bar.set_ylim(0, 1)
        bar.set_title("outcomes, n ≥ 4, all starts and σ", fontsize=9)
        if s_i == len(solvers) - 1:
            bar.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))
    if image is None:
        raise ValueError("stability chart: no solvers to draw")
    fig.colorbar(image, ax=fig.axes[: 2 * len(solvers) : 2], shrink=0.6, label="fraction ok")
    fig.suptitle(
        "Exponential fit to the thesis curve: success by solver, eccentricity range ω_max, points n, "
        "relative noise σ "
        "(28 starts each; n ≤ 3 is rejected by fit)",
        fontsize=10,
    )
    FigureCanvasAgg(fig)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path


def write_sweep(
    out_dir: str | Path = "fits/stability", cfg: SweepConfig = SweepConfig(), write_runs: bool = False
) -> dict:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    runs = run_sweep(cfg)
    seconds = time.perf_counter() - t0
    run_fields = [
        "solver",
        "wmax",
        "n",
        "noise",
        "rep",
        "start",
        "outcome",
        "raw",
        "iterations",
        "chi2",
        "a",
        "b",
        "c",
    ]
    if write_runs:
        _write_csv(out_dir / "runs.csv", runs, run_fields)
    summary = summarise(runs, ("solver", "wmax", "n", "noise"))
    stat_fields = [
        "runs",
        "success_rate",
        *OUTCOME_ORDER,
        "median_iterations",
        "median_err_a",
        "median_err_b",
        "median_err_c",
    ]
    _write_csv(out_dir / "summary.csv", summary, ["solver", "wmax", "n", "noise", *stat_fields])
    by_start = summarise([r for r in runs if r["n"] > 3], ("solver", "start"))
    _write_csv(out_dir / "by_start.csv", by_start, ["solver", "start", *stat_fields])
    by_solver = summarise([r for r in runs if r["n"] > 3], ("solver", "wmax"))
    _write_csv(out_dir / "by_solver_range.csv", by_solver, ["solver", "wmax", *stat_fields])
    plot_sweep(runs, cfg, out_dir / "stability.png")
    return {"runs": len(runs), "seconds": seconds, "by_solver_range": by_solver}
