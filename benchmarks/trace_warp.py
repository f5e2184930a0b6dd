"""Ray-query throughput of the Warp backend against the JAX traversal, same rays, one run.

    python benchmarks/trace_warp.py                     # atrium, 1280x1024 primary, 262k random
    python benchmarks/trace_warp.py --rows primary      # primary rays only
    python benchmarks/trace_warp.py --warp-bvh sah lbvh # Warp's two mesh BVH builders (lbvh: CUDA)
    python benchmarks/trace_warp.py --width 64 --height 48 --random 4096 --repeats 1   # smoke

Both sides run inside `jax.jit` on the default JAX device (a GPU where one is visible, else the CPU,
where Warp runs its kernel on one thread) and return the same thing: the JAX side is
`closest_hit` / `occluded` with `backend="jax"` named (the default, "auto", is Warp itself on CUDA;
records before this was named, up to trace_warp-20261204T195340-7232702-h200, timed Warp in the
"JAX" column on the GPU), 8x8 packets for primary rays, one by one otherwise, as
benchmarks/trace_throughput.py; the Warp side is `fovjax.trace._warp.warp_query` on the flat rays,
followed for closest hits by the same differentiable `hit_geometry` recomputation. Ray sets
(seeded) are trace_throughput.py's: primary (one per pixel of the default camera), random (origins
in the bounding box, uniform directions), shadow (from the primary hits that saw something towards
the first light, tmin 1e-4). Prints Mrays/s (median of --repeats timed runs after a warm-up, which
also builds the Warp mesh), Warp / JAX, compile time and the hit/miss agreement.
"""

import argparse
import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from trace_throughput import scene_rays, shadow_rays  # noqa: E402

import fovjax  # noqa: E402
from fovjax.trace import (  # noqa: E402
    _warp,  # noqa: E402
    build_bvh,
    closest_hit,
    hit_geometry,
    occluded,
)
from fovjax.trace._warp import warp_query  # noqa: E402


