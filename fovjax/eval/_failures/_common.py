"""Where foveated rendering fails: named experiments, each written as its own CSV and chart, so
that a failure shows as the case it is and is not averaged into one number.

- `corner_gaze`: gaze at a screen corner against the centre — error and FLIP per 5° ring;
- `tracking_error`: the frame foveated on a gaze that is off by a tracker error of 1°, 2°, 4°
  in four directions, error measured around the *true* gaze (inside the true fovea radius and
  the central 2°), for a fovea smaller than the error and one larger;
- `after_saccade`: the frames around a main-sequence saccade, foveated on the gaze a tracker
  delivered 25 ms and 50 ms earlier ("latest"), on that gaze extrapolated at constant velocity
  to display time ("predicted", `fovjax.devices.GazePredictor`) and on the true gaze
  ("perfect"), error around the true gaze frame by frame;
- `high_spp`: 1 against 16 samples per pixel at a small resolution — does foveation still win
  on time, and how far are both from a converged image;
- `checkerboard`: a fine high-contrast checkerboard filling the periphery against the same wall
  in its mean grey — error per ring and flicker (fresh and fixed key) along a pursuit;
- `acuity_models`: the thesis's exponential, a fitted linear-MAR curve, a linear fall-off and
  a constant probability at the same ray budget (`equal_budget_foveations`), under the
  "either" and the "strict" sampling rule — error per ring;
- `scanpath_flicker`: `temporal_stability` along a synthetic scanpath, fresh against fixed key.

Errors are against the full render with the *same* key (the same sub-pixel positions), so they
measure what foveation changes, not Monte-Carlo noise: with perfect tracking the fovea is the
full render (to float32 rounding: the two programs are compiled separately). |error| is the
channel mean of the difference of display-encoded (clipped, sRGB) values; FLIP is LDR-FLIP at
the rig's pixels per degree (extra `[flip]`; its columns are left out when flip-evaluator is
missing). Masked values average the per-pixel maps over the mask, both eyes side by side.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import statistics
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._metrics import HmdDisplay, display_encode, error_by_eccentricity, flip, psnr
from ._pareto import write_csv
from ._stability import FullRenders, temporal_stability

CASES = (
    "corner_gaze",
    "tracking_error",
    "after_saccade",
    "high_spp",
    "checkerboard",
    "acuity_models",
    "scanpath_flicker",
)
# What the eye resolves sharply around the gaze: the central 2° (the fovea proper is ~5° across).
CENTRAL_DEG = 2.0
SACCADE_POLICIES = ("perfect", "latest", "predicted")


# ---- shared helpers ---------------------------------------------------------------------------


def _has_flip() -> bool:
    return importlib.util.find_spec("flip_evaluator") is not None


def _side(eye_maps) -> np.ndarray:
    """(2, H, W) per-eye maps -> (H, 2W) side by side."""
    m = np.asarray(eye_maps)
    return np.concatenate([m[0], m[1]], axis=1)


def _true_eccentricity(rig, gaze, foveation) -> np.ndarray:
    """(H, 2W) eccentricity of every pixel from the *true* gaze (per eye), still head."""
    from ..foveate import eccentricity_map

    g = np.asarray(gaze, np.float32).reshape(2, 2)
    return _side([np.asarray(eccentricity_map(c, g[i], foveation)) for i, c in enumerate(rig.eye_cameras())])


def offset_gaze(rig, gaze, angle_deg: float, direction_deg: float = 0.0) -> np.ndarray:
    """Per-eye gaze points (2, 2) `angle_deg` degrees of visual angle away from `gaze`
    (normalised display coordinates, one point or one per eye) towards `direction_deg` on the
    display (0 right, 90 down, 180 left, 270 up), through each eye's own camera model. Raises
    ValueError when the point would leave the screen."""
    from ..foveate import eccentricity_angle

    if not (math.isfinite(angle_deg) and 0 <= angle_deg < 90):
        raise ValueError(f"offset_gaze: angle_deg must be in [0, 90), got {angle_deg}")
    g = np.broadcast_to(np.asarray(gaze, np.float64).reshape(-1, 2), (2, 2))
    out = np.empty((2, 2))
    direction = np.array([math.cos(math.radians(direction_deg)), math.sin(math.radians(direction_deg))])
    for i, cam in enumerate(rig.eye_cameras()):
        size = np.array([cam.width, cam.height], np.float64)
        centre = g[i] * size
        s = np.linspace(0.0, 4.0 * float(size.max()), 8001)
        px = (centre[None] + s[:, None] * direction[None]).astype(np.float32)
        angles = np.asarray(eccentricity_angle(cam, jnp.asarray(g[i], jnp.float32), px), np.float64)
        out[i] = (centre + float(np.interp(angle_deg, angles, s)) * direction) / size
    if not np.isfinite(out).all() or (out < 0).any() or (out > 1).any():
        raise ValueError(
            f"offset_gaze: {angle_deg}° towards {direction_deg}° from {g[0].tolist()} leaves the screen "
            f"({out.tolist()})"
        )
    return out.astype(np.float32)


def _gaze_angle(rig, a, b) -> float:
    """Degrees between the left eye's gaze rays through points a and b."""
    from ..foveate import eccentricity_angle

    cam = rig.eye_cameras()[0]
    a = np.asarray(a, np.float32).reshape(-1, 2)[0]
    b = np.asarray(b, np.float32).reshape(-1, 2)[0]
    px = (b * np.array([cam.width, cam.height], np.float32))[None]
    return float(np.asarray(eccentricity_angle(cam, jnp.asarray(a), px))[0])


@dataclasses.dataclass
class _Bench:
    """What every case needs: the scene, rig and config, memoised full renders, the display's
    ppd for FLIP, and a progress callback."""

    scene: object
    rig: object
    full: FullRenders
    tick: Callable[[], None]
    use_flip: bool

    @classmethod
    def make(cls, scene, rig, config=None, full=None, progress=None, use_flip=None) -> _Bench:
        full = full or FullRenders(scene, rig, config)
        if full.rig is not rig:
            raise ValueError("failure cases: `full` renders another rig than `rig`")
        return cls(
            scene, rig, full, progress or (lambda: None), _has_flip() if use_flip is None else use_flip
        )

    @property
    def ppd(self) -> float:
        return HmdDisplay.from_camera(self.rig.eye_cameras()[0]).ppd

    def foveated(self, gaze, foveation, key):
        from ..foveate import render_foveated

        frame = render_foveated(
            self.scene,
            self.rig,
            gaze=np.asarray(gaze, np.float32).reshape(2, 2),
            foveation=foveation,
            key=None if key is None else jax.random.key(int(key)),
            config=self.full.config,
            bvh=self.full.bvh,
        )
        self.tick()
        return frame

    def reference(self, key, spp: int = 1) -> np.ndarray:
        image = self.full.image(key, spp)
        return image

    def maps(self, test, ref) -> dict[str, np.ndarray]:
        """Per-pixel error maps (H, 2W): "abs" and, with flip-evaluator, "flip"."""
        maps = {"abs": np.abs(display_encode(test) - display_encode(ref)).mean(axis=-1)}
        if self.use_flip:
            maps["flip"] = flip(test, ref, ppd=self.ppd, return_map=True)[1]
        return maps


