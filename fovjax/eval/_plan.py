"""Plan the shading fidelity of each foveation region: the cheapest per-region `Fidelity`
whose error per 5° eccentricity ring, against the full render, stays within a criterion.

Why here and not `fovjax.foveate.plan_fidelity`: the plan is judged by image metrics (FLIP,
`error_by_eccentricity`), which live in `eval`, and the core packages (foveate, render, trace,
scene, acuity, devices) never import the application layer (docs/concepts/architecture.md;
tests/test_architecture.py). So the planner sits with the metrics and returns a plain
`fovjax.foveate.Foveation` that the core renders like any other.

The criterion bounds the error the plan *adds*: per ring, the plan's mean error against the
full render minus plain foveation's (the same foveation without fidelity, same gazes and keys,
so the same samples). Not the plan's whole error: plain foveation alone already measures FLIP
0.10-0.17 per ring outside the fovea against the full render on the atrium at SPP 1 (2×320×256),
so an absolute per-ring bound of 0.05 would be missed by every plan, full fidelity included.

The search is short by construction:
- options per region are a chain, dearest first, each candidate doing no more work than the
  one before (`DEFAULT_STEPS` builds the default chain cumulatively, so it is monotone);
- regions are planned one at a time from the outside inward (outside, periphery, fovea): the
  outside covers most pixels, and each later region is judged with the regions already
  planned in place, so every accepted step was measured as the combined configuration;
- per region: the cheapest candidate first (a loose criterion stops there), else a binary
  search for the cheapest that passes, assuming the added error grows along the chain: at most
  1 + ceil(log2(n)) evaluations of n candidates (4 for the default 6);
- one evaluation = every gaze × key frame of that configuration (fixed for the whole search),
  its FLIP map against the full render of the same key, and its rays and time.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from collections.abc import Callable, Sequence
from numbers import Real

import numpy as np

from ..foveate import Foveation
from ._metrics import HmdDisplay, MissingExtraError, error_by_eccentricity

REGIONS = ("fovea", "periphery", "outside")
PLAN_METRICS = ("flip", "abs")
# Gaze points (per-eye normalised display coordinates, both eyes the same) judged by default:
# three off-centre points (compare's DEFAULT_GAZES bar the centre, plus one more).
DEFAULT_PLAN_GAZES = ((0.35, 0.45), (0.3, 0.4), (0.7, 0.65))

# The default option chain of every region, built cumulatively: each step changes the previous
# candidate's fields, so each candidate does no more work than the one before (monotone). A
# `max_depth` step is skipped where it is not below the render config's depth, a "brightest"
# step where the scene has one light (it would equal "all"), an `spp` step where it is not below
# the frame's SPP. When `Fidelity` gains more fields (geometry `lod`, `texture_lod`, per-region
# `spp`), add their steps here in the order of the error each is expected to add, least first
# (the binary search assumes the error grows along the chain), e.g. {"lod": "auto"} (meant to
# stay below the resolvable angle) and {"texture_lod": "auto"} before the reflection-depth steps,
# {"spp": 1} where it measures: the one place the default grid is defined (a field that needs
# a renderer input beyond what `render_foveated` finds itself also needs `render_kwargs`).
# {"spp": 1} sits after depth 1: on the atrium at SPP 4 it was the one step that bought speed at
# equal FLIP (periphery at 1 SPP + depth 1; docs/performance.md, "Planned fidelity"); geometry LOD
# measured no faster there and texture LOD buys no speed on the CPU, so neither is a default step.
DEFAULT_STEPS: tuple[dict, ...] = (
    {"max_depth": 2},
    {"max_depth": 1},
    {"spp": 1},
    {"max_depth": 0},
    {"shadows": "brightest"},
    {"shadows": "none"},
)


def default_options(max_depth: int = 5, lights: int = 1, spp: int = 1, first: Sequence = ()) -> tuple:
    """The default candidates of one region, dearest first: full fidelity, then the steps of
    `DEFAULT_STEPS` applied one after another (reflection depth 2, 1 below the render config's
    `max_depth`; one sample per pixel where the frame has more; depth 0; then shadow rays to the
    brightest light only, with more than one light; then none). `spp`: the frame's samples per
    pixel (an `spp` step must be below it). `first`: extra steps (dicts of `Fidelity` fields)
    taken before the default ones, each kept in every later candidate (e.g. `({"lod": "auto"},)`
    for a lever meant to stay invisible); the same skipping rules apply to them."""
    from ..foveate import Fidelity

    fields: dict = {}
    chain = [Fidelity()]
    for step in (*first, *DEFAULT_STEPS):
        if not isinstance(step, dict):
            raise ValueError(
                f"default_options: each step of first must be a dict of Fidelity fields, got {step!r}"
            )
        if "max_depth" in step and step["max_depth"] >= max_depth:
            continue
        if step.get("shadows") == "brightest" and lights <= 1:
            continue
        if "spp" in step and step["spp"] >= spp:
            continue
        fields = {**fields, **step}
        candidate = Fidelity(**fields)
        if candidate != chain[-1]:  # a step that changes nothing is no candidate
            chain.append(candidate)
    return tuple(chain)


@dataclasses.dataclass(frozen=True)
class PlanStep:
    """One evaluation of the search: `region` set to `candidate` (the other regions at the plan
    so far); `worst_added` the largest added ring error; `passed` whether every ring stayed
    within the threshold (and the whole frame within `PlanSearch.frame_tolerance`, where set);
    measured rays and median ms per frame; `metric` the whole-frame metric's mean over the
    frames (FLIP, or mean |error|) and `fidelity` the configuration's three regions."""

    region: str
    candidate: object
    worst_added: float
    passed: bool
    rays_per_frame: float
    ms_per_frame: float
    metric: float
    fidelity: tuple


