"""The session loop: a sequence of foveated stereo frames driven by gaze and head-pose sources
(`fovjax session`, and the library call behind it).

- `run_session(renderer, gaze=..., head=..., session=SessionConfig(frames=, fps=, clock=...),
  out=SessionOutput(...))` renders the frames, following the `fovjax.devices.GazeTracker`'s
  widening, and returns a `SessionResult` (the frames' `SessionFrame` rows and a summary;
  optionally images, a video and a log);
- `full_eccentricity(rig, foveation)`: the largest eccentricity any pixel of the display can
  have (a widening of 1 makes every pixel foveal);
- `CLOCKS` ("virtual", "wall"), `LIVE_SCHEMES` (the source specs that are live devices),
  `VirtualClock`.

It builds on the core packages (devices, render, foveate, scene, files) and none of them
imports it; the command line and the viewer sit on top of it.
"""

from ._loop import CLOCKS as CLOCKS
from ._loop import LIVE_SCHEMES as LIVE_SCHEMES
from ._loop import SessionConfig as SessionConfig
from ._loop import SessionFrame as SessionFrame
from ._loop import SessionOutput as SessionOutput
from ._loop import SessionResult as SessionResult
from ._loop import VirtualClock as VirtualClock
from ._loop import full_eccentricity as full_eccentricity
from ._loop import run_session as run_session

__all__ = [
    "CLOCKS",
    "LIVE_SCHEMES",
    "SessionConfig",
    "SessionFrame",
    "SessionOutput",
    "SessionResult",
    "VirtualClock",
    "full_eccentricity",
    "run_session",
]
