"""Timestamped tracking samples: per-eye gaze and head orientation.

Coordinates
-----------
Gaze is given per eye in **normalised display coordinates of that eye's own display** (the left
eye's panel, or the left half of a side-by-side frame, for the left eye): origin at the **top-left**
corner of the display, ``x`` to the right, ``y`` down, ``(0, 0)`` top-left and ``(1, 1)``
bottom-right, independent of resolution. Pixel ``(col, row)`` of a ``W x H`` eye image has its
centre at ``((col + 0.5) / W, (row + 0.5) / H)``. Values slightly outside ``[0, 1]`` mean the eye
looks past the edge of the panel.

Clock
-----
``timestamp`` is in seconds on the clock of the source that produced the sample, which is
``time.monotonic`` unless the source states otherwise (every source has a ``clock`` attribute; a
replay without pacing keeps the recorded timestamps). It is the time the sample became available
to this process, so ``clock() - sample.timestamp`` is the age of a sample. ``device_time`` is the
tracker's own timestamp in its own epoch (NaN when the device gives none); it is recorded but never
compared with ``timestamp``.

Head orientation
----------------
``HeadPose`` carries yaw, pitch and roll in degrees as an InterSense InertiaCube reports them
(``ISD_STATION_DATA_TYPE.Euler = {Yaw, Pitch, Roll}``): a right-handed, z-down frame (x forward,
y right, z down), angles applied yaw about z, then pitch about the new y, then roll about the new
x. Yaw is positive turning right (seen from above), pitch positive looking up, roll positive
tilting the right ear down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np


class EyeGaze(NamedTuple):
    """One eye's gaze: normalised display position, confidence in [0, 1], and the source's verdict.

    ``valid`` is False when the device said this eye was not tracked (blink, lost pupil, quality
    code above the accepted limit, missing field). A valid eye may still be rejected later by a
    quality filter (low confidence, NaN, far off screen).
    """

    x: float
    y: float
    confidence: float = 1.0
    valid: bool = True

    @property
    def xy(self) -> tuple[float, float]:
        return (self.x, self.y)

    def is_finite(self) -> bool:
        return math.isfinite(self.x) and math.isfinite(self.y) and math.isfinite(self.confidence)


MISSING_EYE = EyeGaze(math.nan, math.nan, 0.0, False)


@dataclass(frozen=True, slots=True)
class GazeSample:
    """A binocular gaze sample; see the module docstring for coordinates and clock."""

    timestamp: float
    left: EyeGaze
    right: EyeGaze
    device_time: float = math.nan

    kind = "gaze"

    def eye(self, which: str) -> EyeGaze:
        if which == "left":
            return self.left
        if which == "right":
            return self.right
        raise ValueError(f"GazeSample.eye: which must be 'left' or 'right', got {which!r}")

    def as_row(self) -> dict[str, float | bool]:
        """Flat record (the recording format's field names)."""
        return {
            "t": float(self.timestamp),
            "device_time": float(self.device_time),
            "lx": float(self.left.x),
            "ly": float(self.left.y),
            "lq": float(self.left.confidence),
            "lv": bool(self.left.valid),
            "rx": float(self.right.x),
            "ry": float(self.right.y),
            "rq": float(self.right.confidence),
            "rv": bool(self.right.valid),
        }

    @classmethod
    def from_row(cls, row: dict) -> GazeSample:
        return cls(
            timestamp=float(row["t"]),
            left=EyeGaze(float(row["lx"]), float(row["ly"]), float(row["lq"]), bool(row["lv"])),
            right=EyeGaze(float(row["rx"]), float(row["ry"]), float(row["rq"]), bool(row["rv"])),
            device_time=float(row.get("device_time", math.nan)),
        )

    def with_timestamp(self, timestamp: float) -> GazeSample:
        return GazeSample(timestamp, self.left, self.right, self.device_time)


@dataclass(frozen=True, slots=True)
class HeadPose:
    """Head orientation in degrees, InertiaCube convention (see the module docstring)."""

    timestamp: float
    yaw: float
    pitch: float
    roll: float
    device_time: float = math.nan
    valid: bool = True

    kind = "head"

    def as_row(self) -> dict[str, float | bool]:
        return {
            "t": float(self.timestamp),
            "device_time": float(self.device_time),
            "yaw": float(self.yaw),
            "pitch": float(self.pitch),
            "roll": float(self.roll),
            "valid": bool(self.valid),
        }

    @classmethod
    def from_row(cls, row: dict) -> HeadPose:
        return cls(
            timestamp=float(row["t"]),
            yaw=float(row["yaw"]),
            pitch=float(row["pitch"]),
            roll=float(row["roll"]),
            device_time=float(row.get("device_time", math.nan)),
            valid=bool(row.get("valid", True)),
        )

    def with_timestamp(self, timestamp: float) -> HeadPose:
        return HeadPose(timestamp, self.yaw, self.pitch, self.roll, self.device_time, self.valid)

    def is_finite(self) -> bool:
        return all(math.isfinite(v) for v in (self.yaw, self.pitch, self.roll))

    def rotation_matrix(self) -> np.ndarray:
        """3x3 rotation taking head-frame vectors to the tracker's world frame (x fwd, y right,
        z down): ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

        In this z-down frame a positive rotation about y lifts the x (forward) axis towards -z,
        i.e. looks up, and a positive rotation about x lowers the y (right) axis towards +z, so the
        InertiaCube signs map onto the standard aerospace direction-cosine matrix unchanged.
        """
        y, p, r = (math.radians(a) for a in (self.yaw, self.pitch, self.roll))
        cy, sy = math.cos(y), math.sin(y)
        cp, sp = math.cos(p), math.sin(p)
        cr, sr = math.cos(r), math.sin(r)
        rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
        rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
        return rz @ ry @ rx


Sample = GazeSample | HeadPose

DISPLAY_CENTRE = (0.5, 0.5)