@dataclasses.dataclass(frozen=True)
class FidelityPlan:
    """What `plan_fidelity` found. `foveation`: the plan (the given foveation with
    `fidelity=(fovea, periphery, outside)`, or the given foveation itself where no region could
    be cheapened); `plain`: the given foveation (its own fidelity).
    Per 5° ring (`ring_lower_deg` up): the plan's and plain foveation's mean error against the
    full render (pixel-weighted over every gaze × key frame). `plan_cost`/`plain_cost`:
    `ms_per_frame` (median over frames, the two timed alternately in the same run) and
    `rays_per_frame` (mean). `plan_metric`/`plain_metric`: the whole-frame metric's mean and
    95% interval over the frames (mean, lo, hi). `steps`: the search, in order. `choices`: with
    more than one sampling density planned, each density's plan (`blocks`, `fidelity`,
    `ms_per_frame` timed in turn with the others over the frames, `rays_per_frame`); the
    fastest is the plan. `frame_tolerance`: the search's bound on the whole frame's added
    metric (`PlanSearch.frame_tolerance`; None: none)."""

    foveation: Foveation
    plain: Foveation
    criterion: tuple[str, float]
    ring_lower_deg: np.ndarray
    ring_upper_deg: np.ndarray
    ring_error: np.ndarray
    plain_ring_error: np.ndarray
    plan_cost: dict
    plain_cost: dict
    plan_metric: tuple[float, float, float]
    plain_metric: tuple[float, float, float]
    steps: tuple[PlanStep, ...]
    frames: int
    choices: tuple[dict, ...] = ()
    frame_tolerance: float | None = None

    @property
    def fidelity(self) -> tuple:
        """The plan's (fovea, periphery, outside) `Fidelity` (full ones where the foveation has none)."""
        from ..foveate import Fidelity

        return self.foveation.fidelity or (Fidelity(),) * 3

    @property
    def added_ring_error(self) -> np.ndarray:
        return self.ring_error - self.plain_ring_error

    @property
    def speedup(self) -> float:
        """Plain foveation's median ms per frame over the plan's (same run)."""
        return self.plain_cost["ms_per_frame"] / self.plan_cost["ms_per_frame"]

    @property
    def ray_ratio(self) -> float:
        return self.plan_cost["rays_per_frame"] / self.plain_cost["rays_per_frame"]

    @property
    def within(self) -> bool:
        """Every ring's added error within the threshold (true by construction; recomputable)."""
        added = self.added_ring_error
        return bool(np.all(added[np.isfinite(added)] <= self.criterion[1]))

    def describe_plan(self) -> str:
        regions = ", ".join(f"{name} {_describe(f)}" for name, f in zip(REGIONS, self.fidelity, strict=True))
        if tuple(self.foveation.blocks) != tuple(self.plain.blocks):
            return f"blocks {tuple(self.foveation.blocks)}; {regions}"
        return regions

    def __str__(self) -> str:
        metric, threshold = self.criterion
        name = "FLIP" if metric == "flip" else "mean |error| (sRGB)"
        bound = "" if self.frame_tolerance is None else f" and per frame <= {self.frame_tolerance:g}"
        lines = [
            f"plan ({name} added per 5° ring <= {threshold:g}{bound}, {self.frames} frames, "
            f"{len(self.steps)} evaluations): {self.describe_plan()}",
            f"{'':8} {'ms/frame':>9} {'rays/frame':>11} {name + ' mean [95%]':>28}",
        ]
        for label, cost, m in (
            ("plain", self.plain_cost, self.plain_metric),
            ("planned", self.plan_cost, self.plan_metric),
        ):
            lines.append(
                f"{label:8} {cost['ms_per_frame']:9.1f} {cost['rays_per_frame']:11,.0f} "
                f"{m[0]:12.4f} [{m[1]:.4f}, {m[2]:.4f}]"
            )
        lines.append(f"speed: {self.speedup:.2f}x plain; rays: {self.ray_ratio:.3f}x plain")
        if self.choices:
            timed = ", ".join(
                f"blocks {c['blocks']} {c['ms_per_frame']:.1f} ms ({c['rays_per_frame']:,.0f} rays)"
                for c in self.choices
            )
            lines.append(f"each density's plan, timed in turn: {timed}; the fastest kept")
        if self.speedup <= 1 and self.foveation is not self.plain:
            rays = "fewer" if self.ray_ratio < 1 else "no fewer"
            lines.append(
                f"no measured gain: the plan traces {rays} rays and is not faster than plain foveation "
                "in this run (plain foveation is the cheaper choice here)"
            )
        lines.append(f"{'ring deg':>9} {'plain':>8} {'planned':>8} {'added':>8}")
        for lo, hi, p, q in zip(
            self.ring_lower_deg, self.ring_upper_deg, self.plain_ring_error, self.ring_error, strict=True
        ):
            if math.isfinite(p):
                lines.append(f"{lo:4.0f}-{hi:<4.0f} {p:8.4f} {q:8.4f} {q - p:+8.4f}")
        return "\n".join(lines)


