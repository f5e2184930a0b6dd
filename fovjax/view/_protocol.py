"""Messages between the viewer page and the server, and their validation.

Page -> server (JSON text, at most `MAX_MESSAGE_BYTES`; anything else is ignored with a logged
reason, never an error):

- ``{"type": "gaze", "eye": "left"|"right", "x": X, "y": Y, "t": T}``: the mouse over an eye,
  X, Y in [0, 1] (normalised display coordinates of that eye: origin top-left, y down), T the
  page's `performance.now()` in ms when the mouse event happened;
- ``{"type": "leave"}``: the mouse left both eyes (the gaze is held);
- ``{"type": "key", "action": A}``: one of `ACTIONS`;
- ``{"type": "shown", "frame": N, "latency_ms": L}``: frame N is on screen; L, when the frame
  was the first to use a new page gaze event, is that event's age in ms at display (the page's
  clock on both ends), else null.

Server -> page: ``{"type": "frame", ...}`` (statistics) followed by one binary message (the
JPEG), ``{"type": "status", ...}`` (waiting, compiling, errors), ``{"type": "saved", ...}``.
"""

from __future__ import annotations

import json
import math

MAX_MESSAGE_BYTES = 1024

# Keyboard actions the page may send (the page maps keys to them; see static/viewer.js).
ACTIONS = (
    "head_left",
    "head_right",
    "head_up",
    "head_down",
    "head_reset",
    "fovea_up",
    "fovea_down",
    "periphery_up",
    "periphery_down",
    "preset_1",
    "preset_2",
    "preset_3",
    "preset_4",
    "preset_5",
    "toggle_full",
    "toggle_debug",
    "save",
)

_FIELDS = {
    "gaze": {"type", "eye", "x", "y", "t"},
    "leave": {"type"},
    "key": {"type", "action"},
    "shown": {"type", "frame", "latency_ms"},
}


class MessageError(ValueError):
    """A page message that is ignored; the text says why."""


def _number(msg: dict, name: str, low: float | None = None, high: float | None = None) -> float:
    value = msg[name]
    # bool is an int in Python; JSON true/false are not numbers here.
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise MessageError(f"{name} must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise MessageError(f"{name} must be finite, got {value!r}")
    if (low is not None and value < low) or (high is not None and value > high):
        raise MessageError(f"{name} must be in [{low}, {high}], got {value!r}")
    return value


def json_object(data, limit: int) -> dict:
    """One page message (str or bytes) of at most `limit` bytes, parsed as a JSON object;
    `MessageError` says why it is not one."""
    if isinstance(data, bytes | bytearray):
        size = len(data)
    elif isinstance(data, str):
        size = len(data.encode("utf-8", "surrogatepass"))
    else:
        raise MessageError(f"expected a JSON text message, got {type(data).__name__}")
    if size > limit:
        raise MessageError(f"message of {size} bytes exceeds the {limit}-byte limit")
    try:
        msg = json.loads(data)
    except (ValueError, UnicodeDecodeError) as err:
        raise MessageError(f"malformed JSON: {err}") from None
    if not isinstance(msg, dict):
        raise MessageError(f"expected a JSON object, got {type(msg).__name__}")
    return msg


def parse_message(data) -> dict:
    """Validate one page message (str or bytes) and return it as a dict with checked, typed
    values; `MessageError` says why a message is rejected."""
    msg = json_object(data, MAX_MESSAGE_BYTES)
    kind = msg.get("type")
    if not isinstance(kind, str) or kind not in _FIELDS:
        raise MessageError(f"unknown message type {kind!r} (expected one of {sorted(_FIELDS)})")
    keys = set(msg)
    unknown = keys - _FIELDS[kind]
    if unknown:
        raise MessageError(f"{kind} message: unknown keys {sorted(unknown)}")
    missing = _FIELDS[kind] - keys - ({"latency_ms"} if kind == "shown" else set())
    if missing:
        raise MessageError(f"{kind} message: missing keys {sorted(missing)}")
    if kind == "gaze":
        eye = msg["eye"]
        if eye not in ("left", "right"):
            raise MessageError(f"gaze message: eye must be 'left' or 'right', got {eye!r}")
        return {
            "type": "gaze",
            "eye": eye,
            "x": _number(msg, "x", 0.0, 1.0),
            "y": _number(msg, "y", 0.0, 1.0),
            "t": _number(msg, "t", 0.0, 1e12),
        }
    if kind == "key":
        action = msg["action"]
        if not isinstance(action, str) or action not in ACTIONS:
            raise MessageError(f"key message: unknown action {action!r}")
        return {"type": "key", "action": action}
    if kind == "shown":
        frame = msg["frame"]
        if isinstance(frame, bool) or not isinstance(frame, int) or frame < 0:
            raise MessageError(f"shown message: frame must be a non-negative integer, got {frame!r}")
        latency = msg.get("latency_ms")
        return {
            "type": "shown",
            "frame": frame,
            "latency_ms": None if latency is None else _number(msg, "latency_ms", 0.0, 1e7),
        }
    return {"type": "leave"}