def _masked(maps: Mapping[str, np.ndarray], mask: np.ndarray, suffix: str) -> dict[str, float]:
    n = int(mask.sum())
    out = {f"pixels_{suffix}": n}
    for name, m in maps.items():
        out[f"{name}_{suffix}"] = float(m[mask].mean()) if n else math.nan
    return out


def _ring_rows(maps, test, ref, ecc, ring_deg: float) -> list[dict]:
    rings = error_by_eccentricity(test, ref, ecc, ring_deg=ring_deg, error_map=maps["abs"])
    flips = (
        error_by_eccentricity(test, ref, ecc, ring_deg=ring_deg, error_map=maps["flip"])
        if "flip" in maps
        else None
    )
    rows = []
    for i, row in enumerate(rings.rows()):
        out = {
            "ring_lower_deg": row["ring_lower_deg"],
            "ring_upper_deg": row["ring_upper_deg"],
            "ring_pixels": row["pixels"],
            "abs_error": row["mean_error"],
        }
        if flips is not None:
            out["flip"] = float(flips.mean_error[i])
        rows.append(out)
    return rows


def _frame_metrics(maps, test, ref) -> dict[str, float]:
    out = {"frame_psnr": psnr(test, ref).value, "frame_abs_error": float(maps["abs"].mean())}
    if "flip" in maps:
        out["frame_flip"] = float(maps["flip"].mean())
    return out


def _mean(records, column: str, **match) -> float:
    return statistics.mean(r[column] for r in records if all(r[k] == v for k, v in match.items()))


def _metric(records, name) -> str:
    """The error column to summarise by: FLIP when measured, else |error|."""
    return name if records and name in records[0] else name.replace("flip", "abs")


@dataclasses.dataclass(frozen=True)
class FailureCase:
    """One named experiment: its `records` (CSV rows; `kind` separates row types where a case
    has several), a `finding` sentence computed from them, the `parameters` it ran with, and
    its wall time in seconds (compiles included)."""

    name: str
    title: str
    records: list[dict]
    finding: str
    parameters: dict
    seconds: float

    def write(self, out_dir) -> dict[str, Path]:
        """`NAME.csv` and `NAME.png` in `out_dir`."""
        from . import _charts

        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        chart = getattr(_charts, f"plot_{self.name}")
        return {
            "csv": write_csv(self.records, out / f"{self.name}.csv"),
            "chart": chart(self.records, out / f"{self.name}.png", title=self.title),
        }


@dataclasses.dataclass(frozen=True)
class FailureReport:
    """The cases that were run, by name."""

    cases: dict[str, FailureCase]

    def write(self, out_dir) -> dict[str, Path]:
        """Each case's CSV and chart, and `findings.csv` (one row per case)."""
        out = Path(out_dir)
        paths = {}
        for name, case in self.cases.items():
            for kind, path in case.write(out).items():
                paths[f"{name}_{kind}"] = path
        rows = [
            {
                "case": c.name,
                "title": c.title,
                "finding": c.finding,
                "seconds": c.seconds,
                "parameters": repr(c.parameters),
            }
            for c in self.cases.values()
        ]
        paths["findings"] = write_csv(rows, out / "findings.csv")
        return paths


# ---- equal ray budget across acuity models ----------------------------------------------------


class AcuityTerms(eqx.Module):
    """gain · (exp_a·exp(−ω/exp_b) + const + mar_a / (1 + (ω/mar_e2)^mar_p) + ramp(ω)), where
    ramp falls linearly from ramp_top at ramp_start to ramp_floor at ramp_end degrees.

    Every acuity family of the project is one setting of these terms (`AcuityTerms.of`): the
    thesis's exponential, linear and power MAR, `LinearFalloff`, `Constant`. With one class for
    all of them, foveations that differ only in their curve share one compiled program, and the
    gain scales a curve to a ray budget without changing its shape. (Foveation.probability clips
    the result to [0, 1].)"""

    gain: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1.0)
    exp_a: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
    exp_b: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1.0)
    const: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
    mar_a: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
    mar_e2: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1.0)
    mar_p: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1.0)
    ramp_top: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
    ramp_floor: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
    ramp_start: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
    ramp_end: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1.0)

    def __call__(self, omega):
        w = jnp.asarray(omega, jnp.float32)
        f = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
        value = f(self.exp_a) * jnp.exp(-w / f(self.exp_b)) + f(self.const)
        pos = w > 0
        powered = jnp.where(
            pos, jnp.exp(f(self.mar_p) * jnp.log(jnp.where(pos, w, 1.0) / f(self.mar_e2))), 0.0
        )
        value = value + f(self.mar_a) / (1.0 + powered)
        s = jnp.clip(
            (w - f(self.ramp_start)) / jnp.maximum(f(self.ramp_end) - f(self.ramp_start), 1e-6), 0.0, 1.0
        )
        value = value + (1.0 - s) * f(self.ramp_top) + s * f(self.ramp_floor)
        return f(self.gain) * value

    @classmethod
    def of(cls, model, gain: float = 1.0) -> AcuityTerms:
        """The terms of an `fovjax.acuity` model (Exponential, LinearMAR, PowerMAR) or a
        `fovjax.foveate` LinearFalloff / Constant, times `gain`."""
        from ..acuity import Exponential, LinearMAR, PowerMAR
        from ..foveate import Constant, LinearFalloff

        v = lambda x: float(np.asarray(x))  # noqa: E731
        if isinstance(model, AcuityTerms):
            return dataclasses.replace(model, gain=v(model.gain) * gain)
        if isinstance(model, Exponential):
            return cls(gain=gain, exp_a=v(model.a), exp_b=v(model.b), const=v(model.c))
        if isinstance(model, LinearMAR):
            return cls(gain=gain, mar_a=v(model.a), mar_e2=v(model.e2))
        if isinstance(model, PowerMAR):
            return cls(gain=gain, mar_a=v(model.a), mar_e2=v(model.e2), mar_p=v(model.p))
        if isinstance(model, LinearFalloff):
            return cls(
                gain=gain,
                ramp_top=1.0,
                ramp_floor=v(model.floor),
                ramp_start=v(model.start),
                ramp_end=v(model.end),
            )
        if isinstance(model, Constant):
            return cls(gain=gain, const=v(model.p))
        raise ValueError(
            f"AcuityTerms.of: cannot express {type(model).__name__} as acuity terms; use Exponential, "
            "LinearMAR, PowerMAR, LinearFalloff or Constant"
        )


