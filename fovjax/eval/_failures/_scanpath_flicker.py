"""`scanpath_flicker`: `temporal_stability` along a synthetic scanpath, fresh against fixed key."""

from __future__ import annotations

import time

from .._metrics import HmdDisplay
from .._stability import FullRenders, temporal_stability
from ._common import (
    FailureCase,
    _Bench,
    _case,
    _scene_rig,
)


def scanpath_flicker(
    full: FullRenders,
    foveation=None,
    *,
    seed: int = 3,
    frames: int = 16,
    fps: float = 90.0,
    lead_frames: int = 4,
    progress=None,
) -> FailureCase:
    """`temporal_stability` along `fovjax.devices.Scanpath(seed)` (its degree scale set to the
    rig's field of view) from `lead_frames` before its first saccade, fresh against fixed key;
    the rows are its per-step records."""
    scene, rig = _scene_rig(full, "scanpath_flicker")
    from ...devices import Scanpath
    from ...foveate import Foveation

    t0 = time.perf_counter()
    foveation = foveation or Foveation.thesis(2)
    cam = rig.eye_cameras()[0]
    hfov = HmdDisplay.from_camera(cam).hfov_deg
    path = Scanpath(seed, display_fov_deg=(hfov, float(cam.vfov_deg)))
    # Start `lead_frames` before the first saccade, so the window holds gaze motion.
    onset = next(start for kind, start, _, _ in path.segments_until(60.0) if kind == "saccade")
    start_s = max(0.0, onset - lead_frames / fps)
    bench = _Bench.make(full, progress)
    result = temporal_stability(
        bench.full,
        lambda t: path.position(t + start_s),
        foveation,
        frames=frames,
        fps=fps,
        seed=seed,
        progress=bench.tick,
    )
    by = {r["key_mode"]: r for r in result.summary}
    finding = (
        "flicker beyond the fovea / full fresh-key render's: fresh key "
        f"{by['fresh']['ratio_beyond_fovea']:.2f}, "
        f"fixed key {by['fixed']['ratio_beyond_fovea']:.2f} (full fixed-key render: "
        f"{by['fixed']['full_same_policy_flicker_beyond_fovea']:.4f}); periphery band fresh "
        f"{by['fresh']['ratio_periphery']:.2f} / fixed {by['fixed']['ratio_periphery']:.2f}; mean gaze step "
        f"{by['fresh']['mean_gaze_step_deg']:.2f}° per frame"
    )
    params = {
        "seed": seed,
        "start_s": start_s,
        "frames": frames,
        "fps": fps,
        "fovea_deg": foveation.fovea_deg,
        "periphery_deg": foveation.periphery_deg,
    }
    return _case(
        "scanpath_flicker",
        f"flicker along a scanpath (seed {seed}), fresh vs fixed key",
        result.records,
        finding,
        params,
        t0,
    )
