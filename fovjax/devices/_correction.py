"""A correction of measured gaze: one affine map per eye, on normalised display positions."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from ._geometry import eye_index
from ._samples import EyeGaze, GazeSample

Affine = tuple[tuple[float, float, float], tuple[float, float, float]]
IDENTITY: Affine = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))


def _affine(value, name: str) -> Affine:
    try:
        matrix = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        matrix = np.full(1, np.nan)
    if matrix.shape != (2, 3) or not np.isfinite(matrix).all():
        raise ValueError(
            f"GazeCorrection: {name} must be a finite 2 x 3 affine map ((a, b, c), (d, e, f)), got {value!r}"
        )
    det = float(np.linalg.det(matrix[:, :2]))
    if not abs(det) > 1e-9:
        raise ValueError(
            f"GazeCorrection: {name} {matrix.tolist()} is not invertible (determinant {det:.3g})"
        )
    return (tuple(float(v) for v in matrix[0]), tuple(float(v) for v in matrix[1]))  # type: ignore[return-value]


@dataclasses.dataclass(frozen=True)
class GazeCorrection:
    """Per-eye affine maps applied to measured gaze: an eye at (x, y) is moved to
    ``(a x + b y + c, d x + e y + f)`` with that eye's ``((a, b, c), (d, e, f))``.

    A calibration (`calibrate`) fits one; set it on a source (``source.correction = ...``) and
    every sample read from the source afterwards is corrected. Eyes the source marked invalid
    or that are not finite pass through unchanged.

    Args:
        left: the left eye's map (default: the identity).
        right: the right eye's map (default: the identity).

    Raises:
        ValueError: a map that is not 2 x 3 and finite, or not invertible.
    """

    left: Affine | Sequence[Sequence[float]] | np.ndarray = IDENTITY
    right: Affine | Sequence[Sequence[float]] | np.ndarray = IDENTITY

    def __post_init__(self):
        object.__setattr__(self, "left", _affine(self.left, "left"))
        object.__setattr__(self, "right", _affine(self.right, "right"))

    def matrix(self, eye) -> np.ndarray:
        """The eye's map as a 2 x 3 array."""
        return np.array(self.left if eye_index(eye) == 0 else self.right)

    def apply_xy(self, eye, xy) -> np.ndarray:
        """Corrected positions (..., 2) of `eye`'s measured positions `xy` (..., 2)."""
        m = self.matrix(eye)
        xy = np.asarray(xy, dtype=float)
        return xy @ m[:, :2].T + m[:, 2]

    def _eye(self, which: str, eye: EyeGaze) -> EyeGaze:
        if not (eye.valid and math.isfinite(eye.x) and math.isfinite(eye.y)):
            return eye
        x, y = self.apply_xy(which, (eye.x, eye.y))
        return EyeGaze(float(x), float(y), eye.confidence, eye.valid)

    def apply(self, sample: GazeSample) -> GazeSample:
        """The sample with both eyes corrected."""
        return GazeSample(
            sample.timestamp,
            self._eye("left", sample.left),
            self._eye("right", sample.right),
            sample.device_time,
        )

    def to_dict(self) -> dict:
        return {"left": [list(row) for row in self.left], "right": [list(row) for row in self.right]}

    @classmethod
    def from_dict(cls, data: dict) -> GazeCorrection:
        if not isinstance(data, dict) or not {"left", "right"} <= set(data):
            raise ValueError(f"GazeCorrection: expected {{'left': 2 x 3, 'right': 2 x 3}}, got {data!r}")
        return cls(left=data["left"], right=data["right"])
