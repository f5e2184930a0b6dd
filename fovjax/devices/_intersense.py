"""InterSense trackers (InertiaCube3 and kin) through the InterSense SDK library with ctypes.

Signatures and struct layout followed: InterSense ``isense.h`` (``ISLIB_VERSION "4.237"``, 2012) with
its Unix ``types.h`` (x86-64 branch: ``DWORD`` = ``unsigned int``, ``Bool`` = ``LONG`` = 32-bit
``int``, ``WORD`` = ``unsigned short``, ``Hwnd`` = ``long``; on Windows ``Bool`` is ``BOOL`` and
``Hwnd`` an ``HWND``, the same sizes). Entry points are ``__cdecl`` (``DLLENTRY``):

* ``ISD_TRACKER_HANDLE ISD_OpenTracker(Hwnd hParent, DWORD commPort, Bool infoScreen, Bool verbose)``
  -- ``int`` handle, -1 (here: anything < 1) on failure; port 0 auto-detects;
* ``Bool ISD_GetTrackingData(ISD_TRACKER_HANDLE, ISD_TRACKING_DATA_TYPE *)`` where
  ``ISD_TRACKING_DATA_TYPE`` is ``ISD_STATION_DATA_TYPE Station[ISD_MAX_STATIONS = 8]`` and a
  station's ``Euler[3]`` holds yaw, pitch, roll in degrees; ``NewData`` is TRUE when the data
  changed since the last call; ``TrackingStatus`` is 0 when tracking is lost;
* ``Bool ISD_ResetHeading(ISD_TRACKER_HANDLE, WORD stationID)`` (stations count from 1);
* ``Bool ISD_CloseTracker(ISD_TRACKER_HANDLE)``.

The call sequence (open, reset heading, read once per frame, close) is the thesis's section 4.2
(figure 47); public ctypes/C users of the same calls include ``vrpn/vrpn: vrpn_Tracker_isense.C``.
"""

from __future__ import annotations

import ctypes
import math
import os
import time

from ._samples import HeadPose
from ._source import Clock, DeviceError, LibraryNotFoundError, ThreadedSource
from ._viewpoint import find_library

ISD_MAX_STATIONS = 8
ISD_MAX_BUTTONS = 8
ISD_MAX_CHANNELS = 10
ISD_MAX_AUX_INPUTS = 4
LIBRARY_ENV = "FOVJAX_ISENSE_LIB"

_BYTE = ctypes.c_uint8
_BOOL = ctypes.c_int32
_DWORD = ctypes.c_uint32
_WORD = ctypes.c_uint16
_FLOAT = ctypes.c_float


class ISD_STATION_DATA_TYPE(ctypes.Structure):
    """One station's record, field for field as in ``isense.h`` 4.237."""

    _fields_ = [
        ("TrackingStatus", _BYTE),
        ("NewData", _BYTE),
        ("CommIntegrity", _BYTE),
        ("BatteryState", _BYTE),
        ("Euler", _FLOAT * 3),
        ("Quaternion", _FLOAT * 4),
        ("Position", _FLOAT * 3),
        ("TimeStamp", _FLOAT),
        ("StillTime", _FLOAT),
        ("BatteryLevel", _FLOAT),
        ("CompassYaw", _FLOAT),
        ("ButtonState", _BOOL * ISD_MAX_BUTTONS),
        ("AnalogData", ctypes.c_int16 * ISD_MAX_CHANNELS),
        ("AuxInputs", _BYTE * ISD_MAX_AUX_INPUTS),
        ("AngularVelBodyFrame", _FLOAT * 3),
        ("AngularVelNavFrame", _FLOAT * 3),
        ("AccelBodyFrame", _FLOAT * 3),
        ("AccelNavFrame", _FLOAT * 3),
        ("VelocityNavFrame", _FLOAT * 3),
        ("AngularVelRaw", _FLOAT * 3),
        ("MeasQuality", _BYTE),
        ("bReserved2", _BYTE),
        ("bReserved3", _BYTE),
        ("bReserved4", _BYTE),
        ("TimeStampSeconds", _DWORD),
        ("TimeStampMicroSec", _DWORD),
        ("OSTimeStampSeconds", _DWORD),
        ("OSTimeStampMicroSec", _DWORD),
        ("Reserved", _FLOAT * 56),
        ("MagBodyFrame", _FLOAT * 3),
    ]


class ISD_TRACKING_DATA_TYPE(ctypes.Structure):
    _fields_ = [("Station", ISD_STATION_DATA_TYPE * ISD_MAX_STATIONS)]


