"""Ray-query throughput: fovjax's JAX traversal against Embree, same rays, same process.

    python benchmarks/trace_throughput.py            # atrium (262k) and Cornell box, 1280x1024
    python benchmarks/trace_throughput.py --quick    # smaller ray counts, for a quick check

For each scene and ray type it prints rays per second (median of --repeats timed runs after a
warm-up) of `closest_hit` and `occluded` on the JAX backend and on Embree (embreex, 1 thread;
and the rays split over 2 threads), the ratios, compile time, BVH build time, table memory, and
how far the two backends agree. Timings on shared machines are noisy: read the ratios.

Ray sets:
- "primary": one ray per pixel centre of the scene's default camera (coherent);
- "random": origins uniform in the scene's bounding box, directions uniform on the sphere
  (incoherent), seeded;
- "shadow" (occluded only): from each primary hit point towards the scene's first light.
Primary and shadow rays are traced as 8x8 packets (and primary rays also one by one); random
rays one by one.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import jax
import jax.numpy as jnp
import numpy as np

import fovjax
from fovjax._camera import Camera
from fovjax.trace import build_bvh, closest_hit, last_build_info, occluded
from fovjax.trace._embree import embree_scene, embree_trace_host


def timed(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def embree_runner(scene, o, d, tmin, tmax, any_hit, threads):
    if threads == 1:
        return lambda: embree_trace_host(scene, o, d, tmin, tmax, any_hit)
    parts = np.array_split(np.arange(len(o)), threads)
    pool = ThreadPoolExecutor(threads)

    def run():
        futures = [
            pool.submit(embree_trace_host, scene, o[p], d[p], tmin[p], tmax[p], any_hit) for p in parts
        ]
        return [f.result() for f in futures]

    return run


def make_jax_query(bvh, any_hit, packet, kw):
    if any_hit:
        return jax.jit(lambda o, d, a, b: occluded(bvh, o, d, b, tmin=a, packet=packet, **kw))
    return jax.jit(lambda o, d, a, b: closest_hit(bvh, o, d, a, b, packet=packet, **kw).prim)


def scene_rays(scene, width, height, n_random, seed):
    cam = Camera.from_pose(fovjax.scenes.default_camera(scene), width=width, height=height)
    o, d = cam.primary_rays()
    o = np.asarray(o).reshape(-1, 3)
    d = np.asarray(d).reshape(-1, 3)
    rng = np.random.default_rng(seed)
    lo, hi = scene.bounds
    centre, half = (lo + hi) / 2, (hi - lo) / 2 * 0.95
    ro = (centre + rng.uniform(-1, 1, (n_random, 3)) * half).astype(np.float32)
    rd = rng.normal(size=(n_random, 3))
    rd = (rd / np.linalg.norm(rd, axis=1, keepdims=True)).astype(np.float32)
    return {"primary": (o, d), "random": (ro, rd)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="640x512 primary rays, 65k random rays")
    ap.add_argument("--scenes", nargs="+", default=["atrium", "cornell_box"])
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=1024)
    ap.add_argument("--random", type=int, default=1 << 18, help="number of incoherent rays")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--lanes", type=int, default=None, help="JAX traversal lanes (default: library default)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.quick:
        args.width, args.height, args.random = 640, 512, 1 << 16

    print(f"jax {jax.__version__} on {jax.devices()[0].platform}, {len(jax.devices())} device(s)")
    kw = {} if args.lanes is None else {"lanes": args.lanes}
    rows = []
    for name in args.scenes:
        scene = fovjax.scenes.BUILTIN[name]()
        build_bvh(scene, cache=False)
        build = last_build_info()
        bvh = build_bvh(scene)
        v, f = np.asarray(scene.vertices), np.asarray(scene.faces)
        t0 = time.perf_counter()
        escene = embree_scene(bvh.key, v, f)
        embree_trace_host(
            escene, v[:1], np.ones((1, 3), np.float32), np.zeros(1, np.float32), np.ones(1, np.float32), False
        )
        embree_build = time.perf_counter() - t0
        print(
            f"\n{name}: {scene.num_triangles:,} triangles; BVH build {build['seconds']:.2f} s "
            f"(Embree {embree_build:.2f} s), {build['num_nodes']:,} 4-wide nodes, depth {build['depth']}, "
            f"table {bvh.nbytes / 2**20:.1f} MiB"
        )
        rays = scene_rays(scene, args.width, args.height, args.random, args.seed)
        h, w = args.height, args.width
        # Shadow rays from every primary hit towards the first light; pixels that see nothing
        # get an empty interval (tmax = tmin) and are not counted.
        po, pd = rays["primary"]
        zeros = np.zeros(len(po), np.float32)
        ph_t, ph_prim = embree_trace_host(escene, po, pd, zeros, np.full(len(po), np.inf, np.float32), False)
        hit = ph_prim >= 0
        p = po + pd * np.where(hit, ph_t, 0.0)[:, None]
        light = np.asarray(scene.lights.position)[0]
        to_light = light - p
        dist = np.linalg.norm(to_light, axis=1)
        sd = (to_light / dist[:, None]).astype(np.float32)
        s_tmin = np.full(len(po), 1e-4, np.float32)
        s_tmax = np.where(hit, dist * (1 - 1e-4), 1e-4).astype(np.float32)
        inf = np.full(len(po), np.inf, np.float32)
        n_rand = len(rays["random"][0])
        jobs = [
            ("closest_hit", "primary", (8, 8), (h, w), po, pd, zeros, inf),
            ("closest_hit", "primary", None, (h, w), po, pd, zeros, inf),
            ("closest_hit", "random", None, (n_rand,), *rays["random"], zeros[:n_rand], inf[:n_rand]),
            ("occluded", "shadow", (8, 8), (h, w), p.astype(np.float32), sd, s_tmin, s_tmax),
            ("occluded", "random", None, (n_rand,), *rays["random"], zeros[:n_rand], inf[:n_rand]),
        ]
        for query, kind, packet, shape, o, d, tmin_h, tmax_h in jobs:
            any_hit = query == "occluded"
            n = int(np.sum(tmax_h > tmin_h))
            arrays = [jnp.asarray(x).reshape(shape + x.shape[1:]) for x in (o, d, tmin_h, tmax_h)]
            fn = make_jax_query(bvh, any_hit, packet, kw)
            t0 = time.perf_counter()
            out = jax.block_until_ready(fn(*arrays))
            first = time.perf_counter() - t0
            t_jax = timed(lambda fn=fn, arrays=arrays: jax.block_until_ready(fn(*arrays)), args.repeats)
            compile_s = max(first - t_jax, 0.0)
            t_e1 = timed(embree_runner(escene, o, d, tmin_h, tmax_h, any_hit, 1), args.repeats)
            t_e2 = timed(embree_runner(escene, o, d, tmin_h, tmax_h, any_hit, 2), args.repeats)
            _, e_prim = embree_trace_host(escene, o, d, tmin_h, tmax_h, any_hit)
            out = np.asarray(out).reshape(-1)
            agree = np.mean((out if any_hit else out >= 0) == (e_prim >= 0))
            r = {
                "scene": name,
                "query": query,
                "rays": kind,
                "traversal": "packet 8x8" if packet else "single",
                "n": n,
                "jax": n / t_jax / 1e6,
                "e1": n / t_e1 / 1e6,
                "e2": n / t_e2 / 1e6,
                "compile": compile_s,
                "agree": agree,
            }
            rows.append(r)
            print(
                f"  {query:11s} {kind:7s} {r['traversal']:10s} {n:>9,} rays  JAX {r['jax']:6.3f}  "
                f"Embree-1 {r['e1']:6.3f}  Embree-2 {r['e2']:6.3f} Mrays/s  "
                f"JAX/E1 {r['jax'] / r['e1']:5.3f}  JAX/E2 {r['jax'] / r['e2']:5.3f}  "
                f"compile {compile_s:4.1f} s  hit/miss agree {agree:.5f}"
            )
            sys.stdout.flush()
    return rows


if __name__ == "__main__":
    main()
