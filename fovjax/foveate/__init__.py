"""Foveated sampling: eccentricity, regions, acuity-driven sample selection, the static ray
budget, and the fill-and-blur reconstruction (thesis chapter 4, eq. 4-7, sections 4.4.1, 4.5).

`FoveatedRenderer(scene, rig, foveation, config)` prepares a scene once and renders frames,
batches and their full references for given gaze, head pose, key and thresholds (the way to
render frames in a loop); `render_foveated` renders one frame through a renderer made for it.
`check_gaze(gaze)` is the per-eye gaze check. `thesis_preset(pair)` is the thesis's whole
configuration (regions, sampling, blur, shading, depth, SPP) as a `ThesisPreset(foveation,
config)`. `Foveation(method=...)` chooses the foveation
method (`METHODS`: the thesis's, `Guenter2012`, `Patney2016`,
`Weier2016`), each with its paper's citation; a new method is an `AbstractFoveationMethod`
registered with `register_method`.
The frame program's parts (`foveated_stereo`, `budget_for`, `program_fidelity`, the sampling
steps) are in `fovjax.foveate.internal`, for the packages built on this one."""

from . import internal as internal
from ._api import FoveatedFrame as FoveatedFrame
from ._api import render_foveated as render_foveated
from ._config import ECCENTRICITY_MODES as ECCENTRICITY_MODES
from ._config import REGION_READINGS as REGION_READINGS
from ._config import SAMPLING_RULES as SAMPLING_RULES
from ._config import THESIS_PAIRS as THESIS_PAIRS
from ._config import Constant as Constant
from ._config import Fidelity as Fidelity
from ._config import Foveation as Foveation
from ._config import GazeLike as GazeLike
from ._config import LinearFalloff as LinearFalloff
from ._config import ThesisPreset as ThesisPreset
from ._config import check_gaze as check_gaze
from ._config import thesis_preset as thesis_preset
from ._config import with_regions as with_regions
from ._eccentricity import display_pixel_pitch_mm as display_pixel_pitch_mm
from ._eccentricity import eccentricity_angle as eccentricity_angle
from ._eccentricity import eccentricity_map as eccentricity_map
from ._eccentricity import eccentricity_planar as eccentricity_planar
from ._eccentricity import thesis_pixel_pitch_mm as thesis_pixel_pitch_mm
from ._fill import fill_and_blur as fill_and_blur
from ._frame import DEBUG_VIEW_DIAGNOSTICS as DEBUG_VIEW_DIAGNOSTICS
from ._frame import DIAGNOSTICS as DIAGNOSTICS
from ._frame import DiagnosticsLike as DiagnosticsLike
from ._methods import METHODS as METHODS
from ._methods import AbstractFoveationMethod as AbstractFoveationMethod
from ._methods import Citation as Citation
from ._methods import Guenter2012 as Guenter2012
from ._methods import Patney2016 as Patney2016
from ._methods import Thesis as Thesis
from ._methods import Weier2016 as Weier2016
from ._methods import method_label as method_label
from ._methods import register_method as register_method
from ._renderer import FoveatedRenderer as FoveatedRenderer
from ._sampling import FOVEA as FOVEA
from ._sampling import OUTSIDE as OUTSIDE
from ._sampling import PERIPHERY as PERIPHERY
from ._sampling import regions as regions

# Names that moved to `fovjax.foveate.internal` (the frame program's parts, for the packages
# built on this one and for tests): still reachable here, with a DeprecationWarning.
_MOVED_TO_INTERNAL = frozenset(internal.__all__)


def __getattr__(name: str):
    if name in _MOVED_TO_INTERNAL:
        import warnings

        warnings.warn(
            f"fovjax.foveate.{name} moved to fovjax.foveate.internal (the frame program's parts; "
            "not part of the stable API)",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(internal, name)
    raise AttributeError(f"module 'fovjax.foveate' has no attribute {name!r}")


__all__ = [
    "FoveatedFrame",
    "render_foveated",
    "ECCENTRICITY_MODES",
    "REGION_READINGS",
    "SAMPLING_RULES",
    "THESIS_PAIRS",
    "Constant",
    "Fidelity",
    "GazeLike",
    "Foveation",
    "LinearFalloff",
    "ThesisPreset",
    "check_gaze",
    "thesis_preset",
    "with_regions",
    "display_pixel_pitch_mm",
    "eccentricity_angle",
    "eccentricity_map",
    "eccentricity_planar",
    "thesis_pixel_pitch_mm",
    "fill_and_blur",
    "DEBUG_VIEW_DIAGNOSTICS",
    "DIAGNOSTICS",
    "DiagnosticsLike",
    "METHODS",
    "AbstractFoveationMethod",
    "Citation",
    "Guenter2012",
    "Patney2016",
    "Thesis",
    "Weier2016",
    "method_label",
    "register_method",
    "FoveatedRenderer",
    "FOVEA",
    "OUTSIDE",
    "PERIPHERY",
    "regions",
]