@dataclasses.dataclass(frozen=True)
class EqualBudget:
    """Foveations (by model name) whose curves are scaled (`gains`) so that the expected
    primary rays per frame over `gazes` equal the first (reference) model's, all with the same
    static `ray_budget` per eye (the largest any of them plans), so they also cost the same
    slots and share one compiled program."""

    foveations: dict
    gains: dict
    expected_rays: dict
    ray_budget: int
    reference: str


def _candidates(rig, foveation, gazes):
    """Per gaze and eye: mandatory sample count and the curve's values at the probabilistic
    candidates (the expected-count terms of plan_budget for one gaze)."""
    from ..foveate import FOVEA, eccentricity_map, regions, top_left

    parts = []
    for g in gazes:
        g = np.broadcast_to(np.asarray(g, np.float32).reshape(-1, 2), (2, 2))
        for i, cam in enumerate(rig.eye_cameras()):
            ecc = eccentricity_map(cam, jnp.asarray(g[i]), foveation)
            region = regions(ecc, foveation)
            ty, tx, _ = top_left(region, foveation)
            is_tl = np.asarray(jnp.zeros(region.shape, bool).at[ty, tx].set(True))
            fovea = np.asarray(region == FOVEA)
            if foveation.rule == "either":
                mandatory = fovea | is_tl
                cand = ~mandatory
            else:
                mandatory = fovea
                cand = ~fovea & is_tl
            parts.append((int(mandatory.sum()), np.asarray(ecc)[cand]))
    return parts


def _expected(parts, curve, spp: int, n_gazes: int) -> float:
    total = 0.0
    for mandatory, omega in parts:
        p = np.clip(np.asarray(curve(jnp.asarray(omega)), np.float64), 0.0, 1.0)
        total += spp * (mandatory + float(p.sum()))
    return total / n_gazes


def equal_budget_foveations(
    rig, foveation, models: Mapping[str, object], *, gazes: Sequence = ((0.5, 0.5),), rtol: float = 1e-4
) -> EqualBudget:
    """Scale each of `models` (name -> acuity model; the first is the reference, gain 1) by the
    gain that makes the expected primary rays per frame of `foveation` with that curve, averaged
    over `gazes`, equal the reference's (bisection to `rtol`), and give all of them the same
    static ray budget per eye. The fovea and region thresholds, blocks and rule stay
    `foveation`'s: only where the probabilistic samples go differs."""
    from ..foveate import plan_budget

    if not models:
        raise ValueError("equal_budget_foveations: need at least one model")
    if not (0 < rtol < 0.1):
        raise ValueError(f"equal_budget_foveations: rtol must be in (0, 0.1), got {rtol}")
    if foveation.rule not in ("either", "strict"):
        raise ValueError(
            f"equal_budget_foveations: rule {foveation.rule!r} draws no samples from the acuity curve; "
            "use 'either' or 'strict'"
        )
    gazes = list(gazes)
    if not gazes:
        raise ValueError("equal_budget_foveations: need at least one gaze")
    parts = _candidates(rig, foveation, gazes)
    names = list(models)
    curves = {name: AcuityTerms.of(models[name]) for name in names}
    target = _expected(parts, curves[names[0]], foveation.spp, len(gazes))
    gains, expected = {names[0]: 1.0}, {names[0]: target}
    for name in names[1:]:
        base = curves[name]
        rays = lambda g, base=base: _expected(parts, AcuityTerms.of(base, g), foveation.spp, len(gazes))  # noqa: E731
        lo, hi = 0.0, 1.0
        while rays(hi) < target:
            hi *= 2.0
            if hi > 1e9:
                raise ValueError(
                    f"equal_budget_foveations: model {name!r} cannot reach the reference's "
                    f"{target:.0f} expected rays at any gain (its curve is zero beyond the fovea?)"
                )
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if rays(mid) < target:
                lo = mid
            else:
                hi = mid
            if abs(rays(hi) - target) <= rtol * target:
                break
        gains[name], expected[name] = hi, rays(hi)
    arms = {
        n: dataclasses.replace(foveation, acuity=AcuityTerms.of(curves[n], gains[n]), ray_budget=None)
        for n in names
    }
    budget = max(plan_budget(cam, f) for f in arms.values() for cam in rig.eye_cameras())
    arms = {n: dataclasses.replace(f, ray_budget=int(budget)) for n, f in arms.items()}
    return EqualBudget(arms, gains, expected, int(budget), names[0])


def default_models() -> dict[str, object]:
    """The thesis's exponential, the fitted linear-MAR curve (`fits/published_linear_mar.json`
    when the repository's fits are present, else Song, Levi & Pelli's E2 = 2.72°), the
    `LinearFalloff` default (1 at 5° to 0.05 at 30°) and `Constant` (uniform)."""
    from ..acuity import THESIS_MODEL, LinearMAR, load_fit
    from ..foveate import Constant, LinearFalloff

    fit = Path(__file__).resolve().parents[2] / "fits" / "published_linear_mar.json"
    if fit.exists():
        mar = load_fit(fit)
        mar_name = f"linear MAR fit (E2 {float(mar.e2):.2f}°)"
    else:
        mar = LinearMAR()
        mar_name = "linear MAR (E2 2.72°, Song et al.)"
    return {
        "thesis exponential": THESIS_MODEL,
        mar_name: mar,
        "linear fall-off": LinearFalloff(),
        "constant": Constant(),
    }


# ---- the cases --------------------------------------------------------------------------------


def _case(name, title, records, finding, parameters, t0) -> FailureCase:
    return FailureCase(name, title, records, finding, parameters, time.perf_counter() - t0)


