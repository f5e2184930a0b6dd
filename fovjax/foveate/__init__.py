"""Foveated sampling: eccentricity, regions, acuity-driven sample selection, the static ray
budget, and the fill-and-blur reconstruction (thesis chapter 4, eq. 4-7, sections 4.4.1, 4.5).

`render_foveated` renders one frame. For batches (`fovjax.eval`): `foveated_stereo(scene_arrays,
bvh, rig, head_pose, gaze, key, foveation, *, spp, jitter, config, budget, diagnostics)` is the
pure frame it compiles (`diagnostics`: which per-pixel outputs of `DIAGNOSTICS` it returns),
`budget_for(rig, head_pose, foveation)` its static ray budget (slots for both eyes),
`check_gaze(gaze)` the per-eye gaze check."""

from ._api import FoveatedFrame as FoveatedFrame
from ._api import _budget_for
from ._api import render_foveated as render_foveated
from ._budget import plan_budget as plan_budget
from ._config import (
    ECCENTRICITY_MODES as ECCENTRICITY_MODES,
)
from ._config import (
    REGION_READINGS as REGION_READINGS,
)
from ._config import (
    SAMPLING_RULES as SAMPLING_RULES,
)
from ._config import (
    THESIS_PAIRS as THESIS_PAIRS,
)
from ._config import (
    Constant as Constant,
)
from ._config import (
    Fidelity as Fidelity,
)
from ._config import (
    Foveation as Foveation,
)
from ._config import (
    LinearFalloff as LinearFalloff,
)
from ._config import (
    check_gaze as check_gaze,
)
from ._config import (
    program_fidelity as program_fidelity,
)
from ._config import (
    with_regions as with_regions,
)
from ._eccentricity import (
    display_pixel_pitch_mm as display_pixel_pitch_mm,
)
from ._eccentricity import (
    eccentricity_angle as eccentricity_angle,
)
from ._eccentricity import (
    eccentricity_map as eccentricity_map,
)
from ._eccentricity import (
    eccentricity_planar as eccentricity_planar,
)
from ._eccentricity import (
    thesis_pixel_pitch_mm as thesis_pixel_pitch_mm,
)
from ._fill import fill_and_blur as fill_and_blur
from ._fill import fill_and_blur_pixels as fill_and_blur_pixels
from ._fill import resolve as resolve
from ._frame import DEBUG_VIEW_DIAGNOSTICS as DEBUG_VIEW_DIAGNOSTICS
from ._frame import DIAGNOSTICS as DIAGNOSTICS
from ._frame import foveated_stereo as foveated_stereo
from ._renderer import FoveatedRenderer as FoveatedRenderer
from ._sampling import (
    FOVEA as FOVEA,
)
from ._sampling import (
    MANDATORY as MANDATORY,
)
from ._sampling import (
    OPTIONAL as OPTIONAL,
)
from ._sampling import (
    OUTSIDE as OUTSIDE,
)
from ._sampling import (
    PERIPHERY as PERIPHERY,
)
from ._sampling import (
    SKIPPED as SKIPPED,
)
from ._sampling import (
    compaction_order as compaction_order,
)
from ._sampling import (
    regions as regions,
)
from ._sampling import (
    sample_classes as sample_classes,
)
from ._sampling import (
    subsample_rank as subsample_rank,
)
from ._sampling import (
    top_left as top_left,
)

budget_for = _budget_for  # public: the batches of fovjax.eval plan the same budget
