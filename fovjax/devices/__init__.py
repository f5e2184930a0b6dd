"""Eye and head tracking for fovjax: samples, sources, recording and replay, filtering, and the
fallback when tracking fails.

Conventions (details in each class):

* Gaze: per eye, normalised display coordinates of that eye's own display, origin top-left,
  x right, y down (`GazeSample`). Head: yaw/pitch/roll in degrees, InertiaCube convention
  (`HeadPose`).
* Clock: every source has a ``clock`` (``time.monotonic`` seconds unless stated) and stamps
  samples on it; ``clock() - sample.timestamp`` is a sample's age.
* Sources: iterate for every sample in order, ``latest()`` for the newest without blocking,
  ``open``/``close`` or a ``with`` block.
* Per frame: `GazeTracker.step(now, samples, display_time)` -> `TrackingFrame` (gaze per eye,
  state ok/holding/degraded/lost, fovea widening).
* The rig: `RigGeometry` (`RigGeometry.from_rig(rig)`) relates the two eyes' displays; one
  eye's gaze is never the other's position.
* Calibration: `calibrate(source, present)` -> `CalibrationResult` (per-eye accuracy and
  precision in degrees, a `GazeCorrection` to set as ``source.correction``); `validate`.
"""

from ._calibration import (
    CalibrationError as CalibrationError,
)
from ._calibration import (
    CalibrationPoint as CalibrationPoint,
)
from ._calibration import (
    CalibrationResult as CalibrationResult,
)
from ._calibration import (
    CalibrationSettings as CalibrationSettings,
)
from ._calibration import (
    CalibrationTarget as CalibrationTarget,
)
from ._calibration import (
    EyeAccuracy as EyeAccuracy,
)
from ._calibration import (
    PointEye as PointEye,
)
from ._calibration import (
    ValidationResult as ValidationResult,
)
from ._calibration import (
    calibrate as calibrate,
)
from ._calibration import (
    calibration_targets as calibration_targets,
)
from ._calibration import (
    load_calibration as load_calibration,
)
from ._calibration import (
    targets_at as targets_at,
)
from ._calibration import (
    validate as validate,
)
from ._correction import GazeCorrection as GazeCorrection
from ._filters import (
    ExponentialMovingAverage as ExponentialMovingAverage,
)
from ._filters import (
    GazePredictor as GazePredictor,
)
from ._filters import (
    OneEuroFilter as OneEuroFilter,
)
from ._filters import (
    QualityFilter as QualityFilter,
)
from ._filters import (
    VelocityThresholdDetector as VelocityThresholdDetector,
)
from ._filters import (
    angular_speed as angular_speed,
)
from ._filters import (
    ivt_classify as ivt_classify,
)
from ._geometry import RigGeometry as RigGeometry
from ._intersense import InterSenseSource as InterSenseSource
from ._paced import PacedSource as PacedSource
from ._protocol import (
    LineParser as LineParser,
)
from ._protocol import (
    ProtocolError as ProtocolError,
)
from ._protocol import (
    checksum as checksum,
)
from ._protocol import (
    format_gaze as format_gaze,
)
from ._protocol import (
    format_head as format_head,
)
from ._protocol import (
    parse_line as parse_line,
)
from ._pupil import PupilSource as PupilSource
from ._pupil import gaze_from_pupil_datum as gaze_from_pupil_datum
from ._recording import (
    Recorder as Recorder,
)
from ._recording import (
    Recording as Recording,
)
from ._recording import (
    RecordingSummary as RecordingSummary,
)
from ._recording import (
    ReplaySource as ReplaySource,
)
from ._recording import (
    load_recording as load_recording,
)
from ._recording import (
    record as record,
)
from ._samples import (
    DISPLAY_CENTRE as DISPLAY_CENTRE,
)
from ._samples import (
    MISSING_EYE as MISSING_EYE,
)
from ._samples import (
    EyeGaze as EyeGaze,
)
from ._samples import (
    GazeSample as GazeSample,
)
from ._samples import (
    HeadPose as HeadPose,
)
from ._serial import SerialSource as SerialSource
from ._source import (
    DEFAULT_CONNECT_TIMEOUT as DEFAULT_CONNECT_TIMEOUT,
)
from ._source import (
    ConnectTimeoutError as ConnectTimeoutError,
)
from ._source import (
    DeviceError as DeviceError,
)
from ._source import (
    LibraryNotFoundError as LibraryNotFoundError,
)
from ._source import (
    Source as Source,
)
from ._source import (
    SourceStatus as SourceStatus,
)
from ._source import (
    ThreadedSource as ThreadedSource,
)
from ._specs import source_from_spec as source_from_spec
from ._synthetic import (
    FixedPoints as FixedPoints,
)
from ._synthetic import (
    GazeModel as GazeModel,
)
from ._synthetic import (
    Scanpath as Scanpath,
)
from ._synthetic import (
    SmoothPursuit as SmoothPursuit,
)
from ._synthetic import (
    SyntheticGazeSource as SyntheticGazeSource,
)
from ._synthetic import (
    SyntheticHeadSource as SyntheticHeadSource,
)
from ._synthetic import (
    TargetFollower as TargetFollower,
)
from ._synthetic import (
    min_jerk as min_jerk,
)
from ._synthetic import (
    saccade_duration as saccade_duration,
)
from ._synthetic import (
    saccade_peak_velocity as saccade_peak_velocity,
)
from ._tracking import (
    FallbackPolicy as FallbackPolicy,
)
from ._tracking import (
    GazeTracker as GazeTracker,
)
from ._tracking import (
    HeadFrame as HeadFrame,
)
from ._tracking import (
    HeadTracker as HeadTracker,
)
from ._tracking import (
    TrackingFrame as TrackingFrame,
)
from ._tracking import (
    TrackingState as TrackingState,
)
from ._tracking import (
    widen_thresholds as widen_thresholds,
)
from ._viewpoint import (
    EYE_A as EYE_A,
)
from ._viewpoint import (
    EYE_B as EYE_B,
)
from ._viewpoint import (
    QUALITY_CODES as QUALITY_CODES,
)
from ._viewpoint import (
    ViewPointSource as ViewPointSource,
)
from ._viewpoint import (
    viewpoint_to_side_by_side as viewpoint_to_side_by_side,
)