def corner_gaze(
    scene,
    rig,
    foveation=None,
    *,
    corner=(0.02, 0.02),
    centre=(0.5, 0.5),
    keys: Sequence[int] = (0, 1),
    ring_deg: float = 5.0,
    config=None,
    full: FullRenders | None = None,
    progress=None,
) -> FailureCase:
    """Gaze at a screen corner (both eyes) against the centre: error and FLIP per eccentricity
    ring, primary rays in the fovea, samples dropped beyond the budget."""
    from ..foveate import Foveation, check_gaze

    t0 = time.perf_counter()
    foveation = foveation or Foveation.thesis(2)
    if not keys:
        raise ValueError("corner_gaze: need at least one key")
    bench = _Bench.make(scene, rig, config, full, progress)
    records = []
    for label, point in (("centre", centre), ("corner", corner)):
        g = check_gaze(
            np.broadcast_to(np.asarray(point, np.float64).reshape(-1, 2), (2, 2)), f"corner_gaze {label}"
        )
        for k in keys:
            frame = bench.foveated(g, foveation, k)
            ref = bench.reference(k)
            maps = bench.maps(frame.image, ref)
            ecc = _side(frame.eccentricity)
            common = {
                "gaze": label,
                "gaze_x": float(g[0, 0]),
                "gaze_y": float(g[0, 1]),
                "key": int(k),
                "primary_rays": frame.stats.primary_rays,
                "fovea_rays": frame.foveation.primary_by_region[0],
                "dropped": frame.foveation.dropped,
                **_frame_metrics(maps, frame.image, ref),
            }
            records += [{**common, **row} for row in _ring_rows(maps, frame.image, ref, ecc, ring_deg)]
    m = _metric(records, "frame_flip")
    by = {lab: statistics.mean(r[m] for r in records if r["gaze"] == lab) for lab in ("centre", "corner")}
    rays = {
        lab: statistics.mean(r["fovea_rays"] for r in records if r["gaze"] == lab)
        for lab in ("centre", "corner")
    }
    rings = [r for r in records if r["gaze"] == "corner" and np.isfinite(r["abs_error"])]
    worst = max(rings, key=lambda r: r["abs_error"])
    finding = (
        f"{m} corner {by['corner']:.4f} vs centre {by['centre']:.4f}; fovea primary rays corner "
        f"{rays['corner']:.0f} vs centre {rays['centre']:.0f}; corner's worst ring "
        f"{worst['ring_lower_deg']:g}-{worst['ring_upper_deg']:g}° |error| {worst['abs_error']:.4f}; "
        f"dropped samples {max(r['dropped'] for r in records)}"
    )
    params = {
        "corner": tuple(corner),
        "centre": tuple(centre),
        "keys": tuple(keys),
        "fovea_deg": foveation.fovea_deg,
        "periphery_deg": foveation.periphery_deg,
    }
    return _case("corner_gaze", f"gaze at corner {tuple(corner)} vs centre", records, finding, params, t0)


def tracking_error(
    scene,
    rig,
    foveations: Sequence | None = None,
    *,
    errors_deg: Sequence[float] = (0.0, 1.0, 2.0, 4.0),
    directions_deg: Sequence[float] = (0.0, 90.0, 180.0, 270.0),
    gaze=(0.5, 0.5),
    keys: Sequence[int] = (0,),
    central_deg: float = CENTRAL_DEG,
    config=None,
    full: FullRenders | None = None,
    progress=None,
) -> FailureCase:
    """The frame foveated on a gaze `error` degrees off the true one (each of
    `directions_deg`), error measured around the true gaze: inside the true fovea radius, inside
    the central `central_deg`, and the share of true-fovea pixels the rendered fovea covers.
    `foveations`: default a 2° fovea (smaller than a 2-4° tracker error) and the thesis's 10°."""
    from ..foveate import Foveation, check_gaze

    t0 = time.perf_counter()
    foveations = list(foveations) if foveations is not None else [Foveation(2.0, 4.0), Foveation.thesis(2)]
    errors = [float(e) for e in errors_deg]
    if not foveations or not errors or any(not (math.isfinite(e) and e >= 0) for e in errors):
        raise ValueError(
            f"tracking_error: need foveations and finite errors >= 0 degrees, got {errors_deg!r}"
        )
    if not directions_deg or not keys:
        raise ValueError("tracking_error: need at least one direction and one key")
    if not central_deg > 0:
        raise ValueError(f"tracking_error: central_deg must be > 0, got {central_deg}")
    true = check_gaze(
        np.broadcast_to(np.asarray(gaze, np.float64).reshape(-1, 2), (2, 2)), "tracking_error gaze"
    )
    bench = _Bench.make(scene, rig, config, full, progress)
    records = []
    for fov in foveations:
        ecc = _true_eccentricity(rig, true, fov)
        masks = {"true_fovea": ecc <= fov.fovea_deg, "central": ecc <= central_deg}
        for e in errors:
            for d in directions_deg if e > 0 else directions_deg[:1]:
                shown = offset_gaze(rig, true, e, float(d))
                for k in keys:
                    frame = bench.foveated(shown, fov, k)
                    ref = bench.reference(k)
                    maps = bench.maps(frame.image, ref)
                    row = {
                        "fovea_deg": fov.fovea_deg,
                        "periphery_deg": fov.periphery_deg,
                        "tracker_error_deg": e,
                        "direction_deg": float(d) if e > 0 else math.nan,
                        "key": int(k),
                        "shown_gaze_x": float(shown[0, 0]),
                        "shown_gaze_y": float(shown[0, 1]),
                        "measured_error_deg": _gaze_angle(rig, true, shown),
                        "true_fovea_covered": float((_side(frame.regions)[masks["true_fovea"]] == 0).mean()),
                        "primary_rays": frame.stats.primary_rays,
                    }
                    for name, mask in masks.items():
                        row.update(_masked(maps, mask, name))
                    row.update(_frame_metrics(maps, frame.image, ref))
                    records.append(row)
    m = _metric(records, "flip_true_fovea")
    parts = []
    for fov in foveations:
        vals = [
            f"{e:g}°: {_mean(records, m, fovea_deg=fov.fovea_deg, tracker_error_deg=e):.4f}" for e in errors
        ]
        parts.append(f"fovea {fov.fovea_deg:g}° — " + ", ".join(vals))
    finding = f"{m} inside the true fovea by tracker error: " + "; ".join(parts)
    params = {
        "errors_deg": tuple(errors),
        "directions_deg": tuple(directions_deg),
        "gaze": tuple(np.ravel(gaze)),
        "foveas": tuple((f.fovea_deg, f.periphery_deg) for f in foveations),
        "central_deg": central_deg,
    }
    return _case("tracking_error", "tracker error against fovea size", records, finding, params, t0)


def _saccade_path(rig, start, amplitude_deg, direction_deg, onset_s):
    from ..devices import min_jerk, saccade_duration

    start = np.broadcast_to(np.asarray(start, np.float64).reshape(-1, 2), (2, 2))
    land = offset_gaze(rig, start, amplitude_deg, direction_deg).astype(np.float64)
    duration = saccade_duration(amplitude_deg)

    def at(t: float) -> np.ndarray:
        w = float(min_jerk((t - onset_s) / duration))
        return start + (land - start) * w

    return at, onset_s + duration, duration


