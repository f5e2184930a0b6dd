"""Level of detail: time to decimate the atrium to its levels (cold, into an empty cache, then
again from the cache), each level's triangle count and measured error, against the peer call
trimesh users make (`Trimesh.simplify_quadric_decimation`, the same fast-simplification library
on the whole mesh, no attributes, no error measure).

    python benchmarks/lod.py                     # atrium 262k, ratios 1, 0.5, 0.25, 0.1
    python benchmarks/lod.py --triangles 8000    # a small atrium (a smoke run)

Prints wall-clock seconds (shared machines are noisy: read the same-run ratio) and the process
CPU seconds of the cold call.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import trimesh
from _record import write_record

import fovjax
from fovjax.scene import DEFAULT_RATIOS, lod_levels


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triangles", type=int, default=262_000)
    args = ap.parse_args()
    scene = fovjax.scenes.atrium(triangles=args.triangles)
    with tempfile.TemporaryDirectory() as cache:
        os.environ["FOVJAX_CACHE_DIR"] = cache
        t0, c0 = time.perf_counter(), time.process_time()
        cold = lod_levels(scene, DEFAULT_RATIOS)
        cold_s, cold_cpu = time.perf_counter() - t0, time.process_time() - c0
        t0 = time.perf_counter()
        warm = lod_levels(scene, DEFAULT_RATIOS)
        warm_s = time.perf_counter() - t0
    assert not cold.from_cache and warm.from_cache and warm.errors == cold.errors
    mesh = trimesh.Trimesh(scene.vertices, scene.faces, process=False)
    t0 = time.perf_counter()
    for r in DEFAULT_RATIOS[1:]:
        mesh.simplify_quadric_decimation(face_count=round(r * scene.num_triangles))
    peer_s = time.perf_counter() - t0
    print(f"atrium {scene.num_triangles} triangles, ratios {DEFAULT_RATIOS}")
    print("level  ratio  triangles  error_m")
    for i, (r, n, e) in enumerate(zip(cold.ratios, cold.triangles, cold.errors, strict=True)):
        print(f"{i:5d}  {r:5.2f}  {n:9d}  {e:.4f}")
    print(f"lod_levels cold: {cold_s:.2f} s wall ({cold_cpu:.2f} s CPU); from cache: {warm_s:.3f} s")
    print(f"peer trimesh simplify_quadric_decimation, same ratios: {peer_s:.2f} s wall")
    print(f"ratio lod_levels cold / peer: {cold_s / peer_s:.2f}")
    levels = {
        "title": f"Levels of the atrium ({scene.num_triangles:,} triangles)",
        "columns": ["level", "ratio", "triangles", "error (m)"],
        "rows": [
            [i, r, int(n), round(float(e), 5)]
            for i, (r, n, e) in enumerate(zip(cold.ratios, cold.triangles, cold.errors, strict=True))
        ],
    }
    write_record(
        "lod",
        {
            "tables": [levels],
            "cold_s_wall": round(cold_s, 3),
            "cold_s_cpu": round(cold_cpu, 3),
            "from_cache_s": round(warm_s, 4),
            "peer_trimesh_simplify_s": round(peer_s, 3),
        },
    )


if __name__ == "__main__":
    main()
