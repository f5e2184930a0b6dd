"""`fovjax render`: render a built-in scene or a scene file to an image."""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "render",
        help="render a scene to an image (default: the atrium, normal/depth preview)",
        description="Render a built-in scene (atrium, cornell_box, spheres) or a scene file with the "
        "scene's default camera. For now the image is the geometry preview: primary rays, "
        "coloured by surface normal and darkened with depth.",
    )
    p.add_argument("--scene", default="atrium", help="built-in scene name or a path (OBJ, glTF/GLB, PLY)")
    p.add_argument("--triangles", type=int, default=262_000, help="atrium size (triangles)")
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--height", type=int, default=1024)
    p.add_argument("-o", "--output", default=None, help="output image (.png, .exr); default out/SCENE.png")
    p.set_defaults(func=run)


def run(args) -> int:
    import jax
    import numpy as np

    import fovjax
    from fovjax._image import save_image
    from fovjax._preview import normal_depth_image_jit
    from fovjax.trace import build_bvh, last_build_info

    t0 = time.perf_counter()
    if args.scene in fovjax.scenes.BUILTIN:
        kwargs = {"triangles": args.triangles} if args.scene == "atrium" else {}
        scene = fovjax.scenes.BUILTIN[args.scene](**kwargs)
    else:
        scene = fovjax.load_scene(args.scene)
    t_scene = time.perf_counter() - t0
    bvh = build_bvh(scene)
    build = last_build_info()
    camera = fovjax.Camera.from_pose(
        fovjax.scenes.default_camera(scene), width=args.width, height=args.height
    )

    t0 = time.perf_counter()
    image = jax.block_until_ready(normal_depth_image_jit(bvh, camera))
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    image = jax.block_until_ready(normal_depth_image_jit(bvh, camera))
    trace_s = time.perf_counter() - t0

    out = Path(args.output or f"out/{scene.name}.png")
    save_image(out, np.asarray(image))
    rays = args.width * args.height
    print(f"scene {scene.name}: {scene.num_triangles:,} triangles (built in {t_scene:.2f} s)")
    cached = " (from cache)" if build["from_cache"] else ""
    print(f"BVH: {build['num_nodes']:,} nodes in {build['seconds']:.2f} s{cached}")
    print(
        f"traced {rays:,} primary rays in {trace_s:.3f} s ({rays / trace_s / 1e6:.2f} Mrays/s, "
        f"on {jax.devices()[0].platform}); first call incl. compile {first:.2f} s"
    )
    print(f"wrote {out.resolve()}")
    return 0