def after_saccade(
    scene,
    rig,
    foveation=None,
    *,
    start=(0.3, 0.5),
    amplitude_deg: float = 20.0,
    direction_deg: float = 0.0,
    fps: float = 60.0,
    latencies_s: Sequence[float] = (0.025, 0.05),
    tracker_hz: float = 120.0,
    before_frames: int = 2,
    after_s: float = 0.1,
    key: int = 0,
    central_deg: float = CENTRAL_DEG,
    policies: Sequence[str] = SACCADE_POLICIES,
    config=None,
    full: FullRenders | None = None,
    progress=None,
) -> FailureCase:
    """Frames around one saccade (main-sequence duration, minimum-jerk profile, as
    `fovjax.devices.Scanpath`) of `amplitude_deg` from `start`, displayed at `fps`. The frame
    shown at time t is foveated on: "perfect" the true gaze at t; "latest" the last tracker
    sample (at `tracker_hz`) taken a latency before t, for each of `latencies_s`; "predicted"
    that sample extrapolated at the velocity of the last two samples to t
    (`fovjax.devices.GazePredictor`, horizon at most 50 ms). Error around the true gaze at t
    (true fovea, central `central_deg`), frame by frame; the key is fixed so a still frame with
    perfect tracking has no error in the fovea. `display` names policy and latency."""
    from ..devices import GazePredictor
    from ..foveate import Foveation

    t0 = time.perf_counter()
    foveation = foveation or Foveation.thesis(2)
    if any(p not in SACCADE_POLICIES for p in policies) or not policies:
        raise ValueError(f"after_saccade: policies must be among {SACCADE_POLICIES}, got {policies!r}")
    for name, value in (("fps", fps), ("tracker_hz", tracker_hz), ("amplitude_deg", amplitude_deg)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"after_saccade: {name} must be > 0, got {value}")
    latencies = [float(x) for x in latencies_s]
    if not latencies or any(not (math.isfinite(x) and x >= 0) for x in latencies):
        raise ValueError(f"after_saccade: latencies_s must be finite seconds >= 0, got {latencies_s!r}")
    if not (after_s >= 0) or before_frames < 1:
        raise ValueError(
            f"after_saccade: need after_s >= 0 and before_frames >= 1, got {after_s}, {before_frames}"
        )
    onset = (before_frames - 0.5) / fps
    path, landing, duration = _saccade_path(rig, start, amplitude_deg, direction_deg, onset)
    predictor = GazePredictor()
    bench = _Bench.make(scene, rig, config, full, progress)
    ref = bench.reference(key)
    n_frames = int(math.ceil((landing + after_s) * fps)) + 1
    records = []
    for f in range(n_frames):
        t = f / fps
        true = path(t)
        shown_by = {}
        for policy in policies:
            for latency in [0.0] if policy == "perfect" else latencies:
                if policy == "perfect":
                    shown = true
                else:
                    sample_t = math.floor((t - latency) * tracker_hz + 1e-9) / tracker_hz
                    shown = sample = path(sample_t)
                    if policy == "predicted":
                        velocity = (sample - path(sample_t - 1.0 / tracker_hz)) * tracker_hz
                        shown = np.array([predictor(sample[i], velocity[i], sample_t, t) for i in range(2)])
                label = policy if policy == "perfect" else f"{policy}, {1000 * latency:g} ms"
                shown_by[label] = (policy, latency, np.clip(shown, 0.0, 1.0).astype(np.float32))
        ecc = _true_eccentricity(rig, true, foveation)
        masks = {"true_fovea": ecc <= foveation.fovea_deg, "central": ecc <= central_deg}
        phase = "before" if t < onset else "saccade" if t < landing else "after"
        for label, (policy, latency, shown) in shown_by.items():
            frame = bench.foveated(shown, foveation, key)
            maps = bench.maps(frame.image, ref)
            row = {
                "display": label,
                "policy": policy,
                "latency_ms": 1000 * latency,
                "frame": f,
                "time_ms": 1000 * t,
                "since_landing_ms": 1000 * (t - landing),
                "phase": phase,
                "true_gaze_x": float(true[0, 0]),
                "true_gaze_y": float(true[0, 1]),
                "shown_gaze_x": float(shown[0, 0]),
                "shown_gaze_y": float(shown[0, 1]),
                "gaze_error_deg": _gaze_angle(rig, true, shown),
                "true_fovea_covered": float((_side(frame.regions)[masks["true_fovea"]] == 0).mean()),
            }
            for name, mask in masks.items():
                row.update(_masked(maps, mask, name))
            records.append(row)
    m = _metric(records, "flip_true_fovea")
    parts = []
    for label in dict.fromkeys(r["display"] for r in records):
        rows = [r for r in records if r["display"] == label and r["phase"] == "after"]
        values = ", ".join(f"{r[m]:.4f}" for r in rows[:4])
        parts.append(f"{label} [{values}]")
    finding = (
        f"{amplitude_deg:g}° saccade at {fps:g} Hz, {m} in the first frames after landing: "
        + "; ".join(parts)
    )
    params = {
        "start": tuple(np.ravel(start)),
        "amplitude_deg": amplitude_deg,
        "direction_deg": direction_deg,
        "fps": fps,
        "latencies_s": tuple(latencies),
        "tracker_hz": tracker_hz,
        "saccade_ms": 1000 * duration,
        "onset_ms": 1000 * onset,
        "landing_ms": 1000 * landing,
        "fovea_deg": foveation.fovea_deg,
    }
    return _case("after_saccade", f"frames around a {amplitude_deg:g}° saccade", records, finding, params, t0)


