"""The foveation configuration and the sampling-probability models it can use."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple, TypeAlias

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax.core import Tracer
from jaxtyping import Array, ArrayLike, Float, Real

from ..render import THESIS_BACKGROUND, RenderConfig
from ._methods import AbstractFoveationMethod, as_method

# The thesis's (fovea, periphery) pairs in degrees (section 5.1, tables 2-5).
THESIS_PAIRS: tuple[tuple[float, float], ...] = (
    (5.0, 10.0),
    (7.5, 15.0),
    (10.0, 20.0),
    (12.5, 25.0),
    (15.0, 30.0),
)

ECCENTRICITY_MODES = ("angle", "planar")
SAMPLING_RULES = ("either", "strict", "thesis-measured")
# How the regions' eccentricity is measured (`with_regions`; every command's --regions).
REGION_READINGS = ("angle", "thesis")

# Both eyes' gaze points in normalised display coordinates (x right, y down, (0, 0) the top-left
# of each eye's display): ((lx, ly), (rx, ry)) as nested sequences, a (2, 2) array or 4 numbers.
GazeLike: TypeAlias = (
    Real[ArrayLike, "2 2"] | Real[ArrayLike, " 4"] | Sequence[Sequence[float]] | Sequence[float]
)


class LinearFalloff(eqx.Module):
    """Sampling probability falling linearly from 1 at `start` to `floor` at `end` degrees and
    constant beyond: the linear fall-off of Weier et al. (2016) style foveated ray tracers."""

    start: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=5.0)
    end: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=30.0)
    floor: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.05)

    name = "linear_falloff"

    def __call__(self, omega):
        omega = jnp.asarray(omega, jnp.float32)
        s = jnp.clip((omega - self.start) / jnp.maximum(self.end - self.start, 1e-6), 0.0, 1.0)
        return (1.0 - s) + s * self.floor


class Constant(eqx.Module):
    """The same probability everywhere outside the fovea: uniform subsampling, the baseline."""

    p: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.25)

    name = "constant"

    def __call__(self, omega):
        return jnp.broadcast_to(jnp.asarray(self.p, jnp.float32), jnp.shape(omega))


SHADOW_MODES = ("all", "brightest", "none")


class Fidelity(eqx.Module):
    """Shading fidelity of one region of a foveated frame. Hashable options; `program_fidelity`
    turns depth, shadows and texture level into traced tables (a new value compiles nothing),
    while `spp` (the slot budget) and `lod` (the merged levels) are part of the program.

    - `max_depth`: mirror reflections at most this deep (None: the render config's
      `max_depth`; never more than it);
    - `shadows`: "all" (a shadow ray to every light), "brightest" (only to the light with the
      largest R + G + B of its colour, which carries its intensity; ties: the first light), or
      "none" (no shadow rays). A light without its shadow ray still lights the point,
      unshadowed: the level of detail drops the occlusion test, not the light, so the region
      keeps its brightness and loses only shadows (no light at all would darken it).

    - `lod` (geometry level of detail): None or 0 (the scene itself), a level index into the
      scene's levels of detail (`fovjax.scene.lod_levels`; `render_foveated(lod_levels=)`, by
      default the ratios (1, 0.5, 0.25, 0.1)), or "auto": the coarsest level whose error the eye
      cannot resolve at the region's inner eccentricity (see `fovjax.foveate._lod`). The region's
      rays, their shadow rays and reflections are traced against that level and shaded with its
      normals, UVs and materials. Experimental: correct and tested, but measured as not making
      frames faster on this renderer (docs/how-to-choose.md, "Experimental").
    - `texture_lod`: None (texture lookups at full resolution, level 0), an integer
      level >= 0 of the texture's box-filtered mip pyramid (level l: texels 2^l times as wide),
      or "auto": the level of the ray's footprint (a ray cone, see `fovjax.render.ShadingClasses`)
      widened by the region's sample spacing (its block edge);
    - `spp`: samples per pixel at most (None: the frame's `Foveation.spp`; an integer
      1..the frame's spp): a pixel of the region traces only its first `spp` sub-samples in a
      well-spread order (`fovjax.foveate.subsample_rank`), and the static slot budget shrinks.

    `Fidelity()` is full fidelity: the frame of a foveation without `fidelity`, bit for bit.
    """

    # `object`, not `int | None`: a wrong value gets this class's ValueError, not a type-check error.
    max_depth: object = eqx.field(static=True, default=None)
    shadows: str = eqx.field(static=True, default="all")
    # --- geometry level of detail ---
    lod: object = eqx.field(static=True, default=None)
    # --- end geometry level of detail ---
    # ---- texture level of detail and samples per pixel per region ----
    texture_lod: object = eqx.field(static=True, default=None)
    spp: object = eqx.field(static=True, default=None)
    # ---- end texture level of detail ----

    def __check_init__(self):
        depth = self.max_depth
        if depth is not None and (
            isinstance(depth, bool) or not isinstance(depth, int | np.integer) or depth < 0
        ):
            raise ValueError(f"Fidelity.max_depth must be None or an integer >= 0, got {depth!r}")
        if self.shadows not in SHADOW_MODES:
            raise ValueError(f"Fidelity.shadows must be one of {SHADOW_MODES}, got {self.shadows!r}")
        # --- geometry level of detail ---
        lod = self.lod
        if not (
            lod is None
            or lod == "auto"
            and isinstance(lod, str)
            or (isinstance(lod, int | np.integer) and not isinstance(lod, bool) and lod >= 0)
        ):
            raise ValueError(f"Fidelity.lod must be None, a level index >= 0 or 'auto', got {lod!r}")
        # --- end geometry level of detail ---
        # ---- texture level of detail and samples per region ----
        lod = self.texture_lod
        if lod is not None and lod != "auto" and not _is_int(lod, low=0):
            raise ValueError(
                f'Fidelity.texture_lod must be None, "auto" or an integer level >= 0, got {lod!r}'
            )
        if self.spp is not None and not _is_int(self.spp, low=1):
            raise ValueError(f"Fidelity.spp must be None or an integer >= 1, got {self.spp!r}")
        # ---- end texture level of detail ----


def _is_int(x, *, low: int) -> bool:
    """A Python or NumPy integer (not a bool, not a string) >= `low`."""
    return not isinstance(x, bool | str) and isinstance(x, int | np.integer) and bool(x >= low)


REGION_NAMES = ("fovea", "periphery", "outside")


def region_spp(foveation) -> tuple[int, int, int] | None:
    """Samples per pixel of each region (fovea, periphery, outside), or None where
    every region takes the frame's `spp` (the program without per-region sample counts)."""
    if foveation.fidelity is None:
        return None
    fovea, periphery, outside = (foveation.spp if f.spp is None else int(f.spp) for f in foveation.fidelity)
    spp = (fovea, periphery, outside)
    return None if all(s == foveation.spp for s in spp) else spp


def max_region_spp(foveation) -> int:
    """The most samples a pixel of any region traces: the frame's spp unless every
    region's `Fidelity.spp` is below it (then every-sample budgets shrink to it)."""
    spp = region_spp(foveation)
    return foveation.spp if spp is None else max(spp)


def shading_classes(foveation, config):
    """The renderer's `ShadingClasses` for `foveation.fidelity` (one class per region: fovea,
    periphery, outside) under the render `config`, or None where every region is at full
    fidelity (the program without classes). Raises ValueError for a depth above the config's."""
    if foveation.fidelity is None:
        return None
    from ..render.internal import SHADOWS_ALL, SHADOWS_BRIGHTEST, SHADOWS_NONE, ShadingClasses

    modes = {"all": SHADOWS_ALL, "brightest": SHADOWS_BRIGHTEST, "none": SHADOWS_NONE}
    depths = []
    for name, f in zip(("fovea", "periphery", "outside"), foveation.fidelity, strict=True):
        depth = config.max_depth if f.max_depth is None else int(f.max_depth)
        if depth > config.max_depth:
            raise ValueError(
                f"Foveation.fidelity ({name}): max_depth {depth} exceeds the render config's "
                f"max_depth {config.max_depth}"
            )
        depths.append(depth)
    shadows = [modes[f.shadows] for f in foveation.fidelity]
    texture = _texture_tables(foveation)  # texture level of detail and samples per pixel per region
    if (
        all(d == config.max_depth for d in depths)
        and all(m == SHADOWS_ALL for m in shadows)
        and texture[0] is None
    ):
        return None
    return ShadingClasses(
        np.asarray(depths, np.int32),
        np.asarray(shadows, np.int32),
        texture_level=texture[0],
        texture_cone=texture[1],
    )


def program_fidelity(foveation, config):
    """Split `foveation` for compiling: (the foveation the compiled program is keyed on, the
    `ShadingClasses` tables it is called with). Reflection depth and shadow mode per region are
    values of the tables (traced), not of the program: a new depth or shadow mode per region
    (a fidelity plan's search, a user's next try) reuses the compiled frame. What shapes the
    program stays in the foveation: each region's `spp` (the static slot budget) and `lod`; and
    in the tables' structure: whether any exist (None: every region at full fidelity, the
    program without per-ray classes) and whether they carry texture levels (their values, a
    fixed level or "auto"'s ray cone per region, are traced too). Raises ValueError as
    `shading_classes`."""
    classes = shading_classes(foveation, config)
    if foveation.fidelity is None:
        return foveation, classes
    shaped = tuple(Fidelity(lod=f.lod, spp=f.spp) for f in foveation.fidelity)
    if all(f == Fidelity() for f in shaped):
        shaped = None
    return dataclasses.replace(foveation, fidelity=shaped), classes


# ---- texture level of detail tables ----
def _texture_tables(foveation):
    """(texture_level, texture_cone) of `ShadingClasses` per region, or (None, None) where no
    region sets `texture_lod`. "auto": level 0 plus the ray cone of the region's sample spacing
    in pixels (1 in the fovea, the block edge beyond: one sample stands for a block after the
    fill), scaled to radians by the pixel's spread angle in the frame (`foveated_stereo`)."""
    lods = [f.texture_lod for f in foveation.fidelity]
    if all(lod is None for lod in lods):
        return None, None
    strides = (1, foveation.blocks[0], foveation.blocks[1])
    level = [0.0 if lod in (None, "auto") else float(lod) for lod in lods]
    cone = [float(s) if lod == "auto" else 0.0 for lod, s in zip(lods, strides, strict=True)]
    return np.asarray(level, np.float32), np.asarray(cone, np.float32)


def uses_texture_lod(foveation) -> bool:
    """Whether any region of `foveation` sets `Fidelity.texture_lod` (the scene needs mips)."""
    return foveation.fidelity is not None and any(f.texture_lod is not None for f in foveation.fidelity)


# ---- end texture level of detail ----


def _angle(x: Any) -> float | Array:
    """Thresholds are traced floats: one dtype whatever the caller passed (5, 5.0, np.float64)."""
    return x if isinstance(x, Tracer) else float(x)


def _thesis_model():
    from ..acuity import THESIS_MODEL

    return THESIS_MODEL


class Foveation(eqx.Module):
    """How a foveated frame is sampled, traced and reconstructed.

    - `fovea_deg`, `periphery_deg`: region boundaries ω0 < ω1 (degrees of eccentricity);
    - `spp`: samples per pixel (a square: 1, 4, 9, 16, ...);
    - `acuity`: a callable ω → probability in [0, 1] (default: the thesis's V(ω),
      `fovjax.acuity.THESIS_MODEL`; any `fovjax.acuity` model, `LinearFalloff`, `Constant`);
    - `blocks`: block edge in pixels for the periphery and the outside zone (thesis: 2, 4);
    - `rule`: two readings of one paragraph of the thesis (ray generation, Figure 57), which
      says the top-left condition and the P(ω) draw are conditions "either of which determines"
      a ray and then "If both conditions are met, we generate a ray". "either" (default, the
      first sentence: a sample when either holds) — a block's top-left pixel is always traced
      and any other pixel's sub-sample with probability P(ω); "strict" (the second sentence:
      both must hold) — only top-left pixels, each sub-sample kept with probability P(ω).
      Neither is the thesis's single rule; "either" is fovjax's choice. "thesis-measured" — the
      sampling the thesis's Table 2 implies (not its text): every sub-sample of the pixels
      within `periphery_deg`, one sample per pixel beyond it at any SPP, no draws (see
      `Foveation.thesis_measured` and docs/thesis.md);
    - `blur_sigma`: σ of the 5×5 Gaussian of the fill pass (pixels). Default 1: fovjax's
      choice, as the thesis names the 5×5 mask but no σ (§4.5);
    - `blur_fovea`: True blurs every pixel, as the thesis does ("For each pixel we apply a 5x5
      Gaussian blurring mask", §4.5). Default False: fovjax's choice, the fovea kept sharp and
      the blur blended in over a band of 1° beyond `fovea_deg` (a smoothstep; the thesis has no
      such band);
    - `eccentricity`: "angle" (default, fovjax's choice: the angle between the pixel's ray and
      the gaze ray) or "planar" (the thesis's eq. 4-5: Euclidean distance on the display,
      V = 2·atan(S / 2D));
    - `eye_display_mm` (D, thesis: 24 mm) and `pixel_pitch_mm` (default: derived from the
      display width and field of view) for the planar mode;
    - `ray_budget`: static number of samples traced per eye (None: derived by `plan_budget` from
      the configuration so that it is exceeded with negligible probability);
    - `max_periphery_deg`: the largest thresholds the compiled program serves (None: the
      display's full eccentricity, so any thresholds, including a tracking-loss widening to
      full rendering, reuse it). `fovea_deg` and `periphery_deg` are traced values: a new pair
      within the maximum compiles nothing. A smaller maximum lets `plan_budget` cap the
      number of slots (samples beyond it are dropped and counted, see `FoveationStats`).
    - `fovea_tile_deg`, `grid_tile`: coherent rays traced as image tiles in packets of
      neighbouring rays, as the full frame's camera rays, instead of through the sparse sample
      list (the same frame, up to float rounding): the fovea as a dense tile around the gaze
      point, sized (statically) for a fovea of `fovea_tile_deg` (None: no tile; fovea pixels
      beyond it go through the list), and with `grid_tile` every `blocks[1]`-th pixel of each
      row and column (where every outside block's top-left lies), a pixel's sub-samples side
      by side. Only when the budget is every sample (`max_periphery_deg` and `ray_budget`
      None). Off by default: they gain little on a CPU and lengthen the compile (records on
      docs/performance.md, "Foveated frames").
    - `fidelity`: None (full fidelity everywhere) or a `Fidelity` per region, (fovea,
      periphery, outside): reflection depth and shadow rays per region, and texture
      level of detail and samples per pixel per region (regions move with the gaze without a
      recompile; reflection depth, shadow mode and texture level per region are traced tables
      (`program_fidelity`: a new one compiles nothing); a region's `spp` and `lod` are static).
    - `method`: the foveation method, a name of `fovjax.foveate.METHODS` or an instance of
      one with its parameters: "thesis" (default: the frame above), "guenter2012" (three
      nested layers at decreasing resolution, magnified and blended, `Guenter2012`),
      "patney2016" (shading rate by eccentricity, temporal antialiasing and a
      contrast-preserving pre-filter, `Patney2016`), "weier2016" (sparse tracing plus
      reprojection of the previous frames' samples, `Weier2016`), or a method registered with
      `register_method` (an `AbstractFoveationMethod`). Each method cites its paper
      (`Foveation().method.citation`); the options above that only the thesis's frame has
      (`fidelity`, budgets, tiles) are refused with a method that does not read them
      (`AbstractFoveationMethod.thesis_options`).
    """

    # Floats, or traced under jit (a new pair compiles nothing).
    fovea_deg: float | Array = eqx.field(converter=_angle, default=5.0)
    periphery_deg: float | Array = eqx.field(converter=_angle, default=10.0)
    spp: int = eqx.field(static=True, default=1)
    acuity: Callable[..., Any] = eqx.field(default_factory=_thesis_model)
    blocks: tuple[int, int] = eqx.field(static=True, default=(2, 4))
    rule: str = eqx.field(static=True, default="either")
    blur_sigma: float = eqx.field(static=True, default=1.0)
    blur_fovea: bool = eqx.field(static=True, default=False)
    eccentricity: str = eqx.field(static=True, default="angle")
    eye_display_mm: float = eqx.field(static=True, default=24.0)
    pixel_pitch_mm: float | None = eqx.field(static=True, default=None)
    ray_budget: int | None = eqx.field(static=True, default=None)
    max_periphery_deg: float | None = eqx.field(static=True, default=None)
    fovea_tile_deg: float | None = eqx.field(static=True, default=None)
    grid_tile: bool = eqx.field(static=True, default=False)
    fidelity: tuple | None = eqx.field(static=True, default=None)
    # The method (`fovjax.foveate.METHODS`; default the thesis's): a name or a method instance.
    method: AbstractFoveationMethod = eqx.field(static=True, default="thesis", converter=as_method)

    def __check_init__(self):
        traced = isinstance(self.fovea_deg, Tracer) or isinstance(self.periphery_deg, Tracer)
        if not traced:
            self._check_thresholds()
        self._check_options()

    def _check_thresholds(self):
        if not (math.isfinite(self.fovea_deg) and self.fovea_deg >= 0):
            raise ValueError(f"Foveation.fovea_deg must be a finite angle >= 0, got {self.fovea_deg}")
        if not (math.isfinite(self.periphery_deg) and self.periphery_deg >= self.fovea_deg):
            raise ValueError(
                f"Foveation.periphery_deg must be >= fovea_deg ({self.fovea_deg}), got {self.periphery_deg}"
            )
        if self.max_periphery_deg is not None and not (
            math.isfinite(self.max_periphery_deg) and self.max_periphery_deg >= self.periphery_deg
        ):
            raise ValueError(
                f"Foveation.max_periphery_deg must be >= periphery_deg ({self.periphery_deg}), "
                f"got {self.max_periphery_deg}"
            )

    def _check_options(self):
        n = int(round(self.spp**0.5))
        if self.spp < 1 or n * n != self.spp:
            raise ValueError(f"Foveation.spp must be a positive square (1, 4, 9, 16, ...), got {self.spp}")
        if len(self.blocks) != 2 or any(int(b) < 1 for b in self.blocks):
            raise ValueError(f"Foveation.blocks must be two positive block edges, got {self.blocks}")
        if self.blocks[1] % self.blocks[0]:
            raise ValueError(
                f"Foveation.blocks: the outside block {self.blocks[1]} must be a multiple of {self.blocks[0]}"
            )
        if self.rule not in SAMPLING_RULES:
            raise ValueError(f"Foveation.rule must be one of {SAMPLING_RULES}, got {self.rule!r}")
        if self.eccentricity not in ECCENTRICITY_MODES:
            raise ValueError(
                f"Foveation.eccentricity must be one of {ECCENTRICITY_MODES}, got {self.eccentricity!r}"
            )
        if not self.blur_sigma > 0:
            raise ValueError(f"Foveation.blur_sigma must be > 0, got {self.blur_sigma}")
        if not callable(self.acuity):
            raise ValueError(f"Foveation.acuity must be callable (ω -> probability), got {self.acuity!r}")
        if self.fovea_tile_deg is not None and not (
            math.isfinite(self.fovea_tile_deg) and self.fovea_tile_deg > 0
        ):
            raise ValueError(
                f"Foveation.fovea_tile_deg must be None or a finite angle > 0, got {self.fovea_tile_deg}"
            )
        if self.fidelity is not None and not (
            isinstance(self.fidelity, tuple | list)
            and len(self.fidelity) == 3
            and all(isinstance(f, Fidelity) for f in self.fidelity)
        ):
            raise ValueError(
                "Foveation.fidelity must be None or three Fidelity (fovea, periphery, outside), "
                f"got {self.fidelity!r}"
            )
        if self.fidelity is not None:  # a region never takes more samples than the frame
            for name, f in zip(REGION_NAMES, self.fidelity, strict=True):
                if f.spp is not None and f.spp > self.spp:
                    raise ValueError(
                        f"Foveation.fidelity ({name}): spp {f.spp} exceeds the frame's spp {self.spp} "
                        f"(expected 1..{self.spp})"
                    )
        if self.ray_budget is not None and self.ray_budget < 1:
            raise ValueError(f"Foveation.ray_budget must be positive, got {self.ray_budget}")
        # The thesis's frame's options that the method's frame does not read (`thesis_options`).
        thesis_only = {
            "fidelity": self.fidelity,
            "ray_budget": self.ray_budget,
            "max_periphery_deg": self.max_periphery_deg,
            "fovea_tile_deg": self.fovea_tile_deg,
            "grid_tile": self.grid_tile or None,
        }
        given = [k for k, v in thesis_only.items() if v is not None and k not in self.method.thesis_options]
        if given:
            raise ValueError(
                f"Foveation: {', '.join(given)} apply to the thesis's method only, not to "
                f"method {self.method.name!r} (expected None)"
            )

    @classmethod
    def thesis(cls, pair: int | tuple[float, float] = 0, **kwargs: Any) -> Foveation:
        """One of the thesis's pairs: an index into `THESIS_PAIRS` or a (fovea, periphery) pair
        (`kwargs`: the other fields, fovjax's defaults otherwise). The thesis's whole
        configuration, its sampling, regions, blur and shading with the pair, is
        `fovjax.foveate.thesis_preset`."""
        fovea, periphery = THESIS_PAIRS[pair] if isinstance(pair, int) else pair
        return cls(fovea_deg=float(fovea), periphery_deg=float(periphery), **kwargs)

    @classmethod
    def thesis_measured(
        cls, pair: int | tuple[float, float] = 0, *, eye_height: int = 1024, **kwargs: Any
    ) -> Foveation:
        """A thesis pair as the thesis measured it (Table 2): rule "thesis-measured" with the
        planar eccentricity (eq. 4-5, D = 24 mm) at the pitch `thesis_pixel_pitch_mm` gives
        for `eye_height` rows (the SX111's 64° spread over them: 16 pixels per degree at
        1024 rows)."""
        from ._eccentricity import thesis_pixel_pitch_mm

        kwargs.setdefault("rule", "thesis-measured")
        kwargs.setdefault("eccentricity", "planar")
        kwargs.setdefault("eye_display_mm", 24.0)
        pitch = thesis_pixel_pitch_mm(eye_height, eye_display_mm=kwargs["eye_display_mm"])
        kwargs.setdefault("pixel_pitch_mm", pitch)
        return cls.thesis(pair, **kwargs)

    def probability(self, omega: Real[ArrayLike, "*batch"]) -> Float[Array, "*batch"]:
        """P(ω): 1 in the fovea, the acuity model beyond (thesis eq. 7), clipped to [0, 1]."""
        omega = jnp.asarray(omega, jnp.float32)
        p = jnp.clip(jnp.asarray(self.acuity(omega), jnp.float32), 0.0, 1.0)
        return jnp.where(omega <= self.fovea_deg, 1.0, p)


# The thesis's shading (`thesis_preset`): Blinn–Phong with the shadow payload n·l on the specular
# (§4.4.3), reflections cut below a luminance of 0.01 of their weight (§2.5.2, the OptiX SDK's
# `phong.h` threshold), OptiX's max trace depth 5 (Fig 49) and "bg color" (Fig 51).
THESIS_MIN_CONTRIBUTION = 0.01
THESIS_MAX_DEPTH = 5
# The user study's samples per pixel (§5.2); Tables 2-5 also take 1, 9 and 16.
THESIS_SPP = 4


class ThesisPreset(NamedTuple):
    """The thesis's whole configuration (`thesis_preset`): the foveation and the render config
    a frame takes (`render_foveated(..., foveation=preset.foveation, config=preset.config)`;
    the full reference frame: `render_stereo(..., spp=preset.foveation.spp,
    config=preset.config)`)."""

    foveation: Foveation
    config: RenderConfig


def thesis_preset(
    pair: int | tuple[float, float] = 0,
    *,
    spp: int = THESIS_SPP,
    eye_height: int = 1024,
    config: RenderConfig | None = None,
) -> ThesisPreset:
    """The thesis's configuration in one switch (`fovjax render --preset thesis`); each item,
    with the thesis's line it comes from, is tabled in docs/thesis.md ("The thesis's
    configuration"):

    - regions by the planar eccentricity (eq. 4-5, D = 24 mm) at the SX111's 16 pixels per
      degree scaled to `eye_height` rows (`thesis_pixel_pitch_mm`), and the sampling Table 2
      implies, rule "thesis-measured" (`Foveation.thesis_measured`);
    - blocks of 2 and 4 pixels, the 5×5 Gaussian over every pixel (`blur_fovea=True`, §4.5: no
      sharp fovea, no blend band; σ = 1 pixel is fovjax's, the thesis names none);
    - the thesis's shading (`config`): Blinn–Phong with the specular times the shadow ray's
      payload n·l (`specular_payload`, §4.4.3), the contribution cut-off 0.01
      (`min_contribution`, §2.5.2), max depth 5 (Fig 49), misses in "bg color" (0.34, 0.55,
      0.85) (Fig 51; the thesis's miss program samples an HDR environment map that fovjax does
      not ship: pass one with `scene_arrays(..., envmap=)`);
    - `spp` samples per pixel (4, the user study's, §5.2).

    Args:
        pair: an index into `THESIS_PAIRS` or a (fovea, periphery) pair in degrees.
        spp: samples per pixel (a square).
        eye_height: rows per eye (the pixel pitch scales with them so that a threshold covers
            the thesis's share of the display at any resolution).
        config: the render config whose other settings (ray backend, integrator, chunk sizes)
            the thesis's shading is put on (None: `RenderConfig()`'s).

    Returns:
        `ThesisPreset(foveation, config)`.
    """
    base = RenderConfig() if config is None else config
    shading = dataclasses.replace(
        base,
        max_depth=THESIS_MAX_DEPTH,
        background=THESIS_BACKGROUND,
        specular="blinn-phong",
        specular_payload=True,
        min_contribution=THESIS_MIN_CONTRIBUTION,
    )
    foveation = Foveation.thesis_measured(
        pair, spp=spp, eye_height=eye_height, blocks=(2, 4), blur_fovea=True, blur_sigma=1.0
    )
    return ThesisPreset(foveation, shading)


def with_regions(foveation: Foveation, reading: str, eye_height: int) -> Foveation:
    """`foveation` with its regions measured by `reading`:

    - "angle" (fovjax's default): the exact angle between a pixel's ray and the gaze ray, on the
      rig's own field of view (90° horizontal per eye by default, the thesis's cameras);
    - "thesis": the reading behind the thesis's Table 2 (`Foveation.thesis_measured`'s regions
      without its rule): the planar formula (eq. 4-5, D = 24 mm) at the pitch of the SX111's
      16 pixels per degree, scaled to `eye_height` rows (`thesis_pixel_pitch_mm`). On the 90°
      rig a threshold then covers about twice the pixels "angle" gives it, so a thesis level
      such as 12.5°/25° is like-for-like with the thesis's participants only under "thesis".

    The sampling rule, thresholds and everything else stay `foveation`'s."""
    from ._eccentricity import thesis_pixel_pitch_mm

    if reading not in REGION_READINGS:
        raise ValueError(f"regions must be one of {REGION_READINGS}, got {reading!r}")
    if reading == "angle":
        return dataclasses.replace(foveation, eccentricity="angle")
    pitch = thesis_pixel_pitch_mm(int(eye_height), eye_display_mm=24.0)
    return dataclasses.replace(foveation, eccentricity="planar", eye_display_mm=24.0, pixel_pitch_mm=pitch)


def check_gaze(gaze: GazeLike, name: str = "gaze") -> Float[np.ndarray, "2 2"]:
    """Per-eye gaze in normalised display coordinates (x right, y down, (0, 0) top-left of each
    eye's display), shape (2, 2) for (left, right). Raises on NaN or off-screen values."""
    g = np.asarray(gaze, np.float64)
    if g.shape == (4,):
        g = g.reshape(2, 2)
    if g.shape != (2, 2):
        raise ValueError(
            f"{name} must be ((lx, ly), (rx, ry)) in normalised display coordinates, got shape {g.shape}"
        )
    if not np.isfinite(g).all():
        raise ValueError(
            f"{name} contains NaN or inf: {g.tolist()} (the tracking layer must hold or drop bad samples)"
        )
    if (g < 0).any() or (g > 1).any():
        eye = ["left", "right"][int(np.argwhere((g < 0) | (g > 1))[0, 0])]
        raise ValueError(
            f"{name}: the {eye} eye's point {g.tolist()} is off-screen (each coordinate must be in [0, 1])"
        )
    return g.astype(np.float32)
