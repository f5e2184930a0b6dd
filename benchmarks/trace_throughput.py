"""Ray-query throughput: fovjax's backends against Embree and Mitsuba 3, same rays, one run.

    python benchmarks/trace_throughput.py              # atrium (262k triangles), 1280x1024
    python benchmarks/trace_throughput.py --quick      # 640x512 and 65k random rays
    python benchmarks/trace_throughput.py --host-devices 2   # JAX on two CPU devices (both cores)
    python benchmarks/trace_throughput.py --width 64 --height 48 --random 4096 --repeats 1   # smoke

For each ray set it prints rays per second (median of --repeats timed runs after a warm-up) of
fovjax's backends (--backends; default "auto", what every fovjax call uses — Embree through
XLA's FFI on this CPU where its handler builds — and "jax", the `while_loop` traversal), each a
jitted `closest_hit`/`occluded` on device arrays (the hit recomputation included), and of the
peers, timed on their own call alone, on arrays prepared beforehand:
- Embree (embreex `EmbreeScene.run`, contiguous float32 arrays): embreex traces one ray at a time
  with `rtcIntersect1`/`rtcOccluded1` on the calling thread and releases the GIL, so "1 thread" is
  one call and "2 threads" is the rays split in two halves, one call per Python thread;
- Mitsuba 3 (`llvm_ad_rgb`: `scene.ray_intersect_preliminary` / `scene.ray_test`, evaluated with
  `dr.eval`), which uses every core; optional (`pip install 'fovjax[bench]'`; it also needs the
  system's LLVM shared library >= 16, from Debian's package libllvm19). Its default scene, as a
  user gets it, builds Embree's BVH without Embree's robust mode; fovjax's Embree scenes use it
  (rays through a flat grid's shared edges and vertices hit: `tests/test_trace_native.py`; a ray
  aimed exactly at a closed mesh's vertex can still pass: `tests/test_trace_properties.py`),
  so "Mitsuba 3 robust" (`--peers mitsuba_robust`, on by default) is the same call on a scene
  loaded with `embree_use_robust_intersections`, the like-for-like peer; `--not-watertight`
  times fovjax without it (`BVH.with_watertight(False)`), like for like with "Mitsuba 3".
Then the ratios of the first backend (default "auto") to each peer, compile time, the hit/miss
agreement of every backend with the JAX traversal (the reference), and with Embree and Mitsuba.
"paired" is first backend / Embree-1 again, as the median over --repeats pairs of calls made back to back
(fovjax, then Embree-1), so that both see the same momentary load of a shared machine; "CPU time"
is that ratio in process CPU seconds (each side's own work, not its waits for a core; both run
their traversal on one thread, XLA:CPU's loop as measured in the notes, embreex on the caller's).

Ray sets (seeded; the same arrays for every backend):
- primary: one ray per pixel centre of the scene's default camera, traced as 8x8 packets;
- random: origins uniform in the scene's bounding box, directions uniform on the sphere, one by one;
- shadow: from each primary hit point towards the scene's first light (tmin 1e-4); "one by one"
  traces only the rays of pixels that hit something (compacted), "8x8 packets" traces the whole
  image in tiles with an empty interval (tmax = tmin) where the pixel saw nothing, "sorted" the
  compacted rays with `packet="sorted"` (regrouped by origin into packets of 64 inside the JAX
  call, the sort and the scatter back included in its time; the peers trace the same compacted
  rays one by one). Only live rays are counted.
Timings on shared machines are noisy: read the ratios of the same run.
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
from fovjax.scene import Camera
from fovjax.trace import build_bvh, closest_hit, last_build_info, occluded

MITSUBA_VARIANT = "llvm_ad_rgb"
LLVM_PACKAGE = (
    "libllvm19 (Dr.Jit needs libLLVM >= 16; Debian: apt-get install libllvm19, or set DRJIT_LIBLLVM_PATH)"
)


def timed(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def both_timed(fn):
    """(wall, process CPU) seconds of one call. CPU time counts what the call computed, not its
    waits for a core (on a loaded machine wall time also counts other jobs' turns)."""
    c0, t0 = time.process_time(), time.perf_counter()
    fn()
    return time.perf_counter() - t0, time.process_time() - c0


def paired_ratio(fn_a, fn_b, repeats):
    """Median over `repeats` back-to-back pairs of time(b) / time(a): the speed of a relative to b
    with both timed under the same momentary load; and the same in process CPU time."""
    ratios, cpu_ratios = [], []
    for _ in range(repeats):
        (t_a, c_a), (t_b, c_b) = both_timed(fn_a), both_timed(fn_b)
        ratios.append(t_b / t_a)
        cpu_ratios.append(c_b / c_a)
    return statistics.median(ratios), statistics.median(cpu_ratios)


def prepared_for_peers(o, d, tmin, tmax):
    """Rays as every peer takes them: start moved to tmin (peers start at t = 0), far distance
    tmax - tmin, invalid or empty rays given far = 0. Contiguous float32."""
    o, d = np.asarray(o, np.float32), np.asarray(d, np.float32)
    tmin, tmax = np.asarray(tmin, np.float32), np.asarray(tmax, np.float32)
    valid = np.isfinite(o).all(1) & np.isfinite(d).all(1) & (d != 0).any(1) & (tmax > tmin)
    start = np.ascontiguousarray(np.where(valid[:, None], o + tmin[:, None] * d, 0.0), np.float32)
    dirs = np.ascontiguousarray(np.where(valid[:, None], d, 1.0), np.float32)
    far = np.ascontiguousarray(np.where(valid, np.minimum(tmax - tmin, 1e37), 0.0), np.float32)
    return start, dirs, far, valid


class EmbreePeer:
    """embreex on prepared arrays; `run` writes into `dists`, so each timed call gets a fresh
    copy made before the clock starts."""

    name = "Embree"

    def __init__(self, vertices, faces):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene=self.scene, vertices=vertices, indices=faces)
        one = np.zeros((1, 3), np.float32)
        self.scene.run(one, one + 1, dists=np.ones(1, np.float32), output=1)  # commits (builds)
        self.pool = ThreadPoolExecutor(2)

    def runner(self, start, dirs, far, any_hit, threads, repeats):
        parts = [
            (np.ascontiguousarray(start[p]), np.ascontiguousarray(dirs[p]), far[p])
            for p in np.array_split(np.arange(len(start)), threads)
        ]
        fresh = [[f.copy() for _, _, f in parts] for _ in range(repeats + 1)]
        calls = iter(fresh)
        scene = self.scene

        def one(s, dd, f):
            if any_hit:
                return scene.run(s, dd, dists=f, query="OCCLUDED")
            return scene.run(s, dd, dists=f, output=1)

        def run():
            dists = next(calls)
            if threads == 1:
                return one(parts[0][0], parts[0][1], dists[0])
            futures = [self.pool.submit(one, s, dd, f) for (s, dd, _), f in zip(parts, dists, strict=True)]
            return [x.result() for x in futures]

        return run

    def hits(self, start, dirs, far, valid, any_hit):
        if any_hit:
            geom = np.asarray(self.scene.run(start, dirs, dists=far.copy(), query="OCCLUDED"))
            return valid & (geom != -1)
        res = self.scene.run(start, dirs, dists=far.copy(), output=1)
        return valid & (res["geomID"] != -1)