def _describe(f) -> str:
    parts = [f"{k}={getattr(f, k)!r}" for k in _fields(f) if getattr(f, k) != getattr(type(f)(), k)]
    return "full" if not parts else " ".join(parts)


def _fields(f) -> list[str]:
    return [field.name for field in dataclasses.fields(f)]


# -- validation -------------------------------------------------------------------------------
def _where(name: str) -> str:
    return f"plan_fidelity: {name}"


def _check_criterion(criterion) -> tuple[str, float]:
    if not (isinstance(criterion, tuple | list) and len(criterion) == 2):
        raise ValueError(
            f"{_where('criterion')} {criterion!r}: expected (metric, threshold), e.g. ('flip', 0.05)"
        )
    metric, threshold = criterion
    if metric not in PLAN_METRICS:
        raise ValueError(f"{_where('criterion')} metric {metric!r}: expected one of {PLAN_METRICS}")
    ok = isinstance(threshold, int | float | np.floating | np.integer) and not isinstance(threshold, bool)
    if not ok or not math.isfinite(float(threshold)) or not 0 <= float(threshold) <= 1:
        raise ValueError(
            f"{_where('criterion')} threshold {threshold!r}: expected a number in [0, 1] "
            f"(the added {metric} error per ring)"
        )
    if metric == "flip":
        import importlib.util

        if importlib.util.find_spec("flip_evaluator") is None:
            raise MissingExtraError(
                "plan_fidelity: criterion 'flip' needs flip-evaluator: pip install 'fovjax[flip]'"
            )
    return str(metric), float(threshold)


def _check_gazes(gazes) -> list[np.ndarray]:
    from ..foveate import check_gaze

    if isinstance(gazes, str | bytes) or not isinstance(gazes, Sequence) or len(gazes) == 0:
        raise ValueError(f"{_where('gazes')} {gazes!r}: expected a non-empty sequence of gaze points")
    out = []
    for i, g in enumerate(gazes):
        try:
            a = np.asarray(g, np.float64)
        except (TypeError, ValueError):
            raise ValueError(
                f"{_where(f'gazes[{i}]')} {g!r}: expected (x, y) or ((lx, ly), (rx, ry))"
            ) from None
        if a.shape == (2,):
            a = np.broadcast_to(a, (2, 2))
        out.append(check_gaze(a, f"plan_fidelity: gazes[{i}]"))
    return out


