"""The foveated frame's parts that only the packages built on `fovjax.foveate` (eval, the
session, the viewer), the tests and a foveation method's frame program use: the pure frame
program, the static ray budget, the split of a foveation into program and tables, the sampling
and reconstruction steps, and what a method's frame is built from (`FrameInputs`,
`eccentricities`, `trace_pixels`). Not part of the stable public API
(tests/test_architecture.py keeps the top level and the command line from importing it)."""

from ._budget import plan_budget as plan_budget
from ._config import program_fidelity as program_fidelity
from ._eccentricity import full_eccentricity as full_eccentricity
from ._fill import fill_and_blur_pixels as fill_and_blur_pixels
from ._fill import resolve as resolve
from ._frame import FoveatedOutputs as FoveatedOutputs
from ._frame import FrameOptions as FrameOptions
from ._frame import eccentricities as eccentricities
from ._frame import foveated_stereo as foveated_stereo
from ._methods import THESIS_OPTIONS as THESIS_OPTIONS
from ._methods import FrameInputs as FrameInputs
from ._methods._sparse import TracedPixels as TracedPixels
from ._methods._sparse import trace_pixels as trace_pixels
from ._renderer import _budget_for as budget_for
from ._sampling import MANDATORY as MANDATORY
from ._sampling import OPTIONAL as OPTIONAL
from ._sampling import SKIPPED as SKIPPED
from ._sampling import compaction_order as compaction_order
from ._sampling import sample_classes as sample_classes
from ._sampling import subsample_rank as subsample_rank
from ._sampling import top_left as top_left

__all__ = [
    "plan_budget",
    "program_fidelity",
    "fill_and_blur_pixels",
    "resolve",
    "foveated_stereo",
    "FrameOptions",
    "FoveatedOutputs",
    "eccentricities",
    "THESIS_OPTIONS",
    "FrameInputs",
    "TracedPixels",
    "trace_pixels",
    "MANDATORY",
    "OPTIONAL",
    "SKIPPED",
    "compaction_order",
    "sample_classes",
    "subsample_rank",
    "top_left",
    "budget_for",
    "full_eccentricity",
]
