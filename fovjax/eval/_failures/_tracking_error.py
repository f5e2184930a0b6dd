"""`tracking_error`: the frame foveated on a gaze off by a tracker error, error measured around
the *true* gaze."""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np

from .._stability import FullRenders
from ._common import (
    CENTRAL_DEG,
    FailureCase,
    _Bench,
    _case,
    _frame_metrics,
    _gaze_angle,
    _masked,
    _mean,
    _metric,
    _scene_rig,
    _side,
    _true_eccentricity,
    offset_gaze,
)


def tracking_error(
    full: FullRenders,
    foveations: Sequence | None = None,
    *,
    errors_deg: Sequence[float] = (0.0, 1.0, 2.0, 4.0),
    directions_deg: Sequence[float] = (0.0, 90.0, 180.0, 270.0),
    gaze=(0.5, 0.5),
    keys: Sequence[int] = (0,),
    central_deg: float = CENTRAL_DEG,
    progress=None,
) -> FailureCase:
    """The frame foveated on a gaze `error` degrees off the true one (each of
    `directions_deg`), error measured around the true gaze: inside the true fovea radius, inside
    the central `central_deg`, and the share of true-fovea pixels the rendered fovea covers.
    `foveations`: default a 2° fovea (smaller than a 2-4° tracker error) and the thesis's 10°."""
    scene, rig = _scene_rig(full, "tracking_error")
    from ...foveate import Foveation, check_gaze

    t0 = time.perf_counter()
    foveations = list(foveations) if foveations is not None else [Foveation(2.0, 4.0), Foveation.thesis(2)]
    errors = [float(e) for e in errors_deg]
    if not foveations or not errors or any(not (math.isfinite(e) and e >= 0) for e in errors):
        raise ValueError(
            f"tracking_error: need foveations and finite errors >= 0 degrees, got {errors_deg!r}"
        )
    if not directions_deg or not keys:
        raise ValueError("tracking_error: need at least one direction and one key")
    if not central_deg > 0:
        raise ValueError(f"tracking_error: central_deg must be > 0, got {central_deg}")
    true = check_gaze(
        np.broadcast_to(np.asarray(gaze, np.float64).reshape(-1, 2), (2, 2)), "tracking_error gaze"
    )
    bench = _Bench.make(full, progress)
    records = []
    for fov in foveations:
        ecc = _true_eccentricity(rig, true, fov)
        masks = {"true_fovea": ecc <= fov.fovea_deg, "central": ecc <= central_deg}
        for e in errors:
            for d in directions_deg if e > 0 else directions_deg[:1]:
                shown = offset_gaze(rig, true, e, float(d))
                for k in keys:
                    frame = bench.foveated(shown, fov, k)
                    ref = bench.reference(k)
                    maps = bench.maps(frame.image, ref)
                    row = {
                        "fovea_deg": fov.fovea_deg,
                        "periphery_deg": fov.periphery_deg,
                        "tracker_error_deg": e,
                        "direction_deg": float(d) if e > 0 else math.nan,
                        "key": int(k),
                        "shown_gaze_x": float(shown[0, 0]),
                        "shown_gaze_y": float(shown[0, 1]),
                        "measured_error_deg": _gaze_angle(rig, true, shown),
                        "true_fovea_covered": float((_side(frame.regions)[masks["true_fovea"]] == 0).mean()),
                        "primary_rays": frame.stats.primary_rays,
                    }
                    for name, mask in masks.items():
                        row.update(_masked(maps, mask, name))
                    row.update(_frame_metrics(maps, frame.image, ref))
                    records.append(row)
    m = _metric(records, "flip_true_fovea")
    parts = []
    for fov in foveations:
        vals = [
            f"{e:g}°: {_mean(records, m, fovea_deg=fov.fovea_deg, tracker_error_deg=e):.4f}" for e in errors
        ]
        parts.append(f"fovea {fov.fovea_deg:g}° — " + ", ".join(vals))
    finding = f"{m} inside the true fovea by tracker error: " + "; ".join(parts)
    params = {
        "errors_deg": tuple(errors),
        "directions_deg": tuple(directions_deg),
        "gaze": tuple(np.ravel(gaze)),
        "foveas": tuple((f.fovea_deg, f.periphery_deg) for f in foveations),
        "central_deg": central_deg,
    }
    return _case("tracking_error", "tracker error against fovea size", records, finding, params, t0)
