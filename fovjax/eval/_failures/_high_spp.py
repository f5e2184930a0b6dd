"""`high_spp`: 1 against 16 samples per pixel at a small resolution, foveated and full."""

from __future__ import annotations

import statistics
import time
from collections.abc import Sequence

import numpy as np

from .._metrics import psnr
from .._stability import FullRenders
from ._common import (
    FailureCase,
    _Bench,
    _case,
)


def high_spp(
    scene,
    rig,
    fovea_pair: tuple[float, float] = (10.0, 20.0),
    *,
    spp: Sequence[int] = (1, 16),
    keys: Sequence[int] = (0, 1),
    gaze=(0.5, 0.5),
    config=None,
    progress=None,
) -> FailureCase:
    """Full and foveated frames at each of `spp` (give `rig` a small resolution): ms per frame
    (median over the keys' renders, compile excluded), rays, the foveated frame against the
    full one of the same spp and key, and both against a converged image — the full render at
    the largest spp with another key (with one key: the same key, which then measures only the
    foveation's bias)."""
    from ...foveate import Foveation, check_gaze

    t0 = time.perf_counter()
    spp = sorted({int(s) for s in spp})
    if not spp or any(s < 1 or int(round(s**0.5)) ** 2 != s for s in spp):
        raise ValueError(f"high_spp: spp must be positive squares (1, 4, 9, 16, ...), got {spp!r}")
    if not keys:
        raise ValueError("high_spp: need at least one key")
    g = check_gaze(np.broadcast_to(np.asarray(gaze, np.float64).reshape(-1, 2), (2, 2)), "high_spp gaze")
    bench = _Bench.make(FullRenders(scene, rig, config), progress)
    fulls, fovs = {}, {}
    for s in spp:
        fov = Foveation(fovea_deg=float(fovea_pair[0]), periphery_deg=float(fovea_pair[1]), spp=s)
        for k in keys:
            fulls[s, k] = bench.full.frame(k, s)
            bench.tick()
            fovs[s, k] = bench.foveated(g, fov, k)
    top = spp[-1]
    converged = {k: fulls[top, keys[(i + 1) % len(keys)]].image for i, k in enumerate(keys)}

    def ms(frames):
        warm = [f.stats.render_seconds for f in frames if f.stats.compile_seconds == 0] or [
            f.stats.render_seconds for f in frames
        ]
        return 1000 * statistics.median(warm)

    records = []
    for s in spp:
        full_ms = ms([fulls[s, k] for k in keys])
        fov_ms = ms([fovs[s, k] for k in keys])
        for k in keys:
            full_f, fov_f = fulls[s, k], fovs[s, k]
            row = {
                "spp": s,
                "key": int(k),
                "full_ms": full_ms,
                "foveated_ms": fov_ms,
                "speedup": full_ms / fov_ms,
                "full_rays": full_f.stats.rays,
                "foveated_rays": fov_f.stats.rays,
                "full_primary_rays": full_f.stats.primary_rays,
                "foveated_primary_rays": fov_f.stats.primary_rays,
                "ray_reduction": 1 - fov_f.stats.rays / full_f.stats.rays,
            }
            for label, test, ref in (
                ("foveated_vs_full", fov_f.image, full_f.image),
                ("foveated_vs_converged", fov_f.image, converged[k]),
                ("full_vs_converged", full_f.image, converged[k]),
            ):
                maps = bench.maps(test, ref)
                row[f"psnr_{label}"] = psnr(test, ref).value
                row[f"abs_{label}"] = float(maps["abs"].mean())
                if "flip" in maps:
                    row[f"flip_{label}"] = float(maps["flip"].mean())
            records.append(row)
    m = "flip" if "flip_foveated_vs_full" in records[0] else "abs"
    parts = []
    for s in spp:
        rows = [r for r in records if r["spp"] == s]
        parts.append(
            f"spp {s}: speed-up {rows[0]['speedup']:.1f}x "
            f"({rows[0]['full_ms']:.0f} vs {rows[0]['foveated_ms']:.0f} ms), "
            f"{m} vs full {statistics.mean(r[f'{m}_foveated_vs_full'] for r in rows):.4f}, vs converged "
            f"foveated {statistics.mean(r[f'{m}_foveated_vs_converged'] for r in rows):.4f} / full "
            f"{statistics.mean(r[f'{m}_full_vs_converged'] for r in rows):.4f}"
        )
    finding = "; ".join(parts)
    params = {
        "spp": tuple(spp),
        "keys": tuple(keys),
        "resolution": (rig.eye_width, rig.eye_height),
        "fovea_pair": tuple(fovea_pair),
    }
    return _case(
        "high_spp",
        f"samples per pixel at {rig.eye_width}x{rig.eye_height} per eye",
        records,
        finding,
        params,
        t0,
    )
