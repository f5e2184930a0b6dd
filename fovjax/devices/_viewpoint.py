"""Arrington Research ViewPoint EyeTracker through its SDK library (``VPX_InterApp``) with ctypes.

Signatures followed, from the SDK header ``vpx.h`` / ``vpxMATLAB.h`` (SDK 2.9.x, ``VPX_SDK_VERSION
294``) and the thesis's figure 45, all ``__cdecl``:

* ``int VPX_GetGazePoint2(VPX_EyeType eye, VPX_RealPoint *gp)`` (and ``...Smoothed2``), where
  ``VPX_RealPoint`` is ``struct { float x, y; }`` and ``VPX_EyeType`` is an ``int``
  (``EYE_A = 0``, ``EYE_B = 1``);
* ``int VPX_GetDataQuality2(VPX_EyeType eye, int *quality)``: the quality codes of the thesis's
  table 1 -- 0 glint and pupil good, 1 only the pupil wanted and good, 2 glint bad so the good
  pupil is used, 3 pupil outside criteria limits, 4 no ellipse fit, 5 pupil scan threshold failed;
* ``int VPX_GetDataTime2(VPX_EyeType eye, double *seconds)``;
* ``int VPX_InsertCallback(VPX_CALLBACK fn, void *userPtr)`` / ``int VPX_RemoveCallback(fn)`` with
  ``typedef int (*VPX_CALLBACK)(int msg, int subMsg, int param1, int param2, void *userPtr)``; a
  message ``msg == VPX_DAT_FRESH`` (2) announces fresh eye data. Older SDKs declare the callback
  and ``VPX_InsertCallback`` without the user pointer; under ``__cdecl`` the extra argument is
  harmless either way (the caller pops it), so the five-argument form serves both.

Public uses of the same functions through ctypes that agree with these signatures:
``vrpn/vrpn: vrpn_Tracker_ViewPoint.C`` (C) and ``fcbg-platforms/lsl-viewpoint`` (Python ctypes).

Coordinates: ViewPoint's gaze point is normalised to its GazeSpace, (0, 0) top-left and (1, 1)
bottom-right, which is already `GazeSample`'s convention, so it is passed through (``flip_y``
exists for a GazeSpace set up the other way). Which ViewPoint eye is which follows figure 45: the
thesis maps ``EYE_A`` to the right half of the side-by-side frame (the right eye) and ``EYE_B`` to
the left half; `eye_a` changes that.
"""

from __future__ import annotations

import collections
import ctypes
import ctypes.util
import math
import os
import threading
import time

from .. import _environment
from ._samples import EyeGaze, GazeSample
from ._source import Clock, DeviceError, LibraryNotFoundError, Source

EYE_A = 0
EYE_B = 1
VPX_DAT_FRESH = 2
QUALITY_CODES = {
    0: "Glint and pupil are good.",
    1: "Wanted only the pupil and got a good one.",
    2: "Wanted glint, but it was bad, using the good pupil.",
    3: "Pupil was bad because it exceeded criteria limits.",
    4: "Pupil could not be fit with an ellipse.",
    5: "Pupil scan threshold failed.",
}
WORST_QUALITY_CODE = 5
LIBRARY_ENV = "FOVJAX_VIEWPOINT_LIB"


class VPX_RealPoint(ctypes.Structure):
    _fields_ = [("x", ctypes.c_float), ("y", ctypes.c_float)]


VPX_CALLBACK = ctypes.CFUNCTYPE(
    ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_void_p
)


def find_library(path: str | os.PathLike | None, *, env: str, names: tuple[str, ...], what: str) -> str:
    """Resolve a vendor library: explicit `path`, else ``$env``, else the system search for
    `names`. Raises `LibraryNotFoundError` saying where it looked."""
    tried = []
    candidate = path if path is not None else _environment.path(env)
    if candidate is not None:
        candidate = os.fspath(candidate)
        if os.path.exists(candidate):
            return candidate
        tried.append(candidate)
    else:
        for name in names:
            found = ctypes.util.find_library(name)
            if found:
                return found
            tried.append(f"find_library({name!r})")
    raise LibraryNotFoundError(
        f"{what} library not found (tried {', '.join(tried)}); pass library_path=... or set ${env}"
    )


