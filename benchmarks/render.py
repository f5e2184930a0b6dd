"""Renderer speed: milliseconds per stereo frame, and the integrator against the traversal alone.

    python benchmarks/render.py                 # atrium 262k, 2 x 1280 x 1024, both backends
    python benchmarks/render.py --quick         # 2 x 320 x 256, one repeat (a smoke run)
    python benchmarks/render.py --backends jax

For each backend ("jax": the JAX traversal; "embree": Embree through a host callback, CPU only)
it prints:

1. full frames (the thesis's Whitted settings: max depth 5, one point light) at SPP 1 and 4:
   compile seconds, the median milliseconds per frame over --repeats frames after the first,
   the rays traced by kind and the integrator's rays per second (all rays / frame time);
2. a like-for-like split at depth 0 (primary rays and the shadow rays from their hits, the bulk
   of every frame): the integrator's rays per second, against `closest_hit` + `occluded` alone
   on exactly those rays (same packets, same tmin/tmax), i.e. how much shading, sampling, env
   lookups and bookkeeping add on top of traversal.

Timings are wall-clock medians on whatever machine runs this; shared machines are noisy (read
the ratios).
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np
from _record import write_record

import fovjax
from fovjax.render import RenderConfig, StereoRig, render_stereo, scene_arrays, stereo_sample_rays
from fovjax.render._vec import dot, norm, normalize
from fovjax.render.internal import scene_scale, surface_at
from fovjax.trace import build_bvh, closest_hit, occluded


def median_seconds(fn, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def frame_row(scene, bvh, rig, *, spp, config, repeats):
    first = render_stereo(scene, rig, spp=spp, config=config, bvh=bvh)
    frames = [render_stereo(scene, rig, spp=spp, config=config, bvh=bvh) for _ in range(repeats)]
    seconds = statistics.median(f.stats.render_seconds for f in frames)
    s = frames[-1].stats
    return {
        "compile_s": first.stats.compile_seconds,
        "ms": seconds * 1e3,
        "primary": s.primary_rays,
        "shadow": s.shadow_rays,
        "reflection": s.reflection_rays,
        "mrays": s.rays / seconds / 1e6,
    }


def level0_rays(arrays, bvh, rig, config):
    """The depth-0 rays of a frame exactly as the integrator makes them: primary rays, and the
    shadow rays (origin, direction, tmax; tmax 0 where none is traced) from their hits."""

    @jax.jit
    def make(arrays):
        rays = stereo_sample_rays(rig, None, 1)
        o, d = rays.origins, rays.directions
        hit = closest_hit(bvh, o, d, packet=config.packet, vertices=arrays.vertices, backend=config.backend)
        surface = surface_at(arrays, hit, d)
        offset = config.ray_offset * scene_scale(arrays)
        light = arrays.light_position[0]
        to_light = light - surface.point
        l_dir = normalize(to_light)
        wanted = surface.found & (dot(surface.shading_normal, l_dir) > 0)
        wanted = wanted & (dot(surface.geometric_normal, l_dir) > 0)
        origin = surface.point + offset * surface.geometric_normal
        return o, d, origin[None], l_dir[None], jnp.where(wanted, norm(to_light), 0.0)[None]

    return jax.block_until_ready(make(jax.tree.map(jnp.asarray, arrays)))


def split_row(scene, arrays, bvh, rig, *, config, repeats):
    config0 = RenderConfig(max_depth=0, backend=config.backend, packet=config.packet)
    integrator = frame_row(arrays, bvh, rig, spp=1, config=config0, repeats=repeats)
    o, d, so, sd, stmax = level0_rays(arrays, bvh, rig, config0)
    primary = jax.jit(lambda o, d: closest_hit(bvh, o, d, packet=config.packet, backend=config.backend).prim)
    shadow = jax.jit(lambda o, d, t: occluded(bvh, o, d, t, packet=config.packet, backend=config.backend))
    jax.block_until_ready(primary(o, d))
    jax.block_until_ready(shadow(so, sd, stmax))
    t_primary = median_seconds(lambda: jax.block_until_ready(primary(o, d)), repeats)
    t_shadow = median_seconds(lambda: jax.block_until_ready(shadow(so, sd, stmax)), repeats)
    # The same expressions compiled in another program may round differently: a handful of
    # shadow rays with n·l within an ulp of 0 can differ; anything more would be a mistake here.
    n_shadow = int(np.count_nonzero(np.asarray(stmax) > 0))
    assert abs(n_shadow - integrator["shadow"]) <= 1e-5 * n_shadow + 2, (n_shadow, integrator["shadow"])
    rays = integrator["primary"] + integrator["shadow"]
    traversal_s = t_primary + t_shadow
    return integrator, {
        "primary_ms": t_primary * 1e3,
        "shadow_ms": t_shadow * 1e3,
        "ms": traversal_s * 1e3,
        "mrays": rays / traversal_s / 1e6,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 x 320 x 256 eyes, one repeat")
    parser.add_argument("--backends", default="jax,embree", help="comma-separated: jax, embree")
    parser.add_argument("--spp", default="1,4", help="comma-separated samples per pixel")
    parser.add_argument("--repeats", type=int, default=3, help="timed frames after the first (median)")
    parser.add_argument("--triangles", type=int, default=262_000)
    parser.add_argument("--parts", default="frames,split", help="comma-separated: frames, split")
    args = parser.parse_args(argv)
    width, height = (320, 256) if args.quick else (1280, 1024)
    repeats = 1 if args.quick else args.repeats

    start = time.perf_counter()
    scene = fovjax.scenes.atrium(triangles=args.triangles)
    bvh = build_bvh(scene)
    arrays = scene_arrays(scene)
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=width, eye_height=height)
    print(f"atrium: {scene.num_triangles:,} triangles, scene + BVH {time.perf_counter() - start:.1f} s")
    print(f"stereo {2 * width}x{height} (two {width}x{height} eyes, 90° horizontal FOV, toe-out 13°), "
          f"max depth 5, 1 point light; {jax.devices()[0].platform}, {jax.device_count()} device(s); "
          f"median of {repeats} frame(s) after the first")  # fmt: skip
    print()
    header = f"{'backend':8} {'spp':>3} {'compile s':>9} {'ms/frame':>9} {'primary':>11} {'shadow':>11} "
    header += f"{'reflection':>11} {'Mrays/s':>8}"
    print(header)
    splits, frame_rows = [], []
    for backend in args.backends.split(","):
        config = RenderConfig(backend=backend)
        for spp in (int(s) for s in args.spp.split(",")) if "frames" in args.parts else ():
            r = frame_row(arrays, bvh, rig, spp=spp, config=config, repeats=repeats)
            counts = f"{r['primary']:11,} {r['shadow']:11,} {r['reflection']:11,}"
            print(f"{backend:8} {spp:3d} {r['compile_s']:9.1f} {r['ms']:9.0f} {counts} {r['mrays']:8.2f}")
            frame_rows.append(
                [backend, spp, round(r["compile_s"], 2), round(r["ms"], 1), r["primary"], r["shadow"]]
                + [r["reflection"], round(r["mrays"], 3)]
            )
        if "split" in args.parts:
            splits.append((backend, *split_row(scene, arrays, bvh, rig, config=config, repeats=repeats)))
    print()
    print(
        "depth 0, SPP 1 (primary + shadow rays only): integrator vs the same rays through the traversal alone"
    )
    print(f"{'backend':8} {'rays':>11} {'integrator ms':>13} {'Mrays/s':>8} {'traversal ms':>12} "
          f"{'(primary + shadow)':>20} {'Mrays/s':>8} {'overhead':>8}")  # fmt: skip
    for backend, integ, trav in splits:
        rays = integ["primary"] + integ["shadow"]
        parts = f"({trav['primary_ms']:.0f} + {trav['shadow_ms']:.0f})"
        integrator = f"{integ['ms']:13.0f} {integ['mrays']:8.2f}"
        traversal = f"{trav['ms']:12.0f} {parts:>20} {trav['mrays']:8.2f}"
        print(f"{backend:8} {rays:11,} {integrator} {traversal} {integ['ms'] / trav['ms']:7.2f}x")
    tables = []
    if frame_rows:
        cols = ["backend", "SPP", "compile s", "ms / frame", "primary rays", "shadow rays", "reflection rays"]
        title = (
            f"Full stereo frames: atrium {scene.num_triangles:,} triangles, 2×{width}×{height}, max depth 5, "
            f"one point light; median of {repeats} frame(s) after the first"
        )
        tables.append({"title": title, "columns": [*cols, "Mrays/s"], "rows": frame_rows})
    if splits:
        rows = [
            [b, i["primary"] + i["shadow"], round(i["ms"], 1), round(t["ms"], 1), round(i["ms"] / t["ms"], 3)]
            for b, i, t in splits
        ]
        cols = ["backend", "rays", "integrator ms", "traversal ms", "integrator / traversal"]
        title = "Depth 0, SPP 1 (primary + shadow rays): the integrator against the traversal alone"
        tables.append({"title": title, "columns": cols, "rows": rows})
    write_record("render", {"tables": tables})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