__all__ = [
    "CalibrationError",
    "CalibrationPoint",
    "CalibrationResult",
    "CalibrationSettings",
    "CalibrationTarget",
    "EyeAccuracy",
    "PointEye",
    "ValidationResult",
    "calibrate",
    "calibration_targets",
    "load_calibration",
    "targets_at",
    "validate",
    "GazeCorrection",
    "RigGeometry",
    "ExponentialMovingAverage",
    "GazePredictor",
    "OneEuroFilter",
    "QualityFilter",
    "VelocityThresholdDetector",
    "angular_speed",
    "ivt_classify",
    "InterSenseSource",
    "PacedSource",
    "LineParser",
    "ProtocolError",
    "checksum",
    "format_gaze",
    "format_head",
    "parse_line",
    "PupilSource",
    "gaze_from_pupil_datum",
    "Recorder",
    "Recording",
    "RecordingSummary",
    "ReplaySource",
    "load_recording",
    "record",
    "DISPLAY_CENTRE",
    "MISSING_EYE",
    "EyeGaze",
    "GazeSample",
    "HeadPose",
    "SerialSource",
    "DEFAULT_CONNECT_TIMEOUT",
    "ConnectTimeoutError",
    "DeviceError",
    "LibraryNotFoundError",
    "Source",
    "SourceStatus",
    "ThreadedSource",
    "source_from_spec",
    "FixedPoints",
    "GazeModel",
    "Scanpath",
    "SmoothPursuit",
    "SyntheticGazeSource",
    "SyntheticHeadSource",
    "TargetFollower",
    "min_jerk",
    "saccade_duration",
    "saccade_peak_velocity",
    "FallbackPolicy",
    "GazeTracker",
    "HeadFrame",
    "HeadTracker",
    "TrackingFrame",
    "TrackingState",
    "widen_thresholds",
    "EYE_A",
    "EYE_B",
    "QUALITY_CODES",
    "ViewPointSource",
    "viewpoint_to_side_by_side",
]