def quality_to_confidence(code: int) -> float:
    """Ordinal rescale of a ViewPoint quality code to [0, 1]: 0 -> 1.0, 5 -> 0.0.

    Not a probability; only the order is meaningful. Acceptance uses the code itself.
    """
    return max(0.0, min(1.0, (WORST_QUALITY_CODE - code) / WORST_QUALITY_CODE))


def viewpoint_to_side_by_side(x: float, y: float, eye: int, width: int, height: int) -> tuple[float, float]:
    """The thesis's mapping (figure 45) of a normalised ViewPoint gaze point to pixel coordinates
    of the ``width x height`` side-by-side stereo frame.

    ``EYE_A`` lands in the right half: ``(x * W/2 + W/2, (1 - y) * H)``; ``EYE_B`` in the left half:
    ``(x * W/2, (1 - y) * H)``. The row is counted from the **bottom** (``1 - y``) because the
    thesis's OptiX launch index has its origin at the bottom-left.
    """
    half = width / 2.0
    if eye == EYE_A:
        return x * half + half, (1.0 - y) * height
    if eye == EYE_B:
        return x * half, (1.0 - y) * height
    raise ValueError(f"viewpoint_to_side_by_side: eye must be EYE_A (0) or EYE_B (1), got {eye}")


class ViewPointSource(Source[GazeSample]):
    """Binocular gaze from ViewPoint via the fresh-data callback.

    The library is loaded in `open()` (from `library_path`, ``$FOVJAX_VIEWPOINT_LIB`` or the
    system search for ``VPX_InterApp``) and a clear `LibraryNotFoundError` is raised where it does
    not exist. On every ``VPX_DAT_FRESH`` message both eyes are read -- gaze point, quality code,
    data time -- as the thesis's callback does; an eye is valid when its quality code is at most
    `max_quality_code` (2 by default, the thesis's rule) and its point is finite. A message whose
    two data times equal the previous sample's is not emitted twice. Samples are stamped with
    `clock()` when the callback runs; ViewPoint's data time of the right eye is ``device_time``.

    `smoothed` (default True, as the thesis): the gaze point is ViewPoint's smoothed one,
    ``VPX_GetGazePointSmoothed2``, which is what the thesis's callback reads (its smoothing is
    configured in ViewPoint itself); False reads the unfiltered ``VPX_GetGazePoint2`` (less lag,
    more jitter). The source spec chooses with ``viewpoint[:LIBRARY][@smoothed|@raw]``.
    """

    kind = "gaze"

    def __init__(
        self,
        library_path: str | os.PathLike | None = None,
        *,
        max_quality_code: int = 2,
        smoothed: bool = True,
        eye_a: str = "right",
        flip_y: bool = False,
        clock: Clock = time.monotonic,
        buffer_size: int = 1 << 17,
    ):
        super().__init__(clock=clock)
        if not 0 <= max_quality_code <= WORST_QUALITY_CODE:
            raise ValueError(f"ViewPointSource: max_quality_code must be in 0..5, got {max_quality_code}")
        if eye_a not in ("right", "left"):
            raise ValueError(f"ViewPointSource: eye_a must be 'right' or 'left', got {eye_a!r}")
        self.library_path = library_path
        self.max_quality_code = max_quality_code
        self.smoothed = smoothed
        self.eye_a = eye_a
        self.flip_y = flip_y
        self._lib = None
        self._callback = None
        self._buffer: collections.deque[GazeSample] = collections.deque(maxlen=buffer_size)
        self._cond = threading.Condition()
        self._latest: GazeSample | None = None
        self._last_times: tuple[float, float] | None = None
        self.status.extra["rejected_quality"] = 0

    def describe(self) -> str:
        return "ViewPoint SDK" + ("" if self.library_path is None else f" {self.library_path}")

    def _open(self) -> None:
        path = find_library(self.library_path, env=LIBRARY_ENV, names=("VPX_InterApp",), what="ViewPoint SDK")
        try:
            lib = ctypes.CDLL(path)
        except OSError as exc:
            raise LibraryNotFoundError(
                f"ViewPoint SDK library {path!r} exists but cannot be loaded: {exc}"
            ) from exc
        point_fn = "VPX_GetGazePointSmoothed2" if self.smoothed else "VPX_GetGazePoint2"
        try:
            self._get_point = getattr(lib, point_fn)
            self._get_quality = lib.VPX_GetDataQuality2
            self._get_time = lib.VPX_GetDataTime2
            self._insert = lib.VPX_InsertCallback
            self._remove = lib.VPX_RemoveCallback
        except AttributeError as exc:
            raise DeviceError(f"ViewPoint SDK library {path!r} lacks a required function: {exc}") from exc
        self._get_point.argtypes = [ctypes.c_int, ctypes.POINTER(VPX_RealPoint)]
        self._get_point.restype = ctypes.c_int
        self._get_quality.argtypes = [ctypes.c_int, ctypes.POINTER(ctypes.c_int)]
        self._get_quality.restype = ctypes.c_int
        self._get_time.argtypes = [ctypes.c_int, ctypes.POINTER(ctypes.c_double)]
        self._get_time.restype = ctypes.c_int
        self._insert.argtypes = [VPX_CALLBACK, ctypes.c_void_p]
        self._insert.restype = ctypes.c_int
        self._remove.argtypes = [VPX_CALLBACK]
        self._remove.restype = ctypes.c_int
        self._lib = lib
        self._callback = VPX_CALLBACK(self._on_message)  # kept referenced while registered
        self._insert(self._callback, None)
        self.status.connected = True
        self.status.connects += 1

    def _close(self) -> None:
        if self._lib is not None and self._callback is not None:
            self._remove(self._callback)
        self.status.connected = False
        with self._cond:
            self._cond.notify_all()

    def _read_eye(self, eye: int) -> tuple[EyeGaze, float]:
        point = VPX_RealPoint()
        quality = ctypes.c_int(WORST_QUALITY_CODE)
        seconds = ctypes.c_double(math.nan)
        self._get_point(eye, ctypes.byref(point))
        self._get_quality(eye, ctypes.byref(quality))
        self._get_time(eye, ctypes.byref(seconds))
        x, y = float(point.x), float(point.y)
        if self.flip_y:
            y = 1.0 - y
        code = int(quality.value)
        ok = code <= self.max_quality_code and math.isfinite(x) and math.isfinite(y)
        if not ok:
            self.status.extra["rejected_quality"] += 1
        return EyeGaze(x, y, quality_to_confidence(code), ok), float(seconds.value)

    def _on_message(self, msg, sub_msg, param1, param2, user_ptr) -> int:
        # Runs on ViewPoint's thread; an exception must never propagate into the SDK.
        try:
            if msg != VPX_DAT_FRESH or self._closed:
                return 0
            gaze_a, time_a = self._read_eye(EYE_A)
            gaze_b, time_b = self._read_eye(EYE_B)
            if self._last_times == (time_a, time_b):
                return 0
            self._last_times = (time_a, time_b)
            now = self.clock()
            if self.eye_a == "right":
                sample = GazeSample(now, left=gaze_b, right=gaze_a, device_time=time_a)
            else:
                sample = GazeSample(now, left=gaze_a, right=gaze_b, device_time=time_a)
            with self._cond:
                if len(self._buffer) == self._buffer.maxlen:
                    self.status.dropped += 1
                self._buffer.append(sample)
                self._latest = sample
                self.status.samples += 1
                self._cond.notify_all()
        except Exception as exc:
            self.status.errors += 1
            self.status.last_error = f"{type(exc).__name__}: {exc}"
        return 0

    def read(self, timeout: float | None = None) -> GazeSample | None:
        self._require_open()
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while not self._buffer:
                if self._closed:
                    return None
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                self._cond.wait(0.1 if remaining is None else min(remaining, 0.1))
            sample = self._buffer.popleft()
        return self._corrected(sample)

    def latest(self) -> GazeSample | None:
        with self._cond:
            sample = self._latest
        return self._corrected(sample)

    def drain(self) -> list[GazeSample]:
        with self._cond:
            out = list(self._buffer)
            self._buffer.clear()
        return [self._corrected(sample) for sample in out]