def high_spp(
    scene,
    rig,
    fovea_pair: tuple[float, float] = (10.0, 20.0),
    *,
    spp: Sequence[int] = (1, 16),
    keys: Sequence[int] = (0, 1),
    gaze=(0.5, 0.5),
    config=None,
    progress=None,
) -> FailureCase:
    """Full and foveated frames at each of `spp` (give `rig` a small resolution): ms per frame
    (median over the keys' renders, compile excluded), rays, the foveated frame against the
    full one of the same spp and key, and both against a converged image — the full render at
    the largest spp with another key (with one key: the same key, which then measures only the
    foveation's bias)."""
    from ..foveate import Foveation, check_gaze

    t0 = time.perf_counter()
    spp = sorted({int(s) for s in spp})
    if not spp or any(s < 1 or int(round(s**0.5)) ** 2 != s for s in spp):
        raise ValueError(f"high_spp: spp must be positive squares (1, 4, 9, 16, ...), got {spp!r}")
    if not keys:
        raise ValueError("high_spp: need at least one key")
    g = check_gaze(np.broadcast_to(np.asarray(gaze, np.float64).reshape(-1, 2), (2, 2)), "high_spp gaze")
    bench = _Bench.make(scene, rig, config, None, progress)
    fulls, fovs = {}, {}
    for s in spp:
        fov = Foveation(fovea_deg=float(fovea_pair[0]), periphery_deg=float(fovea_pair[1]), spp=s)
        for k in keys:
            fulls[s, k] = bench.full.frame(k, s)
            bench.tick()
            fovs[s, k] = bench.foveated(g, fov, k)
    top = spp[-1]
    converged = {k: fulls[top, keys[(i + 1) % len(keys)]].image for i, k in enumerate(keys)}

    def ms(frames):
        warm = [f.stats.render_seconds for f in frames if f.stats.compile_seconds == 0] or [
            f.stats.render_seconds for f in frames
        ]
        return 1000 * statistics.median(warm)

    records = []
    for s in spp:
        full_ms = ms([fulls[s, k] for k in keys])
        fov_ms = ms([fovs[s, k] for k in keys])
        for k in keys:
            full_f, fov_f = fulls[s, k], fovs[s, k]
            row = {
                "spp": s,
                "key": int(k),
                "full_ms": full_ms,
                "foveated_ms": fov_ms,
                "speedup": full_ms / fov_ms,
                "full_rays": full_f.stats.rays,
                "foveated_rays": fov_f.stats.rays,
                "full_primary_rays": full_f.stats.primary_rays,
                "foveated_primary_rays": fov_f.stats.primary_rays,
                "ray_reduction": 1 - fov_f.stats.rays / full_f.stats.rays,
            }
            for label, test, ref in (
                ("foveated_vs_full", fov_f.image, full_f.image),
                ("foveated_vs_converged", fov_f.image, converged[k]),
                ("full_vs_converged", full_f.image, converged[k]),
            ):
                maps = bench.maps(test, ref)
                row[f"psnr_{label}"] = psnr(test, ref).value
                row[f"abs_{label}"] = float(maps["abs"].mean())
                if "flip" in maps:
                    row[f"flip_{label}"] = float(maps["flip"].mean())
            records.append(row)
    m = "flip" if "flip_foveated_vs_full" in records[0] else "abs"
    parts = []
    for s in spp:
        rows = [r for r in records if r["spp"] == s]
        parts.append(
            f"spp {s}: speed-up {rows[0]['speedup']:.1f}x "
            f"({rows[0]['full_ms']:.0f} vs {rows[0]['foveated_ms']:.0f} ms), "
            f"{m} vs full {statistics.mean(r[f'{m}_foveated_vs_full'] for r in rows):.4f}, vs converged "
            f"foveated {statistics.mean(r[f'{m}_foveated_vs_converged'] for r in rows):.4f} / full "
            f"{statistics.mean(r[f'{m}_full_vs_converged'] for r in rows):.4f}"
        )
    finding = "; ".join(parts)
    params = {
        "spp": tuple(spp),
        "keys": tuple(keys),
        "resolution": (rig.eye_width, rig.eye_height),
        "fovea_pair": tuple(fovea_pair),
    }
    return _case(
        "high_spp",
        f"samples per pixel at {rig.eye_width}x{rig.eye_height} per eye",
        records,
        finding,
        params,
        t0,
    )


def checkerboard_scene(
    *,
    check_size: float = 0.02,
    distance: float = 1.0,
    smooth: bool = False,
    dark: float = 0.03,
    light: float = 0.9,
):
    """A wall `distance` metres in front of the viewer, wide enough to fill both eyes of an HMD
    rig (±71° horizontally, ±63° vertically), textured with a checkerboard of `check_size`-metre
    squares of linear albedo `dark` and `light` — fine high-contrast detail across the whole
    periphery — or, with `smooth`, the same wall in the checkerboard's mean albedo (same arrays'
    shapes, so both share compiled programs). Lit by one point light above and behind the
    viewer. Returns (scene, `fovjax.scenes.CameraPose`)."""
    from ..scene import CameraPose, make_lights, make_materials, make_scene

    for name, value in (("check_size", check_size), ("distance", distance)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"checkerboard_scene: {name} must be > 0 metres, got {value}")
    if not (0 <= dark <= 1 and 0 <= light <= 1):
        raise ValueError(f"checkerboard_scene: dark and light albedo must be in [0, 1], got {dark}, {light}")
    hw, hh = 3.0 * distance, 2.0 * distance
    vertices = np.array([(-hw, -hh, 0.0), (hw, -hh, 0.0), (hw, hh, 0.0), (-hw, hh, 0.0)])
    faces = np.array([(0, 1, 2), (0, 2, 3)])
    uvs = vertices[:, :2] / (2.0 * check_size)  # one texture tile holds 2x2 checks
    texels = 8  # per check: bilinear filtering blurs an edge over 1/8 of a check
    i = np.arange(2 * texels) // texels
    pattern = (i[:, None] + i[None, :]) % 2
    albedo = (
        np.where(pattern == 1, light, dark) if not smooth else np.full(pattern.shape, 0.5 * (dark + light))
    )
    texture = np.repeat(albedo[..., None], 3, axis=-1).astype(np.float32)
    scene = make_scene(
        vertices,
        faces,
        materials=make_materials([{"name": "wall", "kd": (1.0, 1.0, 1.0), "ka": (0.2,) * 3, "texture": 0}]),
        lights=make_lights([(0.4 * distance, 0.8 * distance, 1.5 * distance)], [(1.0, 1.0, 1.0)]),
        uvs=uvs,
        textures=(texture,),
        name="checkerboard" if not smooth else "checkerboard_smooth",
    )
    return scene, CameraPose(position=(0.0, 0.0, distance), look_at=(0.0, 0.0, 0.0))


def _rig_at(rig, pose):
    from ..render import StereoRig

    return StereoRig.from_pose(
        pose,
        eye_width=rig.eye_width,
        eye_height=rig.eye_height,
        fov_deg=float(rig.fov_deg),
        fov_axis=rig.fov_axis,
        toe_out_deg=float(rig.toe_out_deg),
        ipd=float(rig.ipd),
        offsets=np.asarray(rig.offsets),
        eye_centre=np.asarray(rig.eye_centre),
    )