class MitsubaPeer:
    name = "Mitsuba"

    def __init__(self, vertices, faces, robust=False):
        import drjit as dr
        import mitsuba as mi

        mi.set_variant(MITSUBA_VARIANT)
        self.mi, self.dr = mi, dr
        mesh = mi.Mesh(
            "mesh",
            vertex_count=len(vertices),
            face_count=len(faces),
            has_vertex_normals=False,
            has_vertex_texcoords=False,
        )
        params = mi.traverse(mesh)
        params["vertex_positions"] = mi.Float(np.ascontiguousarray(vertices, np.float32).ravel())
        params["faces"] = mi.UInt32(np.ascontiguousarray(faces, np.uint32).ravel())
        params.update()
        self.scene = mi.load_dict({"type": "scene", "embree_use_robust_intersections": robust, "mesh": mesh})
        self.threads = dr.thread_count()

    def _rays(self, start, dirs, far):
        mi = self.mi
        col = lambda x, i: mi.Float(np.ascontiguousarray(x[:, i]))  # noqa: E731
        ray = mi.Ray3f(
            mi.Point3f(*(col(start, i) for i in range(3))), mi.Vector3f(*(col(dirs, i) for i in range(3)))
        )
        ray.maxt = mi.Float(far)
        self.dr.eval(ray)
        return ray

    def runner(self, start, dirs, far, any_hit, threads, repeats):
        ray, dr, scene = self._rays(start, dirs, far), self.dr, self.scene

        def run():
            if any_hit:
                out = scene.ray_test(ray)
                dr.eval(out)
            else:
                pi = scene.ray_intersect_preliminary(ray)
                dr.eval(pi.t, pi.prim_index)
            dr.sync_thread()

        return run

    def hits(self, start, dirs, far, valid, any_hit):
        ray = self._rays(start, dirs, far)
        if any_hit:
            return valid & np.asarray(self.scene.ray_test(ray), bool)
        return valid & np.isfinite(np.asarray(self.scene.ray_intersect_preliminary(ray).t))