def timed(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def first_and_timed(fn, repeats):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    t = timed(fn, repeats)
    return out, t, max(first - t, 0.0)


def bench_row(bvh, kind, o, d, tmin, tmax, packet, shape, any_hit, repeats, builders):
    """Time both backends on one ray set and print its line."""
    n = len(o)
    flat = [jnp.asarray(x) for x in (o, d, tmin, tmax)]
    shaped = [x.reshape(shape + x.shape[1:]) for x in flat]
    if any_hit:
        jax_fn = jax.jit(lambda o, d, a, b: occluded(bvh, o, d, b, tmin=a, packet=packet, backend="jax"))

        def warp_fn(bvh, o, d, a, b):
            return warp_query(bvh, o, d, a, b, None, any_hit=True)[1] >= 0
    else:

        def jax_fn(o, d, a, b):
            hit = closest_hit(bvh, o, d, a, b, packet=packet, backend="jax")
            return hit.t, hit.prim

        jax_fn = jax.jit(jax_fn)

        def warp_fn(bvh, o, d, a, b):
            t_warp, prim = warp_query(bvh, o, d, a, b, None, any_hit=False)
            t, _, _ = hit_geometry(bvh.vertices, bvh.faces, prim, o, d)
            return t_warp, prim, t  # Warp's own t, compared below; t as closest_hit returns it

    warp_fn = jax.jit(warp_fn)
    out_j, t_j, c_j = first_and_timed(lambda: jax_fn(*shaped), repeats)
    r = {"rays": kind, "n": n, "jax": n / t_j / 1e6}
    hj = np.asarray(out_j if any_hit else out_j[1] >= 0).reshape(-1)
    for builder in builders:
        # The same compiled program for every builder (the mesh id is not part of it): only the
        # first call after the release builds the mesh.
        _warp.BVH_CONSTRUCTOR = builder
        _warp.release_meshes()
        out_w, t_w, c_w = first_and_timed(lambda: warp_fn(bvh, *flat), repeats)
        t_note = ""
        hw = np.asarray(out_w if any_hit else out_w[1] >= 0)
        if not any_hit:
            tj, tw = np.asarray(out_j[0]).reshape(-1), np.asarray(out_w[0])
            both = hj & hw
            rel = np.abs(tw[both] - tj[both]) / np.maximum(np.abs(tj[both]), 1e-6)
            p999 = np.percentile(rel, 99.9) if both.any() else 0.0
            t_note = f"  Warp's own t vs JAX's: rel. diff p99.9 {p999:.1e}"
        agree = float(np.mean(hj == hw))
        r[f"warp_{builder}"], r[f"agree_{builder}"] = n / t_w / 1e6, agree
        print(
            f"  {'occluded' if any_hit else 'closest_hit':11s} {kind:7s} {n:>9,} rays  "
            f"JAX {r['jax']:7.3f}  Warp ({builder}) {r[f'warp_{builder}']:7.3f} Mrays/s  "
            f"Warp/JAX {r[f'warp_{builder}'] / r['jax']:5.2f}  compile JAX {c_j:4.1f} s, "
            f"Warp {c_w:4.1f} s (incl. mesh build)  hit/miss agree {agree:.5f}" + t_note
        )
        sys.stdout.flush()
    return r


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="atrium")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=1024)
    ap.add_argument("--random", type=int, default=1 << 18, help="number of incoherent rays")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rows", nargs="+", default=["primary", "random", "shadow"])
    ap.add_argument(
        "--warp-bvh",
        nargs="+",
        default=[_warp.BVH_CONSTRUCTOR],
        choices=["sah", "lbvh", "median"],
        help="Warp's mesh BVH builder(s) to time (each a Warp column)",
    )
    args = ap.parse_args(argv)

    dev = jax.devices()[0]
    print(f"jax {jax.__version__} on {dev.platform} ({dev.device_kind})")
    import warp

    print(f"warp {warp.config.version}")
    scene = fovjax.scenes.BUILTIN[args.scene]()
    bvh = build_bvh(scene)
    print(f"{args.scene}: {scene.num_triangles:,} triangles")
    h, w = args.height, args.width
    (po, pd), (ro, rd) = scene_rays(scene, w, h, args.random, args.seed)
    rows = []
    for kind in args.rows:
        if kind == "primary":
            o, d = po, pd
            tmin, tmax = np.zeros(h * w, np.float32), np.full(h * w, np.inf, np.float32)
            packet, shape, any_hit = (8, 8), (h, w), False
        elif kind == "random":
            o, d = ro, rd
            tmin, tmax = np.zeros(len(ro), np.float32), np.full(len(ro), np.inf, np.float32)
            packet, shape, any_hit = None, (len(ro),), False
        elif kind == "shadow":
            so, sd, s_tmin, s_tmax, seen = shadow_rays(scene, po, pd, bvh)
            o, d, tmin, tmax = so[seen], sd[seen], s_tmin[seen], s_tmax[seen]
            packet, shape, any_hit = None, (len(o),), True
        else:
            raise SystemExit(f"unknown row {kind!r} (primary, random, shadow)")
        r = bench_row(bvh, kind, o, d, tmin, tmax, packet, shape, any_hit, args.repeats, args.warp_bvh)
        rows.append(r)
    return rows


def warp_tables(rows, builders) -> list[dict]:
    """The record's table: Mrays/s of each backend per ray set."""
    columns = ["rays", "count", "JAX Mrays/s"]
    for b in builders:
        columns += [f"Warp ({b}) Mrays/s", f"Warp ({b}) / JAX", f"hit/miss agree ({b})"]
    out = []
    for r in rows:
        row = [r["rays"], r["n"], round(r["jax"], 3)]
        for b in builders:
            row += [round(r[f"warp_{b}"], 3), round(r[f"warp_{b}"] / r["jax"], 2), round(r[f"agree_{b}"], 5)]
        out.append(row)
    dev = jax.devices()[0]
    title = f"Ray queries on the atrium, Warp against the JAX traversal, {dev.platform} ({dev.device_kind})"
    return [{"title": title, "columns": columns, "rows": out}]


if __name__ == "__main__":
    from _record import write_record

    rows = main()
    builders = sorted({k[len("warp_") :] for r in rows for k in r if k.startswith("warp_")})
    write_record(
        "trace_warp", {"rows": rows, "tables": warp_tables(rows, builders), "jax_column_backend": "jax"}
    )