def checkerboard(
    rig,
    foveation=None,
    *,
    check_size: float = 0.02,
    keys: Sequence[int] = (0, 1),
    gaze=(0.5, 0.5),
    frames: int = 8,
    fps: float = 90.0,
    pursuit_hz: float = 0.5,
    ring_deg: float = 5.0,
    config=None,
    progress=None,
) -> FailureCase:
    """A fine checkerboard filling the periphery (`checkerboard_scene`) against the same wall
    in its mean grey, seen with `rig`'s intrinsics: error per ring at `gaze` ("ring" rows) and
    flicker along a circular pursuit of radius 0.1 at `pursuit_hz` laps per second, fresh
    against fixed key ("flicker" rows, see `temporal_stability`)."""
    from ..devices import SmoothPursuit
    from ..foveate import Foveation, check_gaze

    t0 = time.perf_counter()
    foveation = foveation or Foveation.thesis(2)
    if not keys:
        raise ValueError("checkerboard: need at least one key")
    g = check_gaze(np.broadcast_to(np.asarray(gaze, np.float64).reshape(-1, 2), (2, 2)), "checkerboard gaze")
    records = []
    for smooth in (False, True):
        scene, pose = checkerboard_scene(check_size=check_size, smooth=smooth)
        wall_rig = _rig_at(rig, pose)
        bench = _Bench.make(scene, wall_rig, config, None, progress)
        label = "smooth" if smooth else "checkerboard"
        for k in keys:
            frame = bench.foveated(g, foveation, k)
            ref = bench.reference(k)
            maps = bench.maps(frame.image, ref)
            region = _side(frame.regions)
            common = {"kind": "ring", "scene": label, "key": int(k), **_frame_metrics(maps, frame.image, ref)}
            common.update(_masked(maps, region != 0, "beyond_fovea"))
            rows = _ring_rows(maps, frame.image, ref, _side(frame.eccentricity), ring_deg)
            records += [{**common, **row} for row in rows]
        pursuit = SmoothPursuit(centre=(0.5, 0.5), radius=(0.1, 0.1), frequency=pursuit_hz)
        result = temporal_stability(
            scene,
            wall_rig,
            pursuit,
            foveation,
            frames=frames,
            fps=fps,
            seed=int(keys[0]),
            full=bench.full,
            progress=bench.tick,
        )
        for row in result.summary:
            records.append({"kind": "flicker", "scene": label, **row})
    m = _metric([r for r in records if r["kind"] == "ring"], "flip_beyond_fovea")

    def pick(scene, kind, col, mode=None):
        rows = [
            r
            for r in records
            if r["scene"] == scene and r["kind"] == kind and (mode is None or r["key_mode"] == mode)
        ]
        return statistics.mean(r[col] for r in rows)

    finding = (
        f"{m}: checkerboard {pick('checkerboard', 'ring', m):.4f} vs smooth {pick('smooth', 'ring', m):.4f}; "
        f"flicker beyond the fovea relative to the full fresh-key render: fresh key "
        f"{pick('checkerboard', 'flicker', 'ratio_beyond_fovea', 'fresh'):.2f} (checkerboard) vs "
        f"{pick('smooth', 'flicker', 'ratio_beyond_fovea', 'fresh'):.2f} (smooth), fixed key "
        f"{pick('checkerboard', 'flicker', 'ratio_beyond_fovea', 'fixed'):.2f} vs "
        f"{pick('smooth', 'flicker', 'ratio_beyond_fovea', 'fixed'):.2f}"
    )
    params = {
        "check_size_m": check_size,
        "keys": tuple(keys),
        "frames": frames,
        "fps": fps,
        "pursuit_hz": pursuit_hz,
        "fovea_deg": foveation.fovea_deg,
        "periphery_deg": foveation.periphery_deg,
    }
    return _case("checkerboard", "fine checkerboard periphery vs smooth wall", records, finding, params, t0)


def acuity_models(
    scene,
    rig,
    foveation=None,
    *,
    models: Mapping[str, object] | None = None,
    gazes: Sequence = ((0.5, 0.5), (0.3, 0.4)),
    keys: Sequence[int] = (0,),
    rules: Sequence[str] = ("either", "strict"),
    ring_deg: float = 5.0,
    budgets: Mapping[str, EqualBudget] | None = None,
    config=None,
    full: FullRenders | None = None,
    progress=None,
) -> FailureCase:
    """Acuity models at the same ray budget (`equal_budget_foveations`), under each sampling
    rule of `rules` (under "either" the block top-lefts are traced whatever the curve, under
    "strict" every sample beyond the fovea is the curve's draw); `budgets` (rule -> EqualBudget)
    reuses ones already made. Per rule, model, gaze and key the primary rays (and their
    difference from the rule's reference model's), frame error and FLIP ("frame" rows), and
    error and primary rays per ring ("ring" rows); `arm` names rule and model."""
    from ..foveate import SAMPLING_RULES, Foveation, check_gaze

    t0 = time.perf_counter()
    foveation = foveation or Foveation.thesis(2)
    gazes = [
        check_gaze(np.broadcast_to(np.asarray(g, np.float64).reshape(-1, 2), (2, 2)), "acuity_models gaze")
        for g in gazes
    ]
    if not gazes or not keys:
        raise ValueError("acuity_models: need at least one gaze and one key")
    drawn = tuple(r for r in SAMPLING_RULES if r != "thesis-measured")  # rules that use the curve
    if not rules or any(r not in drawn for r in rules):
        raise ValueError(f"acuity_models: rules must be among {drawn}, got {rules!r}")
    budgets = dict(budgets or {})
    models = models or default_models()
    for rule in rules:
        if rule not in budgets:
            budgets[rule] = equal_budget_foveations(
                rig, dataclasses.replace(foveation, rule=rule), models, gazes=gazes
            )
    bench = _Bench.make(scene, rig, config, full, progress)
    records, rays_ref = [], {}
    for rule in rules:
        budget = budgets[rule]
        for name, fov in budget.foveations.items():
            for gi, g in enumerate(gazes):
                for k in keys:
                    frame = bench.foveated(g, fov, k)
                    ref = bench.reference(k)
                    maps = bench.maps(frame.image, ref)
                    ecc = _side(frame.eccentricity)
                    traced = _side(frame.sample_mask.sum(axis=1))
                    primary = frame.stats.primary_rays
                    rays_ref.setdefault((rule, gi, k), primary)
                    common = {
                        "arm": f"{rule}: {name}",
                        "rule": rule,
                        "model": name,
                        "gaze_x": float(g[0, 0]),
                        "gaze_y": float(g[0, 1]),
                        "key": int(k),
                        "gain": budget.gains[name],
                        "expected_primary_rays": budget.expected_rays[name],
                        "ray_budget_per_eye": budget.ray_budget,
                    }
                    records.append(
                        {
                            "kind": "frame",
                            **common,
                            "primary_rays": primary,
                            "rays": frame.stats.rays,
                            "primary_rays_vs_reference": primary / rays_ref[rule, gi, k] - 1.0,
                            "dropped": frame.foveation.dropped,
                            "ms": 1000 * frame.stats.render_seconds,
                            **_frame_metrics(maps, frame.image, ref),
                        }
                    )
                    for row in _ring_rows(maps, frame.image, ref, ecc, ring_deg):
                        inside = (ecc >= row["ring_lower_deg"]) & (ecc < row["ring_upper_deg"])
                        records.append(
                            {"kind": "ring", **common, **row, "ring_primary_rays": int(traced[inside].sum())}
                        )
    frames = [r for r in records if r["kind"] == "frame"]
    m = _metric(frames, "frame_flip")
    parts = []
    for rule in rules:
        budget = budgets[rule]
        rows = [r for r in frames if r["rule"] == rule]
        spread = max(abs(r["primary_rays_vs_reference"]) for r in rows)
        models_text = ", ".join(
            f"{name} {_mean(rows, m, model=name):.4f} (gain {budget.gains[name]:.3g})"
            for name in budget.foveations
        )
        parts.append(
            f"{rule}: {m} at {budget.expected_rays[budget.reference]:.0f} expected primary rays "
            f"(realised within {100 * spread:.1f}%): {models_text}"
        )
    finding = "; ".join(parts)
    params = {
        "models": tuple(models),
        "rules": tuple(rules),
        "gazes": tuple(tuple(map(float, g[0])) for g in gazes),
        "keys": tuple(keys),
        "ray_budget_per_eye": {r: budgets[r].ray_budget for r in rules},
        "fovea_deg": foveation.fovea_deg,
        "periphery_deg": foveation.periphery_deg,
    }
    return _case("acuity_models", "acuity models at an equal ray budget", records, finding, params, t0)


