"""The foveation methods fovjax ships (`Foveation(method=...)`), each with its paper.

A method is an `AbstractFoveationMethod`: an `eqx.Module` of the paper's parameters (hashable:
part of the compiled program's configuration, so another value compiles another program),
registered by name; the frame's gaze, head pose, key and fovea threshold stay traced.
`Foveation(method="weier2016")` takes a method's defaults;
`Foveation(method=Weier2016(retrace_tolerance=0.05))` sets its parameters. The frame programs
are in the sibling modules, imported when a frame is traced (they import `Foveation`, which
imports this module).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from ._base import THESIS_OPTIONS, AbstractFoveationMethod, Citation, FrameInputs, History
from ._registry import register_method

if TYPE_CHECKING:
    from .._frame import FrameOptions
    from .._renderer import FoveatedRenderer


@register_method
class Thesis(AbstractFoveationMethod):
    """The thesis's method (fovjax's default, every option of `Foveation` applies): regions by
    eccentricity, blocks whose top-left is traced plus samples drawn with the acuity model's
    P(ω), fill from the block's top-left and a Gaussian blur outside the fovea."""

    name = "thesis"
    citation = Citation(
        authors="Andreas Polychronakis",
        year=2020,
        title="Real-Time Foveated Rendering In Virtual Reality For Ray-tracing",
        venue="Diploma thesis, Electrical and Computer Engineering, Technical University of Crete",
        doi=None,
    )
    thesis_options = frozenset(THESIS_OPTIONS)
    batches = True

    @property
    def entry(self) -> str:
        return "foveated"

    def frame(self, inputs: FrameInputs, history: History, *, options: FrameOptions):
        """`fovjax.foveate.internal.foveated_stereo` of `inputs` (no history)."""
        from .._frame import foveated_stereo

        return foveated_stereo(*inputs, options=options), None, None

    def frame_options(
        self, renderer: FoveatedRenderer, *, jitter: bool, diagnostics: tuple[str, ...]
    ) -> FrameOptions:
        """The renderer's samples per pixel, render config, ray-slot budget and tiles."""
        from .._frame import FrameOptions

        return FrameOptions(
            spp=renderer.foveation.spp,
            jitter=jitter,
            config=renderer.config,
            budget=renderer.budget,
            tile=renderer.tile,
            grid=renderer.grid,
            diagnostics=diagnostics,
        )