def load_peers(vertices, faces, want):
    peers = {}
    if "embree" in want:
        try:
            peers["embree"] = EmbreePeer(vertices, faces)
        except ImportError:
            print("Embree: skipped (embreex is not installed: pip install 'fovjax[embree]')")
    if "mitsuba" in want or "mitsuba_robust" in want:
        try:
            import mitsuba  # noqa: F401
        except ImportError:
            print("Mitsuba: skipped (mitsuba is not installed: pip install 'fovjax[bench]')")
        else:
            try:
                for name, robust in (("mitsuba", False), ("mitsuba_robust", True)):
                    if name in want:
                        peers[name] = MitsubaPeer(vertices, faces, robust=robust)
            except Exception as exc:  # drjit found no LLVM: raised as ImportError by set_variant
                print(
                    f"Mitsuba: skipped, its {MITSUBA_VARIANT} variant needs the system's LLVM shared "
                    f"library, install package {LLVM_PACKAGE} ({str(exc).strip().splitlines()[-1]})"
                )
    return peers


def make_jax_query(bvh, any_hit, packet, kw, backend="auto"):
    if any_hit:
        return jax.jit(
            lambda o, d, a, b: occluded(bvh, o, d, b, tmin=a, packet=packet, backend=backend, **kw)
        )

    def query(o, d, a, b):
        hit = closest_hit(bvh, o, d, a, b, packet=packet, backend=backend, **kw)
        return hit.t, hit.prim

    return jax.jit(query)


def scene_rays(scene, width, height, n_random, seed):
    cam = Camera.from_pose(fovjax.scenes.default_camera(scene), width=width, height=height)
    o, d = cam.primary_rays()
    o = np.asarray(o, np.float32).reshape(-1, 3)
    d = np.asarray(d, np.float32).reshape(-1, 3)
    rng = np.random.default_rng(seed)
    lo, hi = scene.bounds
    centre, half = (lo + hi) / 2, (hi - lo) / 2 * 0.95
    ro = (centre + rng.uniform(-1, 1, (n_random, 3)) * half).astype(np.float32)
    rd = rng.normal(size=(n_random, 3))
    rd = (rd / np.linalg.norm(rd, axis=1, keepdims=True)).astype(np.float32)
    return (o, d), (ro, rd)


def shadow_rays(scene, po, pd, bvh):
    """Rays from every primary hit (found by the JAX backend) towards the first light."""
    hit = closest_hit(bvh, po, pd, backend="jax")
    t = np.asarray(hit.t)
    seen = np.isfinite(t)
    p = (po + pd * np.where(seen, t, 0.0)[:, None]).astype(np.float32)
    light = np.asarray(scene.lights.position, np.float32)[0]
    to_light = light - p
    dist = np.linalg.norm(to_light, axis=1)
    sd = (to_light / np.maximum(dist, 1e-12)[:, None]).astype(np.float32)
    tmin = np.full(len(po), 1e-4, np.float32)
    tmax = np.where(seen, dist * (1 - 1e-4), 1e-4).astype(np.float32)
    return p, sd, tmin, tmax, seen