def scanpath_flicker(
    scene,
    rig,
    foveation=None,
    *,
    seed: int = 3,
    frames: int = 16,
    fps: float = 90.0,
    lead_frames: int = 4,
    config=None,
    full: FullRenders | None = None,
    progress=None,
) -> FailureCase:
    """`temporal_stability` along `fovjax.devices.Scanpath(seed)` (its degree scale set to the
    rig's field of view) from `lead_frames` before its first saccade, fresh against fixed key;
    the rows are its per-step records."""
    from ..devices import Scanpath
    from ..foveate import Foveation

    t0 = time.perf_counter()
    foveation = foveation or Foveation.thesis(2)
    cam = rig.eye_cameras()[0]
    hfov = HmdDisplay.from_camera(cam).hfov_deg
    path = Scanpath(seed, display_fov_deg=(hfov, float(cam.vfov_deg)))
    # Start `lead_frames` before the first saccade, so the window holds gaze motion.
    onset = next(start for kind, start, _, _ in path.segments_until(60.0) if kind == "saccade")
    start_s = max(0.0, onset - lead_frames / fps)
    bench = _Bench.make(scene, rig, config, full, progress)
    result = temporal_stability(
        scene,
        rig,
        lambda t: path.position(t + start_s),
        foveation,
        frames=frames,
        fps=fps,
        seed=seed,
        full=bench.full,
        progress=bench.tick,
    )
    by = {r["key_mode"]: r for r in result.summary}
    finding = (
        "flicker beyond the fovea / full fresh-key render's: fresh key "
        f"{by['fresh']['ratio_beyond_fovea']:.2f}, "
        f"fixed key {by['fixed']['ratio_beyond_fovea']:.2f} (full fixed-key render: "
        f"{by['fixed']['full_same_policy_flicker_beyond_fovea']:.4f}); periphery band fresh "
        f"{by['fresh']['ratio_periphery']:.2f} / fixed {by['fixed']['ratio_periphery']:.2f}; mean gaze step "
        f"{by['fresh']['mean_gaze_step_deg']:.2f}° per frame"
    )
    params = {
        "seed": seed,
        "start_s": start_s,
        "frames": frames,
        "fps": fps,
        "fovea_deg": foveation.fovea_deg,
        "periphery_deg": foveation.periphery_deg,
    }
    return _case(
        "scanpath_flicker",
        f"flicker along a scanpath (seed {seed}), fresh vs fixed key",
        result.records,
        finding,
        params,
        t0,
    )


def failure_cases(
    scene,
    rig,
    foveation=None,
    *,
    cases: Sequence[str] = CASES,
    config=None,
    small_resolution: tuple[int, int] = (128, 96),
    high_spp_values: Sequence[int] = (1, 16),
    models: Mapping[str, object] | None = None,
    progress: bool = True,
    options: Mapping[str, Mapping] | None = None,
) -> FailureReport:
    """Run the named `cases` (default all, see the module docstring) on `scene` and `rig`.
    The acuity models' equal-budget foveations are made first and the reference model's (the
    thesis's by default, with the common ray budget) is the foveation of every other case, so
    they share one compiled program; `foveation` sets the thresholds (default the thesis's
    10°/20°). `high_spp` runs at `small_resolution` per eye. `options`: per-case keyword
    arguments (e.g. {"after_saccade": {"latency_s": 0.05}})."""
    from ..foveate import Foveation

    unknown = [c for c in cases if c not in CASES]
    if unknown or not cases:
        raise ValueError(f"failure_cases: unknown cases {unknown}; choose from {CASES}")
    options = dict(options or {})
    bad = [c for c in options if c not in CASES]
    if bad:
        raise ValueError(f"failure_cases: options for unknown cases {bad}; choose from {CASES}")
    foveation = foveation or Foveation.thesis(2)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(unit="frame", desc="failures")
    tick = (lambda: bar.update(1)) if bar is not None else None
    full = FullRenders(scene, rig, config)
    model_opts = dict(options.get("acuity_models", {}))
    gazes = model_opts.pop("gazes", ((0.5, 0.5), (0.3, 0.4)))
    models = models or default_models()
    budget = equal_budget_foveations(rig, foveation, models, gazes=gazes)
    base = budget.foveations[budget.reference]
    common = {"config": config, "progress": tick}
    report = {}
    for name in cases:
        if bar is not None:
            bar.set_description(name)
        opts = dict(options.get(name, {}))
        if name == "corner_gaze":
            case = corner_gaze(scene, rig, base, full=full, **common, **opts)
        elif name == "tracking_error":
            fovs = opts.pop("foveations", [Foveation(2.0, 4.0, acuity=base.acuity), base])
            case = tracking_error(scene, rig, fovs, full=full, **common, **opts)
        elif name == "after_saccade":
            case = after_saccade(scene, rig, base, full=full, **common, **opts)
        elif name == "high_spp":
            small = dataclasses.replace(
                rig, eye_width=int(small_resolution[0]), eye_height=int(small_resolution[1])
            )
            opts.setdefault("spp", high_spp_values)
            case = high_spp(scene, small, (foveation.fovea_deg, foveation.periphery_deg), **common, **opts)
        elif name == "checkerboard":
            case = checkerboard(rig, base, **common, **opts)
        elif name == "acuity_models":
            case = acuity_models(
                scene,
                rig,
                foveation,
                gazes=gazes,
                budgets={foveation.rule: budget},
                models=models,
                full=full,
                **common,
                **model_opts,
            )
        else:
            case = scanpath_flicker(scene, rig, base, full=full, **common, **opts)
        report[name] = case
    if bar is not None:
        bar.close()
    return FailureReport(report)