@register_method
class Guenter2012(AbstractFoveationMethod):
    """Guenter et al. 2012: three nested eccentricity layers around the gaze, rendered at
    decreasing resolution, magnified to the display's and blended.

    Per eye and frame (fovjax's reading for a ray tracer, `fovjax.foveate._methods._guenter`):
    layer 1 (the fovea, ω ≤ `Foveation.fovea_deg`) at every pixel; layer 2 (ω ≤
    `periphery_deg`) at every `strides[0]`-th pixel of each row and column; layer 3 (the whole
    display) at every `strides[1]`-th. A layer traces the pixels of its grid that its
    bilinear magnification needs; a pixel on several grids is traced once (the same ray: it is
    one sample of each). Each layer is magnified by bilinear interpolation between its grid
    pixels and the layers are blended by eccentricity: across `blend_deg` beyond each layer's
    radius (a smoothstep) from the finer layer to the coarser, so a coarser layer shows alone
    only where the rule allows it. No blur.

    The paper's layer-size rule (`layer_radii`): its acuity model, the minimum angle of
    resolution growing linearly with eccentricity, MAR(ω) = ω0 + m·ω, with the slope the paper
    measured, 1.32-1.65 arc minutes per degree (`slope_arcmin_per_deg`, default 1.32, the
    conservative end: larger layers); a layer whose pixels are s display pixels wide may start
    where MAR reaches s display pixels, ω = (s·p − ω0) / m, p the display pixel's angle at the
    centre, with ω0 = p (fovjax's choice: the inner layer is the display at its native
    sharpness). `Foveation.fovea_deg` and `periphery_deg` are the layer radii, traced, so a
    threshold sweep compares radii; `layer_radii` gives the paper's.

    Attributes:
        strides: the middle and outer layers' sampling factors in display pixels (fovjax's
            choice, (2, 4): the thesis's block edges, so the two methods trace comparable grids;
            the paper chooses them with the radii by minimising its cost model).
        blend_deg: width of the blend at a layer's edge (fovjax's choice, 1°: the thesis's
            fovea blend; the paper blends "smoothly" over a band it sizes itself).
        slope_arcmin_per_deg: m of the acuity model (the paper's 1.32-1.65).

    Not modelled: the paper's temporal antialiasing of the coarse layers (jitter and
    reprojection) and its half-rate update of the outer layers.
    """

    strides: tuple[int, int] = (2, 4)
    blend_deg: float = 1.0
    slope_arcmin_per_deg: float = 1.32

    name = "guenter2012"
    citation = Citation(
        authors="Brian Guenter, Mark Finch, Steven Drucker, Desney Tan, John Snyder",
        year=2012,
        title="Foveated 3D Graphics",
        venue="ACM Transactions on Graphics 31(6):164 (SIGGRAPH Asia 2012)",
        doi="10.1145/2366145.2366183",
    )

    def __check_init__(self):
        s = self.strides
        if not (
            isinstance(s, tuple)
            and len(s) == 2
            and all(isinstance(x, int) and not isinstance(x, bool) and x >= 1 for x in s)
            and s[0] <= s[1]
        ):
            raise ValueError(
                f"Guenter2012.strides must be two integers 1 <= middle <= outer, got {self.strides!r}"
            )
        for name in ("blend_deg", "slope_arcmin_per_deg"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not (math.isfinite(v) and v > 0):
                raise ValueError(f"Guenter2012.{name} must be a finite number > 0, got {v!r}")

    def layer_radii(self, pixel_deg: float) -> tuple[float, float]:
        """The paper's rule: the (inner, middle) layers' radii in degrees on a display whose
        pixel subtends `pixel_deg` at its centre (see the class docstring)."""
        if not (math.isfinite(pixel_deg) and pixel_deg > 0):
            raise ValueError(f"Guenter2012.layer_radii: pixel_deg must be > 0, got {pixel_deg!r}")
        m = self.slope_arcmin_per_deg / 60.0
        inner, middle = (float((s * pixel_deg - pixel_deg) / m) for s in self.strides)
        return inner, middle

    def frame(self, inputs: FrameInputs, history: History, *, options: FrameOptions):
        """`fovjax.foveate._methods._guenter.guenter_stereo` (no history)."""
        from ._guenter import guenter_stereo

        return guenter_stereo(self, inputs, history, options=options)


@register_method
class Patney2016(AbstractFoveationMethod):
    """Patney et al. 2016: shading rate falling with eccentricity, a contrast-preserving
    pre-filter of the coarse periphery and temporal antialiasing (temporal: a frame blends the
    history of the frames before it).

    Per eye and frame (fovjax's reading for a ray tracer, `fovjax.foveate._methods._patney`):

    - coarse sampling: as the paper's coarse pixel shading, one shade per s×s block held over the
      block; s is 1 in the fovea (ω ≤ `Foveation.fovea_deg`), `strides[0]` up to
      `periphery_deg` and `strides[1]` beyond, the layers blended by eccentricity over
      `blend_deg` (a smoothstep, as `Guenter2012`); a block's top-left pixel is traced (whole,
      every sub-sample) where its block shows;
    - temporal antialiasing on the held image: the history, clamped to this frame's 3×3
      neighbourhood mean ± `clip_gamma` standard deviations (variance clipping; the box is
      widened to contain the pixel itself, so a still image is a fixed point), is blended with
      weight 1 − `taa_alpha`; after a reset the frame is shown as traced;
    - the pre-filter (the paper's post-process, `contrast_preserving_filter`), outside the
      fovea only: a Gaussian blur of σ = `blur_per_stride`·s pixels, then the local contrast
      the blur removed restored: deviations from the local mean scaled by the ratio of the
      unblurred to the blurred local standard deviation of luminance (Gaussian windows of
      `window_per_sigma`·σ, the gain within [1, `max_gain`]).

    Attributes:
        strides: the middle and outer shading rates in display pixels (fovjax's choice,
            (2, 4): coarse pixels of 2×2 and 4×4; the paper's exact rates could not be read
            here).
        blend_deg: width of the blend between rates (fovjax's choice, 1°: the thesis's blend).
        blur_per_stride: the blur's σ per display pixel of the shading rate (fovjax's choice,
            0.5: Albert et al. 2017, "Latency Requirements for Foveated Rendering in Virtual
            Reality", map a blur radius r to this method's 2r×2r coarse shading rate).
        window_per_sigma: the contrast window's σ per blur σ (fovjax's choice, 2: the scale of
            the detail the blur removes; a smaller window is cheaper and closer to the full
            render by FLIP and JOD, and keeps less of the periphery's contrast:
            `benchmarks/patney_window.py`).
        max_gain: the largest contrast gain (fovjax's choice, 4: bounds the amplification of
            noise where the blur left almost no contrast).
        taa_alpha: the weight of this frame in the temporal blend (fovjax's choice, 0.1: the
            exponential average's usual weight in temporal antialiasing).
        clip_gamma: the variance clip's width in standard deviations (fovjax's choice, 1).

    Not modelled: the paper's pre-filtered shading terms (texture mips, LEAN normal maps,
    variance shadow maps), its reprojection of the history by motion vectors (the history is
    blended in screen space; head motion is limited by the variance clip only), and its
    saccade-aware, eccentricity-varying temporal weights.
    """

    strides: tuple[int, int] = (2, 4)
    blend_deg: float = 1.0
    blur_per_stride: float = 0.5
    window_per_sigma: float = 2.0
    max_gain: float = 4.0
    taa_alpha: float = 0.1
    clip_gamma: float = 1.0

    name = "patney2016"
    temporal = True
    citation = Citation(
        authors="Anjul Patney, Marco Salvi, Joohwan Kim, Anton Kaplanyan, Chris Wyman, Nir Benty, "
        "David Luebke, Aaron Lefohn",
        year=2016,
        title="Towards Foveated Rendering for Gaze-Tracked Virtual Reality",
        venue="ACM Transactions on Graphics 35(6) (SIGGRAPH Asia 2016)",
        doi="10.1145/2980179.2980246",
    )

    def __check_init__(self):
        s = self.strides
        if not (
            isinstance(s, tuple)
            and len(s) == 2
            and all(isinstance(x, int) and not isinstance(x, bool) and x >= 1 for x in s)
            and s[0] <= s[1]
        ):
            raise ValueError(
                f"Patney2016.strides must be two integers 1 <= middle <= outer, got {self.strides!r}"
            )
        for name in ("blend_deg", "blur_per_stride", "window_per_sigma", "clip_gamma"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not (math.isfinite(v) and v > 0):
                raise ValueError(f"Patney2016.{name} must be a finite number > 0, got {v!r}")
        g = self.max_gain
        if isinstance(g, bool) or not isinstance(g, int | float) or not (math.isfinite(g) and g >= 1):
            raise ValueError(f"Patney2016.max_gain must be a finite number >= 1, got {g!r}")
        a = self.taa_alpha
        if isinstance(a, bool) or not isinstance(a, int | float) or not (0 < a <= 1):
            raise ValueError(f"Patney2016.taa_alpha must be a number in (0, 1], got {a!r}")

    def frame(self, inputs: FrameInputs, history: History, *, options: FrameOptions):
        """`fovjax.foveate._methods._patney.patney_stereo`."""
        from ._patney import patney_stereo

        return patney_stereo(self, inputs, history, options=options)

    def empty_history(self, eye_height: int, eye_width: int) -> History:
        """No pixel holds a history (`TaaHistory`): the next frame is shown as traced."""
        from ._patney import empty_history

        return empty_history(eye_height, eye_width)


WIDENED_FOVEA = ("reproject", "trace")


@register_method
class Weier2016(AbstractFoveationMethod):
    """Weier et al. 2016: sparse ray tracing by eccentricity plus reprojection of the previous
    frame's shaded samples (temporal: a frame reuses the history of the frames before it).

    Per pixel and frame (fovjax's reading, `fovjax.foveate._methods._weier`):

    - the previous frame's samples are kept as (colour, world-space hit point) per pixel and
      forward-projected into this frame's cameras (head and gaze motion alike: the gaze only
      moves the fovea); where several land in one pixel the nearest wins (a depth test);
    - a reprojected sample farther than `(1 + retrace_tolerance)` times the nearest reprojected
      sample around it (its 3×3 neighbourhood) is taken as background showing through a gap of
      a nearer surface and rejected;
    - traced this frame: every pixel of the fovea (ω ≤ `fovea_deg`), every pixel that received
      no valid sample (disocclusions, newly visible borders, rejected samples; after a reset
      that is every pixel: the first frame is the full frame), and any other pixel with the
      foveation's P(ω) (`Foveation.acuity`; the paper's linear fall-off is
      `fovjax.foveate.LinearFalloff`), which refreshes the history where shading changes;
    - the image is the traced samples where traced and the reprojected ones elsewhere: every
      pixel holds a sample, so the fill and blur of the thesis's method are not needed.

    Attributes:
        retrace_tolerance: the relative depth step above which a reprojected sample is rejected
            (fovjax's choice, 0.1: the paper schedules "possible errors introduced by this
            reprojection" for resampling from a coarse geometry it rebuilds from a G-buffer; the
            value it uses could not be read here).
        widened_fovea: what the gaze tracker's fallback does to this method when tracking
            degrades or is lost (`fovjax.devices.widen_thresholds`: the fovea widens towards the
            whole display, at full quality). The fallback is fovjax's (the thesis keeps each
            eye's last gaze point whose quality code passes, its Figure 45, and has no
            widening); how Weier's method meets it is fovjax's choice too. "reproject"
            (default): the widening adds no traced pixels; the thresholds stay the configured
            ones around the held gaze, and the full quality the widening asks for comes from
            the history: every pixel shows a full-resolution sample, reprojected where the
            history covers it and traced where not (after the reset at a loss the first frame
            traces every pixel). The widening exists for the thesis's method's sparse, filled
            and blurred periphery, which this method does not have. "trace": the widened fovea
            is traced whole as the fovea (a lost tracker then traces the whole display every
            frame, as the thesis's method does under the fallback).

    A pixel's samples are traced together (every sub-sample at the frame's spp); its world
    point is the hit of its first sub-sample's ray (kept by the native integrator from the ray
    it traces; elsewhere a closest-hit query over the traced pixels). fovjax's choice: the
    paper's coarse support image is not built, because every pixel without a valid sample is
    traced.
    """

    retrace_tolerance: float = 0.1
    widened_fovea: str = "reproject"

    name = "weier2016"
    temporal = True
    citation = Citation(
        authors="Martin Weier, Thorsten Roth, Ernst Kruijff, André Hinkenjann, Arsène Pérard-Gayot, "
        "Philipp Slusallek, Yongmin Li",
        year=2016,
        title="Foveated Real-Time Ray Tracing for Head-Mounted Displays",
        venue="Computer Graphics Forum 35(7):289-298 (Pacific Graphics 2016)",
        doi="10.1111/cgf.13026",
    )

    def __check_init__(self):
        tol = self.retrace_tolerance
        if isinstance(tol, bool) or not isinstance(tol, int | float) or not (math.isfinite(tol) and tol > 0):
            raise ValueError(f"Weier2016.retrace_tolerance must be a finite number > 0, got {tol!r}")
        if self.widened_fovea not in WIDENED_FOVEA:
            raise ValueError(
                f"Weier2016.widened_fovea must be one of {', '.join(map(repr, WIDENED_FOVEA))}, "
                f"got {self.widened_fovea!r}"
            )

    @property
    def widens_fovea(self) -> bool:
        """Whether the tracking fallback's widened thresholds are this method's frame thresholds."""
        return self.widened_fovea == "trace"

    def frame(self, inputs: FrameInputs, history: History, *, options: FrameOptions):
        """`fovjax.foveate._methods._weier.weier_stereo`."""
        from ._weier import weier_stereo

        return weier_stereo(self, inputs, history, options=options)

    def empty_history(self, eye_height: int, eye_width: int) -> History:
        """No pixel holds a sample (`WeierHistory`): the next frame traces every pixel."""
        from ._weier import empty_history

        return empty_history(eye_height, eye_width)
