"""The live foveated viewer (`fovjax view`): a local web server renders foveated stereo frames
for the newest gaze -- the mouse over either eye, or any gaze source -- and streams them to a
page in the browser over a WebSocket, with an overlay of frame rate, stage times, rays and the
gaze-to-display latency. Needs the 'view' extra (aiohttp).

- `LiveRenderer`: the live state and one frame at a time (`render_next`); `MAX_THRESHOLD_DEG`
  the largest fovea or periphery radius it takes;
- `Viewer`: the aiohttp server around it (`start`, `stop`, `url`);
- `StudyServer`: the user-study player's server (`fovjax view --study`): pre-rendered clips,
  the trials' sequences timed on the page, answers handed to the study as they are given;
- `XRViewer`, `XRRenderer`: the headset's server and renderer (`fovjax view --xr`): a WebXR
  page sends the headset pose and both eyes' views, frames are rendered for them and drawn
  reprojected to the newest pose; `XRPose`, `XRView`, `xr_stereo`, `XRStereo`: from a WebXR
  frame's views to the rig that renders them; `parse_xr_message`: that page's protocol;
- `binocular_gaze`: both eyes' gaze from one eye's, through the rig's geometry;
- `parse_message`, `MessageError`, `ACTIONS`: the page protocol and its validation.
"""

from ._gaze import binocular_gaze as binocular_gaze
from ._protocol import ACTIONS as ACTIONS
from ._protocol import MAX_MESSAGE_BYTES as MAX_MESSAGE_BYTES
from ._protocol import MessageError as MessageError
from ._protocol import parse_message as parse_message
from ._renderer import MAX_THRESHOLD_DEG as MAX_THRESHOLD_DEG
from ._renderer import LiveRenderer as LiveRenderer
from ._renderer import RenderedFrame as RenderedFrame
from ._renderer import encode_jpeg as encode_jpeg
from ._server import Viewer as Viewer
from ._server import is_loopback as is_loopback
from ._study import StudyServer as StudyServer
from ._xr_geometry import XRPose as XRPose
from ._xr_geometry import XRStereo as XRStereo
from ._xr_geometry import XRView as XRView
from ._xr_geometry import xr_stereo as xr_stereo
from ._xr_protocol import parse_xr_message as parse_xr_message
from ._xr_renderer import XRRenderer as XRRenderer
from ._xr_server import XRViewer as XRViewer

__all__ = [
    "binocular_gaze",
    "ACTIONS",
    "MAX_MESSAGE_BYTES",
    "MessageError",
    "parse_message",
    "MAX_THRESHOLD_DEG",
    "LiveRenderer",
    "RenderedFrame",
    "encode_jpeg",
    "Viewer",
    "is_loopback",
    "StudyServer",
    "XRPose",
    "XRStereo",
    "XRView",
    "xr_stereo",
    "parse_xr_message",
    "XRRenderer",
    "XRViewer",
]
