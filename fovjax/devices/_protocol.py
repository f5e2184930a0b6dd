"""The fovjax serial line protocol for gaze and head-pose streams.

A microcontroller IMU, an eye-tracker bridge or any program can feed fovjax by writing these lines
to a serial port (or a pty, or anything pyserial can open by URL).

Framing
-------
* ASCII, one message per line, each line ended by ``\\n`` (a ``\\r`` before it is ignored).
* ``$`` starts a message; ``*`` is followed by exactly two hex digits (either case), the checksum:
  the XOR of every byte strictly between ``$`` and ``*``, as in NMEA 0183.
* A line longer than ``MAX_LINE`` (256) bytes, one not starting with ``$``, with a bad or missing
  checksum, an unknown message type, the wrong number of fields, or a field that is not a number is
  rejected and counted; the stream resynchronises at the next ``\\n``. Bytes that are not ASCII are
  garbage like any other.

Messages
--------
``$GAZE,t,lx,ly,lq,rx,ry,rq*CS``
    ``t``: the sender's timestamp in seconds (any epoch; kept as ``device_time``).
    ``lx, ly`` / ``rx, ry``: left / right eye gaze in normalised display coordinates of that eye's
    own display: origin top-left, x right, y down, (1, 1) bottom-right.
    ``lq`` / ``rq``: confidence in [0, 1] (1 best). An eye is *not tracked* when its three fields
    are empty, when its confidence is negative, or when any of its fields is ``nan``.
``$HEAD,t,yaw,pitch,roll*CS``
    Degrees, InertiaCube convention (see `fovjax.devices.HeadPose`). Any empty or ``nan`` angle
    marks the pose invalid.

Numbers use a ``.`` decimal point; ``nan`` and ``inf`` are accepted as Python spells them.

Examples: ``$GAZE,12.5,0.51,0.49,0.98,0.49,0.49,0.97*2B`` and ``$HEAD,3.25,10,-5.25,0.5*09``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from ._samples import EyeGaze, GazeSample, HeadPose

MAX_LINE = 256

_FIELDS = {"GAZE": 7, "HEAD": 4}


class ProtocolError(ValueError):
    """A line that does not follow the protocol; the message says which field and why."""


def checksum(payload: bytes) -> int:
    """XOR of all bytes of `payload` (the text between ``$`` and ``*``)."""
    value = 0
    for byte in payload:
        value ^= byte
    return value


def _fmt(value: float) -> str:
    if math.isnan(value):
        return "nan"
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return f"{value:.6f}".rstrip("0").rstrip(".") if value != 0 else "0"


def frame(payload: str) -> bytes:
    """Wrap a payload (e.g. ``"GAZE,1,0.5,..."``) into a full line with checksum and newline."""
    raw = payload.encode("ascii")
    return b"$" + raw + b"*" + f"{checksum(raw):02X}".encode("ascii") + b"\r\n"


def format_gaze(sample: GazeSample, t: float | None = None) -> bytes:
    """The ``$GAZE`` line for `sample` (``t`` defaults to its device time, else its timestamp)."""
    if t is None:
        t = sample.device_time if math.isfinite(sample.device_time) else sample.timestamp
    fields = [_fmt(t)]
    for eye in (sample.left, sample.right):
        if eye.valid:
            fields += [_fmt(eye.x), _fmt(eye.y), _fmt(eye.confidence)]
        else:
            fields += ["", "", ""]
    return frame("GAZE," + ",".join(fields))


def format_head(pose: HeadPose, t: float | None = None) -> bytes:
    if t is None:
        t = pose.device_time if math.isfinite(pose.device_time) else pose.timestamp
    angles = [_fmt(a) if pose.valid else "" for a in (pose.yaw, pose.pitch, pose.roll)]
    return frame("HEAD," + ",".join([_fmt(t), *angles]))


def _number(text: str, name: str, line: bytes) -> float:
    if text == "":
        return math.nan
    try:
        return float(text)
    except ValueError:
        raise ProtocolError(f"field {name}={text!r} is not a number in line {line!r}") from None


def parse_line(line: bytes, receive_time: float) -> GazeSample | HeadPose:
    """Parse one line (without or with its line ending) into a sample stamped `receive_time`."""
    line = line.rstrip(b"\r\n")
    if len(line) > MAX_LINE:
        raise ProtocolError(f"line of {len(line)} bytes is longer than {MAX_LINE}")
    if not line.startswith(b"$"):
        raise ProtocolError(f"line does not start with '$': {line[:40]!r}")
    star = line.rfind(b"*")
    if star < 0 or len(line) - star != 3:
        raise ProtocolError(f"line has no '*' followed by two hex digits: {line[:60]!r}")
    payload, cs_text = line[1:star], line[star + 1 :]
    try:
        expected = int(cs_text, 16)
    except ValueError:
        raise ProtocolError(f"checksum {cs_text!r} is not hex in line {line[:60]!r}") from None
    actual = checksum(payload)
    if actual != expected:
        raise ProtocolError(f"checksum mismatch: line says {expected:02X}, payload gives {actual:02X}")
    try:
        text = payload.decode("ascii")
    except UnicodeDecodeError:
        raise ProtocolError(f"non-ASCII bytes in line {line[:60]!r}") from None
    parts = text.split(",")
    kind, fields = parts[0], parts[1:]
    if kind not in _FIELDS:
        raise ProtocolError(f"unknown message type {kind!r} (expected GAZE or HEAD)")
    if len(fields) != _FIELDS[kind]:
        raise ProtocolError(f"{kind} needs {_FIELDS[kind]} fields after the type, got {len(fields)}")
    names = ("t", "lx", "ly", "lq", "rx", "ry", "rq") if kind == "GAZE" else ("t", "yaw", "pitch", "roll")
    values = [_number(f, n, line) for f, n in zip(fields, names, strict=True)]
    if kind == "GAZE":
        eyes = []
        for x, y, q in (values[1:4], values[4:7]):
            tracked = all(math.isfinite(v) for v in (x, y, q)) and q >= 0.0
            eyes.append(EyeGaze(x, y, q if tracked else 0.0, tracked))
        return GazeSample(receive_time, eyes[0], eyes[1], device_time=values[0])
    yaw, pitch, roll = values[1:]
    valid = all(math.isfinite(v) for v in (yaw, pitch, roll))
    return HeadPose(receive_time, yaw, pitch, roll, device_time=values[0], valid=valid)


class LineParser:
    """Incremental parser: feed arbitrary byte chunks, get complete parsed messages back.

    Partial lines are kept until their newline arrives; a line that grows past `MAX_LINE` without
    a newline is thrown away up to the next newline. Every rejected line is counted in `rejected`
    by reason and its error text kept in `last_error`; nothing raises.
    """

    def __init__(self, clock: Callable[[], float]):
        self.clock = clock
        self._pending = bytearray()
        self._discarding = False
        self.rejected: dict[str, int] = {"garbage": 0, "checksum": 0, "format": 0, "overlong": 0}
        self.accepted = 0
        self.last_error = ""

    def reset(self) -> None:
        """Forget any partial line (after a reconnect the old tail is meaningless)."""
        if self._pending:
            self.rejected["garbage"] += 1
        self._pending.clear()
        self._discarding = False

    def feed(self, chunk: bytes) -> list[GazeSample | HeadPose]:
        out: list[GazeSample | HeadPose] = []
        now = self.clock()
        start = 0
        while True:
            nl = chunk.find(b"\n", start)
            if nl < 0:
                self._append(chunk[start:])
                return out
            piece = chunk[start:nl]
            start = nl + 1
            if self._discarding:
                self._discarding = False
                self._pending.clear()
                continue
            self._pending += piece
            line = bytes(self._pending)
            self._pending.clear()
            message = self._parse(line, now)
            if message is not None:
                out.append(message)

    def _append(self, tail: bytes) -> None:
        if self._discarding:
            return
        self._pending += tail
        if len(self._pending) > MAX_LINE + 2:
            self.rejected["overlong"] += 1
            self.last_error = f"line longer than {MAX_LINE} bytes without a newline"
            self._pending.clear()
            self._discarding = True

    def _parse(self, line: bytes, now: float) -> GazeSample | HeadPose | None:
        stripped = line.strip(b"\r")
        if not stripped:
            return None
        # Resynchronise on the last '$' so garbage glued to the front of a line costs only the
        # garbage, not the message after it.
        dollar = stripped.rfind(b"$")
        if dollar > 0:
            self.rejected["garbage"] += 1
            stripped = stripped[dollar:]
        try:
            message = parse_line(stripped, now)
        except ProtocolError as exc:
            text = str(exc)
            reason = (
                "checksum"
                if "checksum" in text
                else "garbage"
                if ("start with" in text or "non-ASCII" in text)
                else "overlong"
                if "longer" in text
                else "format"
            )
            self.rejected[reason] += 1
            self.last_error = text
            return None
        self.accepted += 1
        return message
