"""Messages between the headset page (`fovjax view --xr`, static/xr.js) and the server.

Page -> server (JSON text, at most `XR_MAX_MESSAGE_BYTES`; anything else is ignored with a logged
reason, never an error):

- ``{"type": "xr_pose", "t": T, "head": {"position": [3], "orientation": [4]}, "views": [V, V]}``
  every display frame of an immersive session: the viewer pose and both eyes' views, each
  ``{"eye": "left"|"right", "position": [3], "orientation": [4], "projection": [16],
  "viewport": [w, h]}`` (`XRView`, `local` reference space), T the frame's time on the page's
  clock (ms);
- ``{"type": "xr_state", "state": S, "reason": R}``: S "entered" (a session began; R the
  device), "ended" (back to the 2D page), "unsupported" (no WebXR or no immersive-vr here; R
  says which), "failed" (the session could not start; R the browser's error);
- ``{"type": "shown", "frame": N, "display_hz": F, "render_hz": F, "pose_age_ms": F,
  "reprojection_deg": F}``: frame N is in the headset (first drawn), with the page's
  measurements at that display frame (each may be null): the display rate, the rate new frames
  reach the display, the age of the head pose the frame was rendered for, and the angle between
  that pose and the pose it is displayed at;
- ``{"type": "key", "action": A}``: as the 2D viewer's (`parse_message`), head keys excepted.

Server -> page: as the 2D viewer's, the frame statistics carrying the rendered eye cameras
(``"xr"``: `XRStereo.page_json`), and ``{"type": "xr_info", ...}`` (the gaze and the scale).
"""

from __future__ import annotations

from ._protocol import MessageError, _number, json_object, parse_message
from ._xr_geometry import XRPose, XRView

XR_MAX_MESSAGE_BYTES = 4096
XR_STATES = ("entered", "ended", "unsupported", "failed")
MAX_REASON_CHARS = 300

_FIELDS = {
    "xr_pose": {"type", "t", "head", "views"},
    "xr_state": {"type", "state", "reason"},
    "shown": {"type", "frame", "display_hz", "render_hz", "pose_age_ms", "reprojection_deg"},
}
_VIEW_FIELDS = {"eye", "position", "orientation", "projection", "viewport"}
_SHOWN_RANGES = {
    "display_hz": (0.0, 1e4),
    "render_hz": (0.0, 1e4),
    "pose_age_ms": (-1e4, 1e7),  # a frame's predicted display time may lead the clock
    "reprojection_deg": (0.0, 180.0),
}


def _keys(obj, fields: set, what: str) -> None:
    if not isinstance(obj, dict):
        raise MessageError(f"{what} must be a JSON object, got {type(obj).__name__}")
    unknown, missing = set(obj) - fields, fields - set(obj)
    if unknown:
        raise MessageError(f"{what}: unknown keys {sorted(unknown)}")
    if missing:
        raise MessageError(f"{what}: missing keys {sorted(missing)}")


def _pose(msg: dict) -> XRPose:
    head = msg["head"]
    _keys(head, {"position", "orientation"}, "xr_pose head")
    views = msg["views"]
    if not isinstance(views, list) or len(views) != 2:
        count = len(views) if isinstance(views, list) else type(views).__name__
        raise MessageError(f"xr_pose: views must be a list of two (left, right), got {count}")
    made = []
    for view in views:
        _keys(view, _VIEW_FIELDS, "xr_pose view")
        viewport = view["viewport"]
        if not isinstance(viewport, list) or len(viewport) != 2:
            raise MessageError(f"xr_pose view: viewport must be [width, height], got {viewport!r}")
        try:
            made.append(
                XRView(
                    eye=view["eye"],
                    position=view["position"],
                    orientation=view["orientation"],
                    projection=view["projection"],
                    viewport=tuple(viewport),
                )
            )
        except (TypeError, ValueError) as err:
            raise MessageError(f"xr_pose: {err}") from None
    try:
        return XRPose(
            t=msg["t"], position=head["position"], orientation=head["orientation"], views=tuple(made)
        )
    except (TypeError, ValueError) as err:
        raise MessageError(f"xr_pose: {err}") from None


def parse_xr_message(data) -> dict:
    """Validate one headset-page message (str or bytes); returns a dict with checked values (an
    "xr_pose" carries an `XRPose` under "pose"). `MessageError` says why a message is rejected;
    "key" messages are checked as `parse_message` checks them."""
    msg = json_object(data, XR_MAX_MESSAGE_BYTES)
    kind = msg.get("type")
    if kind == "key":
        parsed = parse_message(data)
        if parsed["action"].startswith("head_"):
            raise MessageError(f"key message: {parsed['action']}: the head pose comes from the headset")
        return parsed
    if not isinstance(kind, str) or kind not in _FIELDS:
        raise MessageError(f"unknown message type {kind!r} (expected one of {sorted([*_FIELDS, 'key'])})")
    _keys(msg, _FIELDS[kind], f"{kind} message")
    if kind == "xr_pose":
        return {"type": "xr_pose", "pose": _pose(msg)}
    if kind == "xr_state":
        state, reason = msg["state"], msg["reason"]
        if state not in XR_STATES:
            raise MessageError(f"xr_state message: state must be one of {XR_STATES}, got {state!r}")
        if not isinstance(reason, str) or len(reason) > MAX_REASON_CHARS:
            raise MessageError(
                f"xr_state message: reason must be text of at most {MAX_REASON_CHARS} characters"
            )
        return {"type": "xr_state", "state": state, "reason": " ".join(reason.split())}
    frame = msg["frame"]
    if isinstance(frame, bool) or not isinstance(frame, int) or frame < 0:
        raise MessageError(f"shown message: frame must be a non-negative integer, got {frame!r}")
    out = {"type": "shown", "frame": frame, "latency_ms": None}
    for name, (low, high) in _SHOWN_RANGES.items():
        out[name] = None if msg[name] is None else _number(msg, name, low, high)
    return out