class InterSenseSource(ThreadedSource):
    """Head orientation from an InterSense tracker, polled by one background thread.

    `library_path` (else ``$FOVJAX_ISENSE_LIB``, else the system search for ``isense``) is loaded
    in `open()`; a missing library raises `LibraryNotFoundError` there. The tracker itself is
    opened by the reader thread (`port` 0 auto-detects), so a tracker that is unplugged or not yet
    there is retried with back-off rather than raised. With `reset_heading`, ``ISD_ResetHeading``
    is called after every (re)open, as the thesis does at start-up. The thread polls
    ``ISD_GetTrackingData`` every `poll_interval` seconds and emits a `HeadPose` only when
    ``NewData`` is set; the pose is invalid when ``TrackingStatus`` is 0 or an angle is not
    finite. A failing ``ISD_GetTrackingData`` counts as a broken link: the tracker is closed and
    reopened. ``device_time`` is the station's ``TimeStamp`` (seconds, when the tracker stamps).
    """

    kind = "head"

    def __init__(
        self,
        library_path: str | os.PathLike | None = None,
        *,
        port: int = 0,
        station: int = 1,
        reset_heading: bool = True,
        poll_interval: float = 1.0 / 180.0,
        clock: Clock = time.monotonic,
        backoff_initial: float = 0.1,
        backoff_max: float = 2.0,
        connect_timeout: float | None = None,
    ):
        super().__init__(
            clock=clock,
            backoff_initial=backoff_initial,
            backoff_max=backoff_max,
            connect_timeout=connect_timeout,
        )
        if not 1 <= station <= ISD_MAX_STATIONS:
            raise ValueError(f"InterSenseSource: station must be in 1..{ISD_MAX_STATIONS}, got {station}")
        if not poll_interval > 0:
            raise ValueError(f"InterSenseSource: poll_interval must be > 0 s, got {poll_interval}")
        self.library_path = library_path
        self.port = port
        self.station = station
        self.reset_heading = reset_heading
        self.poll_interval = poll_interval
        self._lib = None
        self._handle = 0
        self._data = ISD_TRACKING_DATA_TYPE()

    def _open(self) -> None:
        path = find_library(self.library_path, env=LIBRARY_ENV, names=("isense",), what="InterSense SDK")
        try:
            lib = ctypes.CDLL(path)
        except OSError as exc:
            raise LibraryNotFoundError(
                f"InterSense SDK library {path!r} exists but cannot be loaded: {exc}"
            ) from exc
        try:
            lib.ISD_OpenTracker.argtypes = [ctypes.c_void_p, _DWORD, _BOOL, _BOOL]
            lib.ISD_OpenTracker.restype = ctypes.c_int
            lib.ISD_GetTrackingData.argtypes = [ctypes.c_int, ctypes.POINTER(ISD_TRACKING_DATA_TYPE)]
            lib.ISD_GetTrackingData.restype = _BOOL
            lib.ISD_ResetHeading.argtypes = [ctypes.c_int, _WORD]
            lib.ISD_ResetHeading.restype = _BOOL
            lib.ISD_CloseTracker.argtypes = [ctypes.c_int]
            lib.ISD_CloseTracker.restype = _BOOL
        except AttributeError as exc:
            raise DeviceError(f"InterSense SDK library {path!r} lacks a required function: {exc}") from exc
        self._lib = lib
        super()._open()

    def describe(self) -> str:
        return f"InterSense tracker on port {self.port}"

    def _sdk(self):
        """The SDK library, loaded by `_open`."""
        if self._lib is None:
            raise DeviceError(f"{self.describe()}: the InterSense SDK is not loaded (open the source first)")
        return self._lib

    def _connect(self) -> None:
        handle = self._sdk().ISD_OpenTracker(None, self.port, False, False)
        if handle < 1:
            raise DeviceError(f"ISD_OpenTracker(port={self.port}) found no tracker (handle {handle})")
        self._handle = handle
        if self.reset_heading:
            self._sdk().ISD_ResetHeading(handle, self.station)

    def reset_heading_now(self) -> bool:
        """Zero the yaw of the configured station now (``ISD_ResetHeading``)."""
        if self._lib is None or self._handle < 1:
            return False
        return bool(self._lib.ISD_ResetHeading(self._handle, self.station))

    def _read_some(self) -> list[HeadPose]:
        self._stop.wait(self.poll_interval)
        if not self._sdk().ISD_GetTrackingData(self._handle, ctypes.byref(self._data)):
            raise DeviceError(f"ISD_GetTrackingData(handle={self._handle}) failed")
        record = self._data.Station[self.station - 1]
        if not record.NewData:
            return []
        yaw, pitch, roll = (float(a) for a in record.Euler)
        valid = record.TrackingStatus != 0 and all(math.isfinite(a) for a in (yaw, pitch, roll))
        return [HeadPose(self.clock(), yaw, pitch, roll, device_time=float(record.TimeStamp), valid=valid)]

    def _disconnect(self) -> None:
        handle, self._handle = self._handle, 0
        if handle > 0 and self._lib is not None:
            self._lib.ISD_CloseTracker(handle)
