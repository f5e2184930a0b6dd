"""Compare fovea thresholds programmatically: cost (rays, time) against accuracy (error and
perceptual difference to the full render of the same frame)."""

from __future__ import annotations

import dataclasses
import itertools
import statistics
from collections.abc import Sequence
from pathlib import Path

import jax
import numpy as np

from ._metrics import HmdDisplay, MissingExtraError, error_by_eccentricity, flip, fovvdp, psnr, ssim
from ._pareto import Choice, cheapest_within, mean_interval, pareto_front, write_csv

# Gaze positions (per-eye normalised display coordinates, both eyes the same) averaged over by
# default: the centre and two off-centre points.
DEFAULT_GAZES = ((0.5, 0.5), (0.3, 0.4), (0.7, 0.65))
# The criterion that names the recommended configuration: mean FLIP (LDR, ppd of the rig) at
# most this; FLIP 0 is identical, ~0.05 is a difference one has to look for in a flip test.
DEFAULT_CRITERION = ("flip", 0.05)
# Metrics where larger is better: a criterion on them asks for the interval to stay above.
HIGHER_IS_BETTER = ("psnr", "ssim", "jod")


THESIS_THRESHOLDS = ((5, 10), (7.5, 15), (10, 20), (12.5, 25), (15, 30))


def _sense(metric: str) -> str:
    return "max" if metric in HIGHER_IS_BETTER else "min"


@dataclasses.dataclass(frozen=True)
class Comparison:
    """`records`: one per configuration (CSV-writable); `rings`: per configuration label, the
    mean |error| (sRGB) and primary rays per 5° eccentricity ring; `choice`: the cheapest
    configuration meeting `criterion` (None if none does); `full`: the full render's cost;
    `plans`: with `plan=`, the `FidelityPlan` of each planned configuration, by label.
    `criterion` (metric, threshold): the metric's whole interval must stay below the threshold
    (above it for PSNR, SSIM and JOD, where larger is better)."""

    records: list[dict]
    rings: dict
    ring_rays: dict
    choice: Choice | None
    criterion: tuple[str, float]
    full: dict
    plans: dict = dataclasses.field(default_factory=dict)

    def write(self, out_dir) -> dict[str, Path]:
        """CSV and charts next to each other in `out_dir`."""
        from ._charts import plot_cost_accuracy, plot_metric_bars, plot_ring_errors

        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        metric, threshold = self.criterion
        paths = {"csv": write_csv(self.records, out / "comparison.csv")}
        for spp in sorted({r["spp"] for r in self.records}):
            rows = [r for r in self.records if r["spp"] == spp]
            paths[f"cost_accuracy_ms_spp{spp}"] = plot_cost_accuracy(
                rows,
                out / f"cost_accuracy_ms_spp{spp}.png",
                cost="ms_per_frame",
                accuracy=metric,
                sense=_sense(metric),
                threshold=threshold,
                title=f"ms per frame against {metric}, SPP {spp} "
                f"(full: {self.full[spp]['ms_per_frame']:.0f} ms)",
            )
            paths[f"cost_accuracy_rays_spp{spp}"] = plot_cost_accuracy(
                rows,
                out / f"cost_accuracy_rays_spp{spp}.png",
                cost="rays_per_frame",
                accuracy=metric,
                sense=_sense(metric),
                threshold=threshold,
                title=f"rays per frame against {metric}, SPP {spp}",
            )
            if any(r.get("method", "thesis") != "thesis" for r in rows):  # methods side by side
                paths[f"cost_accuracy_new_rays_spp{spp}"] = plot_cost_accuracy(
                    rows,
                    out / f"cost_accuracy_new_rays_spp{spp}.png",
                    cost="new_rays_per_frame",
                    accuracy=metric,
                    sense=_sense(metric),
                    threshold=threshold,
                    title=f"new primary rays per frame against {metric} by method, SPP {spp}",
                )
            metrics = [m for m in ("psnr", "ssim", "flip", "jod") if m in rows[0]]
            paths[f"bars_spp{spp}"] = plot_metric_bars(
                rows, out / f"bars_spp{spp}.png", metrics=["speedup", *metrics], title=f"SPP {spp}"
            )
        paths["rings"] = plot_ring_errors(
            self.rings, out / "rings.png", rays=self.ring_rays, title="error and primary rays by eccentricity"
        )
        return paths


