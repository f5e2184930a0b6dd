"""Frames of a batch one by one, batched on one device, and batched and sharded over devices.

    python benchmarks/shard.py                       # 2 forced CPU devices, 4 frames, 160x128 per eye
    python benchmarks/shard.py --devices 4 --frames 8
    python benchmarks/shard.py --full                # the full render too

Renders the same batch of foveated stereo frames (gaze points spread over the display, a fresh
key per frame) on the atrium three ways: `render_foveated` frame by frame, `render_foveated_batch`
on one device (the frames vmapped in one program), and `render_foveated_batch` sharded over all
devices with `shard_map` (with --auto also left to jit's partitioner). Prints the median over
--repeats of the batch's wall time per frame (compile excluded, one warm-up) and the ratios.
`--devices N` forces N XLA host (CPU) devices through XLA_FLAGS before JAX starts; on a GPU
machine pass --devices 0 to use the devices there are. The machine is noisy: read the ratios of
one run.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys


def _args(argv):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--devices", type=int, default=2, help="forced CPU devices (0: leave JAX's own)")
    p.add_argument("--frames", type=int, default=4)
    p.add_argument("--width", type=int, default=160, help="pixels per eye")
    p.add_argument("--height", type=int, default=128)
    p.add_argument("--triangles", type=int, default=20_000)
    p.add_argument("--max-depth", type=int, default=5)
    p.add_argument("--spp", type=int, default=1)
    p.add_argument("--fovea", type=float, nargs=2, default=(5.0, 10.0), metavar=("FOVEA", "PERIPHERY"))
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--full", action="store_true", help="also the full render, the same three ways")
    p.add_argument(
        "--auto", action="store_true", help="also partition='auto' (loop conditions reduced over devices)"
    )
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = _args(sys.argv[1:] if argv is None else argv)
    if args.devices > 0:
        flags = os.environ.get("XLA_FLAGS", "")
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={args.devices}".strip()

    import jax
    import numpy as np
    from _record import write_record

    import fovjax
    from fovjax.eval import render_foveated_batch, render_stereo_batch
    from fovjax.foveate import Foveation, render_foveated
    from fovjax.render import RenderConfig, StereoRig, render_stereo
    from fovjax.trace import build_bvh

    devices = jax.devices()
    print(f"jax {jax.__version__}, {len(devices)} {devices[0].platform} devices, {os.cpu_count()} cores")
    scene = fovjax.scenes.atrium(triangles=args.triangles)
    bvh = build_bvh(scene)
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(scene), eye_width=args.width, eye_height=args.height
    )
    config = RenderConfig(max_depth=args.max_depth)
    fov = Foveation(fovea_deg=args.fovea[0], periphery_deg=args.fovea[1], spp=args.spp)
    rng = np.random.default_rng(0)
    gazes = [tuple(g) for g in rng.uniform(0.3, 0.7, (args.frames, 2)).round(3)]
    n = args.frames

    def keys(repeat):  # fresh keys per repeat; repeat -1 is the warm-up
        return [1000 * (repeat + 1) + i for i in range(n)]

    common = {"config": config, "bvh": bvh}

    # Every way is timed alike: the compiled program's wall time (block_until_ready), not the
    # host copies after it; one by one sums its frames' times.
    def one_by_one_foveated(repeat):
        frames = [
            render_foveated(scene, rig, gaze=(g, g), foveation=fov, key=jax.random.key(k), **common)
            for g, k in zip(gazes, keys(repeat), strict=True)
        ]
        return sum(f.stats.render_seconds for f in frames), frames[0].stats.compile_seconds

    def batch_foveated(devs, partition="shard_map"):
        def run(repeat):
            b = render_foveated_batch(
                scene,
                rig,
                gazes=gazes,
                keys=keys(repeat),
                foveation=fov,
                devices=devs,
                partition=partition,
                **common,
            )
            return b.render_seconds, b.compile_seconds

        return run

    def one_by_one_full(repeat):
        frames = [
            render_stereo(scene, rig, spp=args.spp, key=jax.random.key(k), **common) for k in keys(repeat)
        ]
        return sum(f.stats.render_seconds for f in frames), frames[0].stats.compile_seconds

    def batch_full(devs, partition="shard_map"):
        def run(repeat):
            b = render_stereo_batch(
                scene, rig, keys=keys(repeat), spp=args.spp, devices=devs, partition=partition, **common
            )
            return b.render_seconds, b.compile_seconds

        return run

    def measure(name, run):
        compile_s = run(-1)[1]  # warm-up: compiles
        times = [run(r)[0] for r in range(args.repeats)]
        ms = 1000 * statistics.median(times) / n
        per_batch = ", ".join(f"{t:.2f}" for t in times)
        print(f"  {name:<34s} {ms:9.1f} ms/frame  ({per_batch} s per batch; compile {compile_s:.1f} s)")
        return ms

    kinds = [("foveated", one_by_one_foveated, batch_foveated)]
    if args.full:
        kinds.append(("full", one_by_one_full, batch_full))
    print(
        f"atrium {args.triangles:,} triangles, {n} stereo frames of 2x{args.width}x{args.height}, "
        f"spp {args.spp}, max depth {args.max_depth}, fovea {args.fovea[0]:g}/{args.fovea[1]:g}, "
        f"median of {args.repeats}"
    )
    columns, results = [], {}
    for kind, one_by_one, batch in kinds:
        print(kind)
        single = measure("one by one (render_*)", one_by_one)
        unsharded = measure("batch, 1 device (vmap)", batch(devices[:1]))
        sharded = measure(f"batch, shard_map over {len(devices)} devices", batch(devices))
        ways = {"one by one": single, "batch, 1 device (vmap)": unsharded, "batch, shard_map": sharded}
        if args.auto:
            ways['batch, partition="auto"'] = measure(
                f"batch, jit-partitioned over {len(devices)}", batch(devices, "auto")
            )
        columns.append(kind)
        for way, ms in ways.items():
            results.setdefault(way, {})[kind] = round(ms, 2)
        print(
            f"  ratios: one-by-one / sharded {single / sharded:.2f}x, "
            f"1-device batch / sharded {unsharded / sharded:.2f}x, one-by-one / 1-device batch "
            f"{single / unsharded:.2f}x"
        )
    title = (
        f"ms per frame: atrium {args.triangles:,} triangles, {n} frames of 2×{args.width}×{args.height}, "
        f"SPP {args.spp}, depth {args.max_depth}, fovea {args.fovea[0]:g}/{args.fovea[1]:g}, "
        f"{len(devices)} {devices[0].platform} devices, median of {args.repeats}"
    )
    rows = [[way, *(by_kind.get(k) for k in columns)] for way, by_kind in results.items()]
    write_record("shard", {"tables": [{"title": title, "columns": ["", *columns], "rows": rows}]})
    return 0


if __name__ == "__main__":
    sys.exit(main())
