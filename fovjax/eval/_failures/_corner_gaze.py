"""`corner_gaze`: gaze at a screen corner against the centre; error and FLIP per 5° ring."""

from __future__ import annotations

import statistics
import time
from collections.abc import Sequence

import numpy as np

from .._stability import FullRenders
from ._common import (
    FailureCase,
    _Bench,
    _case,
    _frame_metrics,
    _metric,
    _ring_rows,
    _scene_rig,
    _side,
)


def corner_gaze(
    full: FullRenders,
    foveation=None,
    *,
    corner=(0.02, 0.02),
    centre=(0.5, 0.5),
    keys: Sequence[int] = (0, 1),
    ring_deg: float = 5.0,
    progress=None,
) -> FailureCase:
    """Gaze at a screen corner (both eyes) against the centre: error and FLIP per eccentricity
    ring, primary rays in the fovea, samples dropped beyond the budget."""
    scene, rig = _scene_rig(full, "corner_gaze")
    from ...foveate import Foveation, check_gaze

    t0 = time.perf_counter()
    foveation = foveation or Foveation.thesis(2)
    if not keys:
        raise ValueError("corner_gaze: need at least one key")
    bench = _Bench.make(full, progress)
    records = []
    for label, point in (("centre", centre), ("corner", corner)):
        g = check_gaze(
            np.broadcast_to(np.asarray(point, np.float64).reshape(-1, 2), (2, 2)), f"corner_gaze {label}"
        )
        for k in keys:
            frame = bench.foveated(g, foveation, k)
            ref = bench.reference(k)
            maps = bench.maps(frame.image, ref)
            ecc = _side(frame.eccentricity)
            common = {
                "gaze": label,
                "gaze_x": float(g[0, 0]),
                "gaze_y": float(g[0, 1]),
                "key": int(k),
                "primary_rays": frame.stats.primary_rays,
                "fovea_rays": frame.foveation.primary_by_region[0],
                "dropped": frame.foveation.dropped,
                **_frame_metrics(maps, frame.image, ref),
            }
            records += [{**common, **row} for row in _ring_rows(maps, frame.image, ref, ecc, ring_deg)]
    m = _metric(records, "frame_flip")
    by = {lab: statistics.mean(r[m] for r in records if r["gaze"] == lab) for lab in ("centre", "corner")}
    rays = {
        lab: statistics.mean(r["fovea_rays"] for r in records if r["gaze"] == lab)
        for lab in ("centre", "corner")
    }
    rings = [r for r in records if r["gaze"] == "corner" and np.isfinite(r["abs_error"])]
    worst = max(rings, key=lambda r: r["abs_error"])
    finding = (
        f"{m} corner {by['corner']:.4f} vs centre {by['centre']:.4f}; fovea primary rays corner "
        f"{rays['corner']:.0f} vs centre {rays['centre']:.0f}; corner's worst ring "
        f"{worst['ring_lower_deg']:g}-{worst['ring_upper_deg']:g}° |error| {worst['abs_error']:.4f}; "
        f"dropped samples {max(r['dropped'] for r in records)}"
    )
    params = {
        "corner": tuple(corner),
        "centre": tuple(centre),
        "keys": tuple(keys),
        "fovea_deg": foveation.fovea_deg,
        "periphery_deg": foveation.periphery_deg,
    }
    return _case("corner_gaze", f"gaze at corner {tuple(corner)} vs centre", records, finding, params, t0)