def _metrics(test, ref, eccentricity, display, gazes_xy, use_flip, use_fovvdp):
    out = {"psnr": psnr(test, ref).value, "ssim": ssim(test, ref).value}
    if use_flip:
        out["flip"] = flip(test, ref, ppd=display.ppd).value
    if use_fovvdp:
        out["jod"] = fovvdp(test, ref, display, gaze_xy=gazes_xy).value
    rings = error_by_eccentricity(test, ref, eccentricity)
    return out, rings


def _summarise(name: str, values: Sequence[float]) -> dict:
    """Mean and 95% interval of a metric over a configuration's frames. The interval is over the
    finite samples and needs two of them; every frame identical (all values equal, e.g. PSNR +inf
    for identical images) gives the degenerate interval at that value; otherwise, with fewer than
    two finite samples, the interval is NaN and no criterion can be met on it."""
    values = [float(v) for v in values]
    finite = [v for v in values if np.isfinite(v)]
    if len(finite) >= 2:
        mean, lo, hi = mean_interval(finite)
    elif len(values) >= 2 and all(v == values[0] for v in values):
        mean = lo = hi = values[0]
    else:
        mean = float(np.mean(finite)) if finite else float(np.mean(values))
        lo = hi = float("nan")
    return {name: mean, f"{name}_lo": lo, f"{name}_hi": hi, f"{name}_n": len(finite)}