def throughput_tables(rows: list[dict]) -> list[dict]:
    """The rows as the Performance page's table: Mrays/s of each backend and peer, ratios of the
    first backend (the default, "auto") to the peers, hit/miss agreement with the JAX traversal."""
    if not rows:
        return []
    backends = [b for b in fovjax.trace.BACKENDS if b in rows[0]]
    peers = [
        (k, t)
        for k, t in (
            ("embree1", "Embree 1 thread"),
            ("embree2", "Embree 2 threads"),
            ("mitsuba", "Mitsuba 3"),
            ("mitsuba_robust", "Mitsuba 3 robust"),
        )
        if k in rows[0]
    ]
    first = backends[0]
    columns = ["rays", "traversal", "rays traced", *(f"fovjax {b}" for b in backends), *(t for _, t in peers)]
    columns += [f"{first} / {t}" for _, t in peers] + [f"agreement {first} vs jax"]
    table = []
    for r in rows:
        row = [
            r["rays"],
            r["traversal"],
            r["n"],
            *(round(r[b], 2) for b in backends),
            *(round(r[k], 2) for k, _ in peers),
        ]
        row += [round(r[first] / r[k], 2) for k, _ in peers] + [round(r[f"agree_jax_{first}"], 6)]
        table.append(row)
    return [
        {
            "title": f"Mrays/s on the {rows[0]['scene']} (median of the timed calls, one run)"
            + ("" if rows[0].get("watertight", True) else "; fovjax's Embree scenes not watertight"),
            "columns": columns,
            "rows": table,
        }
    ]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="640x512 primary rays, 65k random rays")
    ap.add_argument("--scenes", nargs="+", default=["atrium"])
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=1024)
    ap.add_argument("--random", type=int, default=1 << 18, help="number of incoherent rays")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument(
        "--peers",
        nargs="*",
        default=["embree", "mitsuba", "mitsuba_robust"],
        choices=["embree", "mitsuba", "mitsuba_robust"],
    )
    ap.add_argument(
        "--rows", nargs="+", default=None, help="subset of: primary random shadow shadow8x8 shadow_sorted"
    )
    ap.add_argument("--lanes", type=int, default=None, help="JAX traversal lanes (default: library default)")
    ap.add_argument(
        "--backends",
        nargs="+",
        default=["auto", "jax"],
        choices=list(fovjax.trace.BACKENDS),
        help="fovjax backends to time (the first is the one the ratios are of; default: auto jax)",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--not-watertight",
        action="store_true",
        help="fovjax's Embree scenes without Embree's robust mode (BVH.with_watertight(False)), as "
        "Mitsuba 3 builds its scenes by default: the like-for-like row against 'Mitsuba 3'",
    )
    ap.add_argument(
        "--host-devices",
        type=int,
        default=None,
        help="CPU devices for JAX (jax_num_cpu_devices; default: JAX's, 1): with 2, closest_hit and "
        "occluded split the rays over both cores",
    )
    args = ap.parse_args(argv)
    if args.host_devices is not None:
        jax.config.update("jax_num_cpu_devices", args.host_devices)
    if args.quick:
        args.width, args.height, args.random = 640, 512, 1 << 16

    dev = jax.devices()[0]
    print(f"jax {jax.__version__} on {dev.platform} ({dev.device_kind}), {len(jax.devices())} device(s)")
    for b in args.backends:
        print(f"backend {b}: {fovjax.trace.describe_backend(b, dev.platform)}")
    first = args.backends[0]
    kw = {} if args.lanes is None else {"traversal": fovjax.trace.Traversal(lanes=args.lanes)}
    rows = []
    for name in args.scenes:
        scene = fovjax.scenes.BUILTIN[name]()
        build_bvh(scene, cache=False)
        build = last_build_info()
        bvh = build_bvh(scene)
        if args.not_watertight:
            bvh = bvh.with_watertight(False)
        v, f = np.asarray(scene.vertices, np.float32), np.asarray(scene.faces, np.int32)
        t0 = time.perf_counter()
        peers = load_peers(v, f, args.peers)
        peer_build = time.perf_counter() - t0
        print(
            f"\n{name}: {scene.num_triangles:,} triangles; BVH build {build['seconds']:.2f} s "
            f"(peers' scenes {peer_build:.2f} s), {build['num_nodes']:,} 4-wide nodes, depth "
            f"{build['depth']}, table {bvh.nbytes / 2**20:.1f} MiB"
        )
        if "mitsuba" in peers or "mitsuba_robust" in peers:
            any_mitsuba = peers.get("mitsuba") or peers["mitsuba_robust"]
            print(f"  Mitsuba {MITSUBA_VARIANT} on {any_mitsuba.threads} thread(s)")
        (po, pd), (ro, rd) = scene_rays(scene, args.width, args.height, args.random, args.seed)
        h, w = args.height, args.width
        so, sd, s_tmin, s_tmax, seen = shadow_rays(scene, po, pd, bvh)
        zeros = lambda n: np.zeros(n, np.float32)  # noqa: E731
        infs = lambda n: np.full(n, np.inf, np.float32)  # noqa: E731
        jobs = {
            "primary": ("closest_hit", "primary", (8, 8), (h, w), po, pd, zeros(h * w), infs(h * w)),
            "random": ("closest_hit", "random", None, (len(ro),), ro, rd, zeros(len(ro)), infs(len(ro))),
            "shadow": (
                "occluded",
                "shadow",
                None,
                (int(seen.sum()),),
                so[seen],
                sd[seen],
                s_tmin[seen],
                s_tmax[seen],
            ),
            "shadow8x8": ("occluded", "shadow", (8, 8), (h, w), so, sd, s_tmin, s_tmax),
            "shadow_sorted": (
                "occluded",
                "shadow",
                "sorted",
                (int(seen.sum()),),
                so[seen],
                sd[seen],
                s_tmin[seen],
                s_tmax[seen],
            ),
        }
        for key in args.rows or list(jobs):
            query, kind, packet, shape, o, d, tmin_h, tmax_h = jobs[key]
            any_hit = query == "occluded"
            n = int(np.sum(tmax_h > tmin_h))
            arrays = [jnp.asarray(x).reshape(shape + x.shape[1:]) for x in (o, d, tmin_h, tmax_h)]
            r = {
                "scene": name,
                "watertight": bvh.watertight,
                "query": query,
                "rays": kind,
                "traversal": {None: "one by one", "sorted": "sorted"}.get(packet, "8x8 packets"),
                "n": n,
            }
            fns, hits = {}, {}
            for b in dict.fromkeys([*args.backends, "jax"]):  # the JAX traversal is the reference
                fns[b] = fn = make_jax_query(bvh, any_hit, packet, kw, b)
                t0 = time.perf_counter()
                out = jax.block_until_ready(fn(*arrays))
                first_call = time.perf_counter() - t0
                hits[b] = np.asarray(out if any_hit else out[1] >= 0).reshape(-1)
                if b not in args.backends:
                    continue
                t_b = timed(lambda fn=fn, arrays=arrays: jax.block_until_ready(fn(*arrays)), args.repeats)
                r[b] = n / t_b / 1e6
                r[f"compile_{b}"] = max(first_call - t_b, 0.0)
            for b in args.backends:
                r[f"agree_jax_{b}"] = float(np.mean(hits[b] == hits["jax"]))
            fn, jax_hit = fns[first], hits[first]
            start, dirs, far, valid = prepared_for_peers(o, d, tmin_h, tmax_h)
            for pname, peer in peers.items():
                configs = [1, 2] if pname == "embree" else [peer.threads]
                for threads in configs:
                    label = f"{pname}{threads}" if pname == "embree" else pname
                    fn_p = peer.runner(start, dirs, far, any_hit, threads, 2 * args.repeats)
                    fn_p()  # warm-up (Mitsuba compiles its kernel here)
                    r[label] = n / timed(fn_p, args.repeats) / 1e6
                    if label == "embree1":
                        # fovjax and Embree-1 call after call: both see the same load (shared machine).
                        r["paired_e1"], r["cpu_e1"] = paired_ratio(
                            lambda fn=fn, arrays=arrays: jax.block_until_ready(fn(*arrays)),
                            fn_p,
                            args.repeats,
                        )
                r[f"agree_{pname}"] = float(np.mean(peer.hits(start, dirs, far, valid, any_hit) == jax_hit))
            rows.append(r)
            line = f"  {query:11s} {kind:7s} {r['traversal']:11s} {n:>9,} rays "
            line += " ".join(f"{b} {r[b]:6.2f}" for b in args.backends)
            titles = (("embree1", "Embree-1"), ("embree2", "Embree-2"), ("mitsuba", "Mitsuba"))
            for label, title in (*titles, ("mitsuba_robust", "Mitsuba-robust")):
                if label in r:
                    line += f"  {title} {r[label]:6.2f}"
            line += " Mrays/s; "
            short = (("embree1", "E1"), ("embree2", "E2"), ("mitsuba", "Mi"), ("mitsuba_robust", "MiR"))
            for label, title in short:
                if label in r:
                    line += f" {first}/{title} {r[first] / r[label]:5.2f}"
            if "paired_e1" in r:
                line += f" (paired {r['paired_e1']:5.2f}, CPU time {r['cpu_e1']:5.2f})"
            line += "; compile " + " ".join(f"{r[f'compile_{b}']:.1f}" for b in args.backends) + " s"
            line += "; agree-jax " + " ".join(f"{r[f'agree_jax_{b}']:.5f}" for b in args.backends)
            for pname in peers:
                line += f" agree-{pname} {r[f'agree_{pname}']:.5f}"
            print(line)
            sys.stdout.flush()
    return rows


if __name__ == "__main__":
    from _record import write_record

    rows = main()
    write_record("trace_throughput", {"rows": rows, "tables": throughput_tables(rows)})