def _check_keys(keys) -> list[int]:
    if isinstance(keys, str | bytes) or not isinstance(keys, Sequence) or len(keys) == 0:
        raise ValueError(f"{_where('keys')} {keys!r}: expected a non-empty sequence of integer seeds >= 0")
    for i, k in enumerate(keys):
        if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 0:
            raise ValueError(f"{_where(f'keys[{i}]')} {k!r}: expected an integer seed >= 0")
    return [int(k) for k in keys]


def _check_options(options, max_depth: int, lights: int, spp: int) -> list[tuple]:
    """Three chains (fovea, periphery, outside) of `Fidelity`, each non-empty, each depth at
    most the render config's."""
    from ..foveate import Fidelity

    if options is None:
        return [default_options(max_depth, lights, spp)] * 3
    if isinstance(options, Fidelity) or isinstance(options, str | bytes) or not isinstance(options, Sequence):
        raise ValueError(
            f"{_where('options')} {options!r}: expected a sequence of candidate Fidelity (every region) "
            "or three such sequences (fovea, periphery, outside)"
        )
    if len(options) > 0 and all(isinstance(o, Fidelity) for o in options):
        per_region = [tuple(options)] * 3
    elif len(options) == 3 and all(
        isinstance(o, Sequence) and not isinstance(o, str | bytes) for o in options
    ):
        per_region = [tuple(o) for o in options]
    else:
        raise ValueError(
            f"{_where('options')} {options!r}: expected a non-empty sequence of Fidelity or three "
            "sequences of Fidelity (fovea, periphery, outside)"
        )
    for name, chain in zip(REGIONS, per_region, strict=True):
        if not chain:
            raise ValueError(
                f"{_where(f'options ({name})')}: empty; expected at least one candidate Fidelity"
            )
        for i, f in enumerate(chain):
            if not isinstance(f, Fidelity):
                raise ValueError(
                    f"{_where(f'options ({name})[{i}]')} {f!r}: expected a fovjax.foveate.Fidelity"
                )
            if isinstance(f.max_depth, int | np.integer) and int(f.max_depth) > max_depth:
                raise ValueError(
                    f"{_where(f'options ({name})[{i}]')} max_depth {f.max_depth}: expected at most the "
                    f"render config's max_depth {max_depth}"
                )
    return per_region


def _check_densities(densities, foveation) -> list:
    """The foveation at each sampling density (`Foveation.blocks` pair), in the given order;
    None: the foveation itself."""
    if densities is None:
        return [foveation]
    if isinstance(densities, str | bytes) or not isinstance(densities, Sequence) or not densities:
        raise ValueError(
            f"{_where('densities')} {densities!r}: expected None or a non-empty sequence of "
            "Foveation.blocks pairs, e.g. [(2, 4), (1, 3)]"
        )
    bases = []
    for i, d in enumerate(densities):
        if (
            isinstance(d, str | bytes)
            or not isinstance(d, Sequence)
            or len(d) != 2
            or not all(isinstance(v, int | np.integer) and not isinstance(v, bool) for v in d)
        ):
            raise ValueError(
                f"{_where(f'densities[{i}]')} {d!r}: expected a pair of integers (periphery, outside)"
            )
        blocks = (int(d[0]), int(d[1]))
        try:
            base = (
                foveation
                if blocks == tuple(foveation.blocks)
                else dataclasses.replace(foveation, blocks=blocks)
            )
        except ValueError as err:
            raise ValueError(f"{_where(f'densities[{i}]')} {d!r}: {err}") from None
        if any(b.blocks == base.blocks for b in bases):
            raise ValueError(f"{_where(f'densities[{i}]')} {d!r}: given twice")
        bases.append(base)
    return bases


