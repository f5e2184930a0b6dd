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

One private module per case (`_corner_gaze.py`, ...); `_common.py` holds what they share and
`_run.py` runs them (`failure_cases`).
"""

from ._acuity_models import FITTED_MAR as FITTED_MAR
from ._acuity_models import AcuityTerms as AcuityTerms
from ._acuity_models import EqualBudget as EqualBudget
from ._acuity_models import acuity_models as acuity_models
from ._acuity_models import default_models as default_models
from ._acuity_models import equal_budget_foveations as equal_budget_foveations
from ._after_saccade import SaccadeTrial as SaccadeTrial
from ._after_saccade import after_saccade as after_saccade
from ._checkerboard import PursuitFlicker as PursuitFlicker
from ._checkerboard import checkerboard as checkerboard
from ._checkerboard import checkerboard_scene as checkerboard_scene
from ._common import CASES as CASES
from ._common import CENTRAL_DEG as CENTRAL_DEG
from ._common import SACCADE_POLICIES as SACCADE_POLICIES
from ._common import FailureCase as FailureCase
from ._common import FailureReport as FailureReport
from ._common import offset_gaze as offset_gaze
from ._corner_gaze import corner_gaze as corner_gaze
from ._high_spp import high_spp as high_spp
from ._run import failure_cases as failure_cases
from ._scanpath_flicker import scanpath_flicker as scanpath_flicker
from ._tracking_error import tracking_error as tracking_error
