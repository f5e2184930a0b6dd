"""Shading fidelity per region against plain foveation, same run: rays traced and frame time.

    python benchmarks/fidelity.py                          # atrium 262k, 320x256 per eye, SPP 1
    python benchmarks/fidelity.py --triangles 20000 --width 160 --height 128 --spp 4
    python benchmarks/fidelity.py --lod none,1,2 --no-shading   # geometry level of detail only

Plain foveation (thesis pair 0) against the same foveation with `fidelity=(full, periphery,
outside)` (default: periphery one reflection bounce, outside no reflections and no shadow rays),
both at the render config's default max depth. Stereo, gaze off-centre, head still; each frame
time is the median of --repeats frames after a warm-up (compile reported separately, not in
the times), each frame with a fresh key. The machine is noisy: read the ratio. Also prints the
mean absolute difference of the two images (linear RGB) per region, to show what it costs.

`--lod F,P,O`: geometry level of detail per region (`Fidelity.lod`: none, a level index into the
atrium's levels at the default ratios (1, 0.5, 0.25, 0.1), or auto); with `--no-shading` the
regions keep full shading, so only the geometry differs. Plain and fidelity frames alternate
(one of each per repeat), so load changes on a shared machine hit both alike.
"""

from __future__ import annotations

import argparse
import statistics

import jax
import numpy as np

import fovjax
from fovjax.foveate import Fidelity, Foveation, render_foveated
from fovjax.render import RenderConfig, StereoRig

GAZE = ((0.35, 0.45), (0.3, 0.45))


def _frames(scene, rig, foveations, config, repeats):
    """First frame (compiles) of each foveation, then `repeats` rounds of one frame each."""
    first = [
        render_foveated(scene, rig, gaze=GAZE, foveation=f, key=jax.random.key(0), config=config)
        for f in foveations
    ]
    times = [[] for _ in foveations]
    for i in range(repeats):
        for f, t in zip(foveations, times, strict=True):
            frame = render_foveated(
                scene, rig, gaze=GAZE, foveation=f, key=jax.random.key(i + 1), config=config
            )
            t.append(frame.stats.render_seconds)
    return first, [statistics.median(t) for t in times]


def _lod(text):
    parts = text.split(",")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"--lod needs three values (fovea,periphery,outside), got {text!r}")
    return tuple(None if p == "none" else p if p == "auto" else int(p) for p in parts)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--triangles", type=int, default=262_000)
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--height", type=int, default=256)
    parser.add_argument("--spp", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--periphery-depth", type=int, default=1)
    parser.add_argument("--outside-depth", type=int, default=0)
    parser.add_argument("--outside-shadows", default="none")
    parser.add_argument("--lod", type=_lod, default=(None, None, None))
    parser.add_argument("--no-shading", action="store_true", help="full shading everywhere (only --lod)")
    args = parser.parse_args(argv)

    scene = fovjax.scenes.atrium(triangles=args.triangles)
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(scene), eye_width=args.width, eye_height=args.height
    )
    config = RenderConfig()
    if args.no_shading:
        fidelity = tuple(Fidelity(lod=lod) for lod in args.lod)
    else:
        fidelity = (
            Fidelity(lod=args.lod[0]),
            Fidelity(max_depth=args.periphery_depth, lod=args.lod[1]),
            Fidelity(max_depth=args.outside_depth, shadows=args.outside_shadows, lod=args.lod[2]),
        )
    plain_f = Foveation.thesis(0, spp=args.spp)
    lod_f = Foveation.thesis(0, spp=args.spp, fidelity=fidelity)
    (plain, lod), (t_plain, t_lod) = _frames(scene, rig, (plain_f, lod_f), config, args.repeats)
    print(
        f"atrium {args.triangles} triangles, 2 x {args.width}x{args.height}, SPP {args.spp}, "
        f"max_depth {config.max_depth}"
    )
    print(f"fidelity: {fidelity}")
    print(
        f"{'':10} {'primary':>9} {'shadow':>9} {'reflection':>11} {'total':>9} "
        f"{'frame ms':>9} {'compile s':>9}"
    )
    for name, f, t in (("plain", plain, t_plain), ("fidelity", lod, t_lod)):
        s = f.stats
        print(
            f"{name:10} {s.primary_rays:9,} {s.shadow_rays:9,} {s.reflection_rays:11,} {s.rays:9,} "
            f"{1e3 * t:9.1f} {s.compile_seconds:9.1f}"
        )
    print(f"rays: {lod.stats.rays / plain.stats.rays:.3f} x plain; frame time: {t_plain / t_lod:.2f}x faster")
    regions = np.concatenate([plain.regions[0], plain.regions[1]], axis=1)
    diff = np.abs(lod.image - plain.image).mean(axis=-1)
    for r, name in enumerate(("fovea", "periphery", "outside")):
        print(f"mean |difference| {name}: {diff[regions == r].mean():.4f}")


if __name__ == "__main__":
    main()