def _check_int(value, name: str, ge: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < ge:
        raise ValueError(f"{_where(name)} {value!r}: expected an integer >= {ge}")
    return int(value)


@dataclasses.dataclass(frozen=True)
class PlanSearch:
    """What `plan_fidelity` judges candidates on and which it tries.

    Args:
        gazes: the gaze points ((x, y), or one per eye) of the frames every candidate is
            judged on.
        keys: the seeds of those frames' keys.
        options: the candidates, a chain dearest first with each candidate doing no more work
            than the one before (the search assumes it): one sequence of `Fidelity` for every
            region, or three (fovea, periphery, outside). None: `default_options(config.max_depth,
            lights)`, built from `DEFAULT_STEPS` (reflection depth, then shadow rays); checked
            against the render config when planning.
        densities: sampling densities to plan at, each a `Foveation.blocks` pair (periphery,
            outside block edges in pixels; None: the foveation's own only); checked against the
            foveation when planning.
        repeats: after the search, plain foveation and the plan are rendered alternately over
            the frames this many times to time them (and, with more than one density, each
            density's plan in turn, to choose the fastest).
        frame_tolerance: a candidate passes only where its whole-frame metric (the mean over
            the frames) also exceeds plain foveation's by at most this: "equal FLIP within
            0.005" is `frame_tolerance=0.005`. None: the rings alone decide.

    Raises:
        ValueError: a bad gaze, key, repeat count or tolerance, naming it and what was expected.
    """

    gazes: Sequence = DEFAULT_PLAN_GAZES
    keys: Sequence[int] = (0, 1)
    options: object = None
    densities: Sequence | None = None
    repeats: int = 1
    frame_tolerance: float | None = None

    def __post_init__(self):
        _check_gazes(self.gazes)
        object.__setattr__(self, "keys", tuple(_check_keys(self.keys)))
        _check_int(self.repeats, "repeats", 1)
        tolerance = _check_frame_tolerance(self.frame_tolerance, _where("frame_tolerance"))
        object.__setattr__(self, "frame_tolerance", tolerance)


def _check_frame_tolerance(tolerance, where: str) -> float | None:
    """None, or a finite float >= 0; else a ValueError naming `where` and the value."""
    if tolerance is None:
        return None
    value = float(tolerance) if isinstance(tolerance, Real) and not isinstance(tolerance, bool) else math.nan
    if not 0 <= value < math.inf:
        raise ValueError(f"{where} {tolerance!r}: expected None or a finite number >= 0")
    return value


# -- evaluation -------------------------------------------------------------------------------
@dataclasses.dataclass
class _Evaluation:
    ring_sum: np.ndarray  # per ring: sum over frames of error × pixels
    ring_pixels: np.ndarray
    metric: list[float]  # whole-frame metric per frame
    rays: list[int]
    seconds: list[float]

    @property
    def ring_error(self) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.ring_pixels > 0, self.ring_sum / np.maximum(self.ring_pixels, 1), np.nan)


def _pad(a: np.ndarray, n: int) -> np.ndarray:
    return np.pad(np.asarray(a, np.float64), (0, n - len(a)))


class _Judge:
    """Renders a configuration over the fixed frames and measures it against the references."""

    def __init__(self, scene, rig, config, frames, references, metric, bvh, render_kwargs):
        self.scene, self.rig, self.config, self.bvh = scene, rig, config, bvh
        self.render_kwargs = render_kwargs
        self.frames, self.references, self.metric = frames, references, metric
        self.ppd = HmdDisplay.from_camera(rig.eye_cameras()[0]).ppd

    def render(self, foveation, gaze, key):
        import jax

        from ..foveate import render_foveated

        def once():
            return render_foveated(
                self.scene,
                self.rig,
                gaze=gaze,
                foveation=foveation,
                key=jax.random.key(key),
                config=self.config,
                bvh=self.bvh,
                **self.render_kwargs,
            )

        frame = once()
        if frame.stats.compile_seconds > 0:  # the first frame compiled: time it again
            frame = once()
        return frame

    def error_map(self, image, reference) -> np.ndarray:
        from ._metrics import display_encode, flip

        if self.metric == "flip":
            return flip(image, reference, ppd=self.ppd, return_map=True)[1]
        return np.mean(np.abs(display_encode(image) - display_encode(reference)), axis=-1)

    def __call__(self, foveation) -> _Evaluation:
        ev = _Evaluation(np.zeros(0), np.zeros(0), [], [], [])
        for gaze, key in self.frames:
            frame = self.render(foveation, gaze, key)
            ref = self.references[key]
            emap = self.error_map(frame.image, ref)
            assert frame.eccentricity is not None  # the search's renders ask for it
            ecc = np.concatenate(list(frame.eccentricity), axis=1)
            rings = error_by_eccentricity(frame.image, ref, ecc, error_map=emap)
            n = max(len(ev.ring_sum), len(rings.mean_error))
            sums = np.where(rings.pixels > 0, rings.mean_error, 0.0) * rings.pixels
            ev.ring_sum = _pad(ev.ring_sum, n) + _pad(sums, n)
            ev.ring_pixels = _pad(ev.ring_pixels, n) + _pad(rings.pixels, n)
            ev.metric.append(float(emap.mean()))
            ev.rays.append(int(frame.stats.rays))
            ev.seconds.append(float(frame.stats.render_seconds))
        return ev


