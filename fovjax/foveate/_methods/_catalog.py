"""The foveation methods a `Foveation` can use (`Foveation(method=...)`), each with its paper.

A method is a frozen dataclass of the paper's parameters (hashable: part of the compiled
program's configuration, so another value compiles another program); the frame's gaze, head
pose, key and fovea threshold stay traced. `Foveation(method="weier2016")` takes a method's
defaults; `Foveation(method=Weier2016(retrace_tolerance=0.05))` sets its parameters. The frame
programs are in the sibling modules (imported only when a frame is rendered).
"""

from __future__ import annotations

import dataclasses
import math


@dataclasses.dataclass(frozen=True)
class Citation:
    """A method's paper. The DOI is taken only from a source that could be read (the thesis's
    bibliography or the publisher's pages); None where none was."""

    authors: str
    year: int
    title: str
    venue: str
    doi: str | None

    def __str__(self) -> str:
        doi = f" doi:{self.doi}" if self.doi else ""
        return f"{self.authors} ({self.year}). {self.title}. {self.venue}.{doi}"


@dataclasses.dataclass(frozen=True)
class Thesis:
    """The thesis's method (fovjax's default, every option of `Foveation` applies): regions by
    eccentricity, blocks whose top-left is traced plus samples drawn with the acuity model's
    P(ω), fill from the block's top-left and a Gaussian blur outside the fovea."""

    name = "thesis"
    temporal = False
    citation = Citation(
        authors="Andreas Polychronakis",
        year=2020,
        title="Real-Time Foveated Rendering In Virtual Reality For Ray-tracing",
        venue="Diploma thesis, Electrical and Computer Engineering, Technical University of Crete",
        doi=None,
    )


@dataclasses.dataclass(frozen=True)
class Weier2016:
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

    Parameters:
        retrace_tolerance: the relative depth step above which a reprojected sample is rejected
            (fovjax's choice, 0.1: the paper schedules "possible errors introduced by this
            reprojection" for resampling from a coarse geometry it rebuilds from a G-buffer; the
            value it uses could not be read here).

    A pixel's samples are traced together (every sub-sample at the frame's spp); its world
    point is the hit of its first sub-sample's ray (a second closest-hit query over the traced
    pixels: the integrator returns radiance only). fovjax's choice: the paper's coarse support
    image is not built, because every pixel without a valid sample is traced.
    """

    retrace_tolerance: float = 0.1

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

    def __post_init__(self):
        tol = self.retrace_tolerance
        if isinstance(tol, bool) or not isinstance(tol, int | float) or not (math.isfinite(tol) and tol > 0):
            raise ValueError(f"Weier2016.retrace_tolerance must be a finite number > 0, got {tol!r}")


METHODS: dict[str, type] = {m.name: m for m in (Thesis, Weier2016)}
"""The methods by name (`Foveation(method=name)`, `fovjax compare --methods`)."""


def as_method(method):
    """A method instance from a name of `METHODS` or an instance of one of its classes."""
    if isinstance(method, str):
        if method not in METHODS:
            raise ValueError(f"Foveation.method must be one of {tuple(METHODS)}, got {method!r}")
        return METHODS[method]()
    if isinstance(method, tuple(METHODS.values())):
        return method
    raise ValueError(
        f"Foveation.method must be a name of {tuple(METHODS)} or an instance of "
        f"{', '.join(c.__name__ for c in METHODS.values())}, got {method!r}"
    )