def _available(module: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(module) is not None


def _finite(x) -> bool:
    number = isinstance(x, int | float | np.integer | np.floating) and not isinstance(x, bool)
    return bool(number and np.isfinite(x))


@dataclasses.dataclass(frozen=True)
class ThresholdSweep:
    """The configurations `compare_thresholds` renders and the frames it measures them on.

    Args:
        thresholds: (fovea, periphery) pairs in degrees; default the thesis's five.
        spp: samples per pixel to compare (perfect squares).
        models: acuity models for P(ω) (None: the thesis's only).
        gazes: gaze points, (x, y) for both eyes or one per eye.
        keys: seeds of the frames' keys.
        rule: the sampling rule of every foveation (`fovjax.foveate.SAMPLING_RULES`).
        regions: the region reading (`fovjax.foveate.with_regions`, recorded per row): "angle"
            (fovjax's exact-angle regions, the default) or "thesis" (the thesis's Table 2
            reading; the one under which the thesis levels compare like-for-like with its
            participants' answers).
        methods: the foveation methods to sweep (names of `fovjax.foveate.METHODS` or method
            instances; default the thesis's): every method × threshold pair × spp, recorded per
            row (`method`, with `new_rays_per_frame` and `reused_pixels_per_frame`). A temporal
            method (`Weier2016`, `Patney2016`) is measured on each still frame after one frame
            of history of the same view (a reset, then the frame with the next key): its steady state on
            a still view, where it reuses the most.

    Raises:
        ValueError: a bad pair, SPP, gaze, key, rule, reading or method, naming it and what was
            expected.
    """

    thresholds: Sequence[tuple[float, float]] = THESIS_THRESHOLDS
    spp: Sequence[int] = (1, 4)
    models: Sequence | None = None
    gazes: Sequence = DEFAULT_GAZES
    keys: Sequence[int] = (0, 1)
    rule: str = "either"
    regions: str = "angle"
    methods: Sequence = ("thesis",)

    def __post_init__(self):
        from ..foveate import REGION_READINGS, SAMPLING_RULES

        where = "ThresholdSweep"
        for name in ("thresholds", "spp", "gazes", "keys", "methods"):
            value = getattr(self, name)
            if isinstance(value, str | bytes) or not isinstance(value, Sequence) or len(value) == 0:
                raise ValueError(f"{where}: {name} {value!r}: expected a non-empty sequence")
        for i, pair in enumerate(self.thresholds):
            ok = isinstance(pair, Sequence) and len(pair) == 2 and all(_finite(x) for x in pair)
            if not ok or not 0 <= pair[0] <= pair[1]:
                raise ValueError(
                    f"{where}: thresholds[{i}] {pair!r}: expected (fovea, periphery) degrees, "
                    "0 <= fovea <= periphery"
                )
        for i, s in enumerate(self.spp):
            if isinstance(s, bool) or not isinstance(s, int | np.integer) or s < 1 or round(s**0.5) ** 2 != s:
                raise ValueError(f"{where}: spp[{i}] {s!r}: expected a positive square (1, 4, 9, 16, ...)")
        for i, g in enumerate(self.gazes):
            try:
                a = np.asarray(g, np.float64)
            except (TypeError, ValueError):
                a = None
            if a is None or a.shape not in ((2,), (2, 2)) or not np.all((a >= 0) & (a <= 1)):
                raise ValueError(
                    f"{where}: gazes[{i}] {g!r}: expected (x, y) or ((lx, ly), (rx, ry)) in [0, 1]"
                )
        for i, k in enumerate(self.keys):
            if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 0:
                raise ValueError(f"{where}: keys[{i}] {k!r}: expected an integer seed >= 0")
        if self.models is not None and (
            isinstance(self.models, str) or not isinstance(self.models, Sequence)
        ):
            raise ValueError(f"{where}: models {self.models!r}: expected None or a sequence of acuity models")
        if self.rule not in SAMPLING_RULES:
            raise ValueError(f"{where}: rule {self.rule!r}: expected one of {SAMPLING_RULES}")
        if self.regions not in REGION_READINGS:
            raise ValueError(f"{where}: regions {self.regions!r}: expected one of {REGION_READINGS}")


# The keywords `compare_thresholds` took before `ThresholdSweep` and the renderer, still accepted
# (with a DeprecationWarning) because the README and the tutorials showed them.
_OLD_SWEEP = ("thresholds", "spp", "models", "gazes", "keys", "rule", "regions", "methods")
_OLD_RENDERER = ("config", "bvh")


def _upgrade_old_keywords(old: dict, sweep):
    """`sweep` and the renderer's arguments from the old keywords, each use warned of
    with its replacement; an unknown keyword is a TypeError as Python's own."""
    import warnings

    unknown = sorted(set(old) - {*_OLD_SWEEP, *_OLD_RENDERER})
    if unknown:
        raise TypeError(f"compare_thresholds() got an unexpected keyword argument {unknown[0]!r}")

    def moved(names, where):
        warnings.warn(
            f"compare_thresholds({', '.join(f'{n}=' for n in names)}) is deprecated; pass {where}",
            DeprecationWarning,
            stacklevel=4,
        )

    given = [n for n in _OLD_SWEEP if n in old]
    if given:
        if sweep is not None:
            raise ValueError(f"compare_thresholds: give sweep= or the old {', '.join(given)}=, not both")
        moved(given, "sweep=fovjax.eval.ThresholdSweep(...)")
        sweep = ThresholdSweep(**{n: old[n] for n in given})
    renderer = {n: old[n] for n in _OLD_RENDERER if n in old}
    if renderer:
        moved(
            list(renderer), "a fovjax.FoveatedRenderer(scene, rig, config=..., bvh=...) in place of the scene"
        )
    return sweep, renderer


def compare_thresholds(
    scene,
    rig=None,
    sweep: ThresholdSweep | None = None,
    *,
    criterion: tuple[str, float] = DEFAULT_CRITERION,
    perceptual: bool | None = None,
    plan: tuple[str, float] | tuple[str, float, float | None] | None = None,
    shard: bool = False,
    devices: Sequence | None = None,
    progress: bool = True,
    **old,
) -> Comparison:
    """Compare fovea thresholds: cost against image error for every configuration.

    Renders every (threshold pair × spp × acuity model) foveated, for every gaze and key, and the
    full render for every key (it does not depend on gaze); measures rays per frame, ms per frame
    (median over renders, compile excluded), the speed-up over full, and PSNR, SSIM, FLIP and
    FovVideoVDP JOD at the gaze point, each with a 95% Student-t interval over gaze × key. A metric
    with fewer than two finite samples for a configuration has no interval (`_lo`/`_hi` NaN), so
    it cannot meet the criterion; `{metric}_n` counts the finite samples.

    Args:
        scene: the `Scene`, or a `fovjax.FoveatedRenderer` (its scene, rig, render config and
            BVH; its foveation is replaced by each configuration's).
        rig: with a `Scene`, the `StereoRig` (default: the thesis HMD at the scene's default
            viewpoint, as `FoveatedRenderer`'s); None with a renderer.
        sweep: the `ThresholdSweep`: threshold pairs, SPPs, acuity models, gazes, keys, sampling
            rule and region reading (default `ThresholdSweep()`).
        criterion: (metric, threshold): the cheapest configuration (by ms per frame) whose metric's
            whole interval stays below the threshold (above it for PSNR, SSIM and JOD) is chosen.
        perceptual: measure FovVideoVDP (default: when pyfvvdp is installed).
        plan: (metric, threshold), e.g. ("flip", 0.01): also plan each configuration per region
            with `plan_fidelity` (the cheapest `Fidelity` per region adding at most that per 5°
            ring over plain foveation) and measure it: a record labelled "... planned" with
            `planned` True and the plan in `fidelity` (plain records: `planned` False, `fidelity`
            "full"). (metric, threshold, frame_tolerance), e.g. ("flip", 0.01, 0.005): a plan's
            whole-frame metric (the mean over the sweep's gazes and keys) may also exceed plain
            foveation's by at most `frame_tolerance` (`PlanSearch.frame_tolerance`; None: the
            rings alone decide). None (default): no plans.
        shard: render each configuration's frames in one program, vmapped and sharded over
            `devices` (default `jax.devices()`, every host's under `jax.distributed`; see
            `render_foveated_batch`). Its ms per frame is then the batch's wall time over its
            frames and includes what batching costs; images, rays and metrics are those of
            `shard=False`.
        devices: the devices of a sharded sweep.
        progress: print a line per configuration.
        **old: the keywords of the earlier signature (`thresholds`, `spp`, `gazes`, `keys`,
            `config`, `bvh`, ...): accepted with a `DeprecationWarning` naming the
            replacement.

    Returns:
        A `Comparison`: `records` (one per configuration), `rings` (error per 5° ring), `choice`,
        `full` (the full render's cost), `plans`; `write(dir)` writes the CSV and the charts.

    Raises:
        MissingExtraError: the criterion's metric needs an extra that is not installed.
        ValueError: a bad criterion or plan (its criterion or frame tolerance; the sweep checks
            its own fields).

    Example:
        ```python
        sweep = fe.ThresholdSweep(thresholds=[(5, 10), (12.5, 25)], spp=[1, 4])
        cmp = fe.compare_thresholds(scene, rig, sweep)
        cmp.write("out/compare")
        print(cmp.choice)
        ```
    """
    from ..foveate import FoveatedRenderer, Foveation, method_label, with_regions
    from ..render import StereoRig
    from ..scene import Scene, default_camera
    from ._plan import PlanSearch, _check_criterion, _check_frame_tolerance, plan_fidelity

    sweep, renderer_args = _upgrade_old_keywords(old, sweep)
    sweep = ThresholdSweep() if sweep is None else sweep
    if not isinstance(sweep, ThresholdSweep):
        raise TypeError(f"compare_thresholds: sweep must be a ThresholdSweep, got {type(sweep).__name__}")
    frame_tolerance = None
    if plan is not None:
        parts = tuple(plan) if isinstance(plan, tuple | list) else ()
        if len(parts) not in (2, 3):
            raise ValueError(
                f"compare_thresholds: plan {plan!r}: expected (metric, threshold) or (metric, threshold, "
                "frame_tolerance), e.g. ('flip', 0.01, 0.005)"
            )
        plan_criterion = _check_criterion(parts[:2])
        if len(parts) == 3:
            frame_tolerance = _check_frame_tolerance(parts[2], "compare_thresholds: plan's frame tolerance")
    thresholds, spp, models = sweep.thresholds, list(sweep.spp), sweep.models
    gazes, keys, rule, regions = sweep.gazes, list(sweep.keys), sweep.rule, sweep.regions
    if isinstance(scene, FoveatedRenderer):
        clashing = [name for name, value in {"rig": rig, **renderer_args}.items() if value is not None]
        if clashing:
            raise ValueError(
                f"compare_thresholds: the renderer has its own {', '.join(clashing)}; "
                "pass them when making it"
            )
        given = scene
        scene, rig, config, bvh = given.scene, given.rig, given.config, given.bvh
    elif isinstance(scene, Scene):
        given = None
        if rig is None:
            rig = StereoRig.from_pose(default_camera(scene))
        config, bvh = renderer_args.get("config"), renderer_args.get("bvh")
    else:
        raise TypeError(
            "compare_thresholds: scene must be a fovjax.Scene or a fovjax.FoveatedRenderer, "
            f"got {type(scene).__name__}"
        )
    methods = [Foveation(method=m).method for m in sweep.methods]  # names checked by Foveation
    # A batch (shard), a fidelity plan and a sampling rule need a method that takes them.
    refusing = [
        m.name
        for m in methods
        if (shard and not m.batches)
        or (plan is not None and "fidelity" not in m.thesis_options)
        or (rule != "either" and "rule" not in m.thesis_options)
    ]
    if refusing:
        raise ValueError(
            f"compare_thresholds: methods {refusing} take neither shard, plan nor a rule "
            f"(got shard={shard}, plan={plan!r}, rule={rule!r}); those are the thesis's"
        )
    models = list(models) if models is not None else [None]
    display = HmdDisplay.from_camera(rig.eye_cameras()[0])
    use_flip = _available("flip_evaluator")
    if perceptual is None:
        perceptual = _available("pyfvvdp")
    criterion = (str(criterion[0]), float(criterion[1]))
    if criterion[0] == "flip" and not use_flip:
        raise MissingExtraError("the FLIP criterion needs flip-evaluator: pip install 'fovjax[flip]'")
    gazes = [np.broadcast_to(np.asarray(g, np.float32).reshape(-1, 2), (2, 2)) for g in gazes]
    configs = list(itertools.product(spp, thresholds, models, methods))
    total = len(spp) * len(keys) + len(configs) * len(gazes) * len(keys)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, unit="frame", desc="compare")

    # The scene prepared once for every configuration (arrays, BVH); each foveation below is a
    # variant of it. Only the per-pixel outputs read here: the traced samples and eccentricity
    # (a batch's program also returns the regions, as `render_foveated_batch`'s: one program).
    diagnostics = ("traced", "region", "eccentricity") if shard else ("traced", "eccentricity")
    if given is not None:
        base = given.with_foveation(Foveation(spp=spp[0]), diagnostics=diagnostics)
    else:
        base = FoveatedRenderer(scene, rig, Foveation(spp=spp[0]), config, bvh=bvh, diagnostics=diagnostics)
    config = base.config
    full, references = {}, {}
    for s in spp:
        renderer = base.with_foveation(Foveation(spp=s))
        if shard:
            batch = renderer.render_full_batch(keys=keys, devices=devices)
            if batch.compile_seconds > 0:  # the first batch compiled: time it again
                batch = renderer.render_full_batch(keys=keys, devices=devices)
            for k, image in zip(keys, batch.images, strict=True):
                references[s, k] = image
            times, rays = [batch.ms_per_frame / 1000] * len(keys), list(batch.rays)
            if bar is not None:
                bar.update(len(keys))
        else:
            times, rays = [], []
            for k in keys:
                frame = renderer.render_full(key=jax.random.key(k))
                if frame.stats.compile_seconds > 0:  # the first frame compiled: time it again
                    frame = renderer.render_full(key=jax.random.key(k))
                references[s, k] = frame.image
                times.append(frame.stats.render_seconds)
                rays.append(frame.stats.rays)
                if bar is not None:
                    bar.update(1)
        full[s] = {"ms_per_frame": 1000 * statistics.median(times), "rays_per_frame": statistics.mean(rays)}

    records, rings, ring_rays, plans = [], {}, {}, {}

    def evaluate(s, fov, label, record_fields):
        """Render `fov` for every gaze × key, measure it, add its record and rings."""
        samples, times, rays, ring_acc, ring_ray_acc = {}, [], [], [], []
        frames = list(itertools.product(gazes, keys))
        renderer = base.with_foveation(fov)
        if shard:
            frame_gazes, frame_keys = [g for g, _ in frames], [k for _, k in frames]
            batch = renderer.render_batch(frame_gazes, keys=frame_keys, devices=devices)
            if batch.compile_seconds > 0:  # the first batch compiled: time it again
                batch = renderer.render_batch(frame_gazes, keys=frame_keys, devices=devices)
            # (image, eccentricity, sample mask, rays) per frame, as frames one by one give them.
            assert batch.eccentricity is not None and batch.sample_mask is not None  # in diagnostics
            rendered = [
                (batch.images[i], batch.eccentricity[i], batch.sample_mask[i], batch.rays[i])
                for i in range(len(frames))
            ]
            new_rays, reused = [int(x) for x in batch.primary_rays], [0] * len(frames)
            seconds = [batch.ms_per_frame / 1000] * len(frames)
        else:
            rendered, seconds, new_rays, reused = [], [], [], []
            temporal = fov.method.temporal
            for g, k in frames:
                if temporal:  # one frame of history of this view (another key), then the frame
                    renderer.render(g, key=jax.random.key(k + 1), reset=True)
                frame = renderer.render(g, key=jax.random.key(k))
                if frame.stats.compile_seconds > 0 and not temporal:
                    frame = renderer.render(g, key=jax.random.key(k))
                rendered.append((frame.image, frame.eccentricity, frame.sample_mask, frame.stats.rays))
                seconds.append(frame.stats.render_seconds)
                new_rays.append(frame.stats.primary_rays)
                reused.append(frame.foveation.reused)
        for (g, k), (image, eccentricity, sample_mask, n_rays), t in zip(
            frames, rendered, seconds, strict=True
        ):
            ecc = np.concatenate(list(eccentricity), axis=1)
            values, ring = _metrics(image, references[s, k], ecc, display, g, use_flip, perceptual)
            for name, v in values.items():
                samples.setdefault(name, []).append(v)
            times.append(t)
            rays.append(int(n_rays))
            ring_acc.append(ring)
            traced = np.concatenate(list(sample_mask.sum(axis=1)), axis=1)
            ring_ray_acc.append(
                [
                    traced[(ecc >= lo) & (ecc < hi)].sum()
                    for lo, hi in zip(ring.lower_deg, ring.upper_deg, strict=True)
                ]
            )
            if bar is not None:
                bar.update(1)
        ms = 1000 * statistics.median(times)
        record = {
            "config": label,
            **record_fields,
            "rays_per_frame": float(statistics.mean(rays)),
            "new_rays_per_frame": float(statistics.mean(new_rays)),
            "reused_pixels_per_frame": float(statistics.mean(reused)),
            "ms_per_frame": ms,
            "speedup": full[s]["ms_per_frame"] / ms,
            "ray_reduction": 1 - statistics.mean(rays) / full[s]["rays_per_frame"],
            "full_ms_per_frame": full[s]["ms_per_frame"],
            "full_rays_per_frame": full[s]["rays_per_frame"],
            "n": len(times),
            "timing": f"batch over {batch.devices} devices / frames" if shard else "median of frames",
        }
        for name, vals in samples.items():
            record.update(_summarise(name, vals))
        if "jod" in record:
            record["jod_drop"] = 10.0 - record["jod"]
        records.append(record)
        # Rings reach each frame's largest eccentricity, which moves with the gaze: pad to the
        # widest (no pixels there: NaN error, 0 rays) before averaging.
        widest = max(ring_acc, key=lambda r: len(r.lower_deg))
        n_rings = len(widest.lower_deg)
        errors = [
            np.pad(r.mean_error, (0, n_rings - len(r.mean_error)), constant_values=np.nan) for r in ring_acc
        ]
        ring_rays_padded = [np.pad(np.asarray(r, float), (0, n_rings - len(r))) for r in ring_ray_acc]
        rings[label] = dataclasses.replace(widest, mean_error=np.nanmean(np.stack(errors), axis=0))
        ring_rays[label] = list(np.mean(np.stack(ring_rays_padded), axis=0))

    for s, (fovea, periphery), model, method in configs:
        kwargs = {} if model is None else {"acuity": model}
        fov = Foveation(
            fovea_deg=float(fovea), periphery_deg=float(periphery), spp=s, rule=rule, method=method, **kwargs
        )
        fov = with_regions(fov, regions, rig.eye_height)
        model_name = "thesis" if model is None else getattr(model, "name", type(model).__name__)
        label = f"{fovea:g}/{periphery:g} spp{s}" + ("" if model is None else f" {model_name}")
        name = method_label(method)  # its parameters where they are not the defaults
        if len(methods) > 1 or name != "thesis":
            label = f"{name} {label}"
        fields = {
            "method": name,
            "fovea_deg": float(fovea),
            "periphery_deg": float(periphery),
            "spp": s,
            "model": model_name,
            "regions": regions,
        }
        planned = {"planned": False, "fidelity": "full"} if plan is not None else {}
        evaluate(s, fov, label, {**fields, **planned})
        if plan is not None:
            found = plan_fidelity(
                scene,
                rig,
                fov,
                plan_criterion,
                search=PlanSearch(gazes=gazes, keys=keys, frame_tolerance=frame_tolerance),
                config=config,
                bvh=base.bvh,
                _references={k: references[s, k] for k in keys},
            )
            plans[label + " planned"] = found
            if bar is not None:
                bar.total += len(gazes) * len(keys)
            extra = {"planned": True, "fidelity": found.describe_plan()}
            evaluate(s, found.foveation, label + " planned", {**fields, **extra})
    if bar is not None:
        bar.close()
    metric, threshold = criterion
    front = pareto_front(records, {"ms_per_frame": "min", metric: _sense(metric)})
    for r, on_front in zip(records, front, strict=True):
        r["pareto"] = bool(on_front)
    choice = cheapest_within(
        records, cost="ms_per_frame", metric=metric, threshold=threshold, below=_sense(metric) == "min"
    )
    return Comparison(records, rings, ring_rays, choice, criterion, full, plans)