def _nan_pad(a: np.ndarray, n: int) -> np.ndarray:
    return np.pad(np.asarray(a, np.float64), (0, n - len(a)), constant_values=np.nan)


def _added(ev: _Evaluation, plain: _Evaluation) -> np.ndarray:
    """Per ring: the configuration's mean error minus plain foveation's (NaN where either has
    no pixel)."""
    n = max(len(ev.ring_sum), len(plain.ring_sum))
    return _nan_pad(ev.ring_error, n) - _nan_pad(plain.ring_error, n)


def _worst(added: np.ndarray) -> float:
    finite = added[np.isfinite(added)]
    return float(finite.max()) if finite.size else 0.0


def _interval(values: list[float]) -> tuple[float, float, float]:
    from ._pareto import mean_interval

    return mean_interval(values) if len(values) >= 2 else (float(np.mean(values)), math.nan, math.nan)


def plan_fidelity(
    scene,
    rig,
    foveation,
    criterion: tuple[str, float] = ("flip", 0.05),
    *,
    search: PlanSearch | None = None,
    config=None,
    bvh=None,
    render_kwargs: dict | None = None,
    log: Callable[[str], None] | None = None,
    _references: dict | None = None,
) -> FidelityPlan:
    """The cheapest per-region shading fidelity for `foveation` (a `fovjax.foveate.Foveation`)
    whose error per 5° eccentricity ring against the full render stays within `criterion`.

    `criterion` (metric, threshold): per ring, the plan's mean error against the full render
    may exceed plain foveation's (the same foveation, same gazes and keys, hence the same
    samples) by at most `threshold` (module docstring: why added, not absolute). Metric "flip"
    (the FLIP map at the rig's pixels per degree, extra [flip]) or "abs" (mean |difference| of
    sRGB-encoded values). Threshold 0: only changes that change no pixel.

    `search` (`PlanSearch`, default `PlanSearch()`): the frames (gazes × keys) every candidate
    is judged on, the candidates (`options`) per region, the sampling `densities` and the timing
    `repeats`. A region whose candidates all fail keeps the foveation's own fidelity for it
    (full when `foveation.fidelity` is None). `config`: the `RenderConfig` (default:
    `RenderConfig()`). The search: module docstring. Cost: after the search, plain foveation and
    the plan are rendered alternately over the frames `search.repeats` times; median ms per
    frame (compile excluded) and mean rays per frame. `render_kwargs`: more keyword arguments of
    every `render_foveated` call that change nothing at full fidelity (the full render does not
    get them), e.g. the levels of detail a `Fidelity.lod` needs. `log`: a line per evaluation.
    Densities: a density is a candidate where it passes the criterion at the foveation's own
    fidelity (against plain foveation at its own blocks); the region search runs at each, and
    the plan is the one of them with the least median ms per frame in the search (at SPP > 1 a
    denser grid at 1 SPP outside the fovea can beat sparse blocks at full SPP: the sub-samples
    spent on pixels).

    Every argument is checked before anything is rendered (ValueError naming the argument, the
    value and what was expected; `MissingExtraError` when FLIP is not installed)."""
    from ..foveate import Foveation
    from ..render import RenderConfig, StereoRig, render_stereo
    from ..scene import Scene

    if not isinstance(scene, Scene):
        raise ValueError(f"{_where('scene')}: expected a fovjax.Scene, got {type(scene).__name__}")
    if not isinstance(rig, StereoRig):
        raise ValueError(f"{_where('rig')}: expected a fovjax.StereoRig, got {type(rig).__name__}")
    if not isinstance(foveation, Foveation):
        raise ValueError(
            f"{_where('foveation')}: expected a fovjax.foveate.Foveation, got {type(foveation).__name__}"
        )
    if config is None:
        config = RenderConfig()
    elif not isinstance(config, RenderConfig):
        raise ValueError(f"{_where('config')}: expected a fovjax.RenderConfig, got {type(config).__name__}")
    metric, threshold = _check_criterion(criterion)
    search = PlanSearch() if search is None else search
    if not isinstance(search, PlanSearch):
        raise ValueError(f"{_where('search')}: expected a PlanSearch, got {type(search).__name__}")
    gazes, keys, repeats = _check_gazes(search.gazes), list(search.keys), search.repeats
    options, densities = search.options, search.densities
    lights = len(scene.lights) if scene.lights is not None else 0
    chains = _check_options(options, int(config.max_depth), lights, foveation.spp)
    if render_kwargs is not None and not isinstance(render_kwargs, dict):
        raise ValueError(
            f"{_where('render_kwargs')} {render_kwargs!r}: expected None or a dict of keyword arguments "
            "of render_foveated"
        )
    bases = _check_densities(densities, foveation)
    from ..foveate import Fidelity

    for name, f in zip(REGIONS, foveation.fidelity or (), strict=False):
        if f.max_depth is not None and int(f.max_depth) > config.max_depth:
            raise ValueError(
                f"{_where(f'foveation.fidelity ({name})')} max_depth {f.max_depth}: expected at most "
                f"the render config's max_depth {config.max_depth}"
            )
    say = log or (lambda line: None)

    # The full render of every key (it does not depend on gaze), at the foveation's SPP.
    references = dict(_references or {})
    for key in keys:
        if key not in references:
            import jax

            ref = render_stereo(
                scene, rig, spp=foveation.spp, key=jax.random.key(key), config=config, bvh=bvh
            )
            references[key] = ref.image
    frames = [(g, k) for g in gazes for k in keys]
    judge = _Judge(scene, rig, config, frames, references, metric, bvh, render_kwargs or {})

    start = tuple(foveation.fidelity) if foveation.fidelity is not None else (Fidelity(),) * 3
    plain_ev = judge(foveation)
    whole = "FLIP" if metric == "flip" else "mean |error|"
    plain_whole = float(np.mean(plain_ev.metric))
    say(
        f"plain: {statistics.mean(plain_ev.rays):,.0f} rays, "
        f"{1e3 * statistics.median(plain_ev.seconds):.1f} ms per frame, {whole} {plain_whole:.4f}"
    )
    steps: list[PlanStep] = []

    def record(region, candidate, label, ev, fidelity) -> bool:
        """One evaluation as a `PlanStep` and a log line; whether it passed the criterion."""
        worst = _worst(_added(ev, plain_ev))
        whole_added = float(np.mean(ev.metric)) - plain_whole
        rings_ok = worst <= threshold
        ok = rings_ok and (search.frame_tolerance is None or whole_added <= search.frame_tolerance)
        step = PlanStep(
            region,
            candidate,
            worst,
            ok,
            float(statistics.mean(ev.rays)),
            1e3 * float(statistics.median(ev.seconds)),
            float(np.mean(ev.metric)),
            fidelity,
        )
        steps.append(step)
        say(
            f"{region:9} {label:40} worst added {worst:.4f} "
            f"{'pass' if ok else 'fail' if not rings_ok else 'fail (whole frame)'}  "
            f"{step.rays_per_frame:,.0f} rays {step.ms_per_frame:.1f} ms  "
            f"{whole} {step.metric:.4f} ({whole_added:+.4f})"
        )
        return ok

    def search_regions(base, base_ev):
        """The region search at `base`'s density, from the foveation's own fidelity."""
        current = list(start)
        best_ev = base_ev
        for region in (2, 1, 0):
            # Candidates cheaper than the region's current fidelity: after it where the chain holds it.
            chain = list(chains[region])
            if current[region] in chain:
                chain = chain[chain.index(current[region]) + 1 :]
            if not chain:
                continue
            results: dict[int, tuple[bool, _Evaluation]] = {}

            def passes(i, region=region, chain=chain, results=results):
                trial = list(current)
                trial[region] = chain[i]
                ev = judge(dataclasses.replace(base, fidelity=tuple(trial)))
                ok = record(REGIONS[region], chain[i], _describe(chain[i]), ev, tuple(trial))
                results[i] = (ok, ev)
                return ok

            # The cheapest first; else binary search for the cheapest passing candidate, -1 being
            # the region's current (known to pass) fidelity.
            lo, hi = -1, len(chain) - 1
            if not passes(hi):
                while hi - lo > 1:
                    mid = (lo + hi) // 2
                    if passes(mid):
                        lo = mid
                    else:
                        hi = mid
                chosen = lo
            else:
                chosen = hi
            if chosen >= 0:
                current[region] = chain[chosen]
                best_ev = results[chosen][1]
        return current, best_ev

    def as_foveation(fidelity, base):
        """The foveation of a plan: the given one itself where nothing changed (the same
        compiled program)."""
        if tuple(fidelity) == start and base is foveation:
            return foveation
        return dataclasses.replace(base, fidelity=tuple(fidelity))

    plans = []  # (fidelity, base, evaluation): the plan at each density that passed
    for base in bases:
        if base.blocks == foveation.blocks:
            base_ev = plain_ev
        else:
            base_ev = judge(base)
            blocks = tuple(base.blocks)
            if not record("density", blocks, f"blocks {blocks}", base_ev, tuple(start)):
                continue
        current, best_ev = search_regions(base, base_ev)
        plans.append((tuple(current), base, best_ev))
    if not plans:  # no density passed at full fidelity: plain foveation's own
        plans.append((tuple(start), foveation, plain_ev))
    choices: list[dict] = []
    if len(plans) > 1:
        # One plan per density: timed against each other in the same run, in turn over the
        # frames (their search timings came minutes apart on a machine whose load drifts).
        seconds: list[list[float]] = [[] for _ in plans]
        for _ in range(repeats):
            for gaze, key in frames:
                for i, (fidelity, base, _) in enumerate(plans):
                    frame = judge.render(as_foveation(fidelity, base), gaze, key)
                    seconds[i].append(frame.stats.render_seconds)
        for (fidelity, base, ev), s in zip(plans, seconds, strict=True):
            choices.append(
                {
                    "blocks": tuple(int(b) for b in base.blocks),
                    "fidelity": tuple(fidelity),
                    "ms_per_frame": 1e3 * statistics.median(s),
                    "rays_per_frame": float(statistics.mean(ev.rays)),
                }
            )
        fastest = min(range(len(plans)), key=lambda i: choices[i]["ms_per_frame"])
        current, base, best_ev = plans[fastest]
    else:
        current, base, best_ev = plans[0]

    # Nothing cheaper passed: the given foveation itself (the same compiled program).
    planned = as_foveation(current, base)
    plain_fov = foveation
    # Cost in the same run: plain and plan rendered alternately over the frames.
    plain_s, plan_s, plain_rays, plan_rays = [], [], [], []
    for _ in range(repeats):
        for gaze, key in frames:
            a = judge.render(plain_fov, gaze, key)
            b = judge.render(planned, gaze, key)
            plain_s.append(a.stats.render_seconds)
            plan_s.append(b.stats.render_seconds)
            plain_rays.append(a.stats.rays)
            plan_rays.append(b.stats.rays)
    n = max(len(best_ev.ring_sum), len(plain_ev.ring_sum))
    ring_lower = np.arange(n) * 5.0
    return FidelityPlan(
        foveation=planned,
        plain=plain_fov,
        criterion=(metric, threshold),
        ring_lower_deg=ring_lower,
        ring_upper_deg=ring_lower + 5.0,
        ring_error=_nan_pad(best_ev.ring_error, n),
        plain_ring_error=_nan_pad(plain_ev.ring_error, n),
        plan_cost={
            "ms_per_frame": 1e3 * statistics.median(plan_s),
            "rays_per_frame": float(statistics.mean(plan_rays)),
        },
        plain_cost={
            "ms_per_frame": 1e3 * statistics.median(plain_s),
            "rays_per_frame": float(statistics.mean(plain_rays)),
        },
        plan_metric=_interval(best_ev.metric),
        plain_metric=_interval(plain_ev.metric),
        steps=tuple(steps),
        frames=len(frames),
        choices=tuple(choices),
        frame_tolerance=search.frame_tolerance,
    )
