"""Shading fidelity per region against plain foveation, same run: rays traced and frame time.

    python benchmarks/fidelity.py                          # atrium 262k, 320x256 per eye, SPP 1
    python benchmarks/fidelity.py --triangles 20000 --width 160 --height 128 --spp 4
    python benchmarks/fidelity.py --lod none,1,2 --no-shading   # geometry level of detail only

Texture level of detail and samples per pixel per region:

    python benchmarks/fidelity.py --full-shading --spp 4 --spp-periphery 1 --spp-outside 1
    python benchmarks/fidelity.py --full-shading --textured --texture-lod auto,auto --reference-spp 16

The atrium has no texture coordinates or textures; `--textured` gives it some (this script
only): every triangle gets its own corners, UVs by planar projection along its normal's
dominant axis (one texture repeat per `--texture-metres`) and every material a procedural
512 x 512 texture (a stone-tile checker with per-texel noise). `--reference-spp N` also renders
the full (not foveated) frame at SPP N and prints each frame's mean |difference| from it per
region: the error that matters, where a coarser texture level should alias less.

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
from _record import write_record

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


def _textured(scene, metres):
    """`scene` with UVs and one procedural texture on every material (see above)."""
    import dataclasses

    faces = np.asarray(scene.faces)
    corners = np.asarray(scene.vertices)[faces]  # (F, 3, 3)
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    axis = np.argmax(np.abs(normal), axis=1)  # project along the dominant axis
    keep = np.array([[1, 2], [0, 2], [0, 1]])[axis]  # (F, 2): the other two coordinates
    uv = np.take_along_axis(corners, keep[:, None, :], axis=2) / metres  # (F, 3, 2)
    rng = np.random.default_rng(0)
    y, x = np.mgrid[:512, :512]
    tiles = ((y // 64 + x // 64) % 2).astype(np.float32)
    grain = rng.random((512, 512)).astype(np.float32)
    base = 0.55 + 0.3 * tiles[..., None] * np.array([1.0, 0.9, 0.75], np.float32)
    texture = np.clip(base * (0.6 + 0.8 * grain[..., None]), 0.0, 1.0)
    n = len(faces)
    materials = dataclasses.replace(scene.materials, texture=np.zeros(len(scene.materials.kd), np.int32))
    normals = None if scene.normals is None else np.asarray(scene.normals)[faces].reshape(-1, 3)
    return fovjax.make_scene(
        corners.reshape(-1, 3),
        np.arange(3 * n).reshape(n, 3),
        face_material=scene.face_material,
        materials=materials,
        lights=scene.lights,
        normals=normals,
        uvs=uv.reshape(-1, 2).astype(np.float32),
        textures=(texture,),
        ambient=scene.ambient,
        name="atrium",
    )


def _tex_lod(text):
    return None if text in (None, "none") else ("auto" if text == "auto" else int(text))


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
    # texture level of detail and samples per pixel per region
    parser.add_argument("--full-shading", action="store_true", help="full depth and shadows everywhere")
    parser.add_argument("--spp-periphery", type=int, default=None)
    parser.add_argument("--spp-outside", type=int, default=None)
    parser.add_argument("--textured", action="store_true", help="UVs and a procedural texture")
    parser.add_argument("--texture-metres", type=float, default=2.0)
    parser.add_argument("--texture-lod", default=None, help="PERIPHERY,OUTSIDE: none, auto or a level")
    parser.add_argument("--reference-spp", type=int, default=None)
    args = parser.parse_args(argv)

    scene = fovjax.scenes.atrium(triangles=args.triangles)
    if args.textured:
        scene = _textured(scene, args.texture_metres)
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(scene), eye_width=args.width, eye_height=args.height
    )
    config = RenderConfig()
    if args.no_shading or args.full_shading:
        args.periphery_depth = args.outside_depth = None
        args.outside_shadows = "all"
    tex_lod = [None, None] if args.texture_lod is None else [_tex_lod(x) for x in args.texture_lod.split(",")]
    fidelity = (
        Fidelity(lod=args.lod[0]),
        Fidelity(
            max_depth=args.periphery_depth, lod=args.lod[1], texture_lod=tex_lod[0], spp=args.spp_periphery
        ),
        Fidelity(
            max_depth=args.outside_depth,
            shadows=args.outside_shadows,
            lod=args.lod[2],
            texture_lod=tex_lod[1],
            spp=args.spp_outside,
        ),
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
    names = ("fovea", "periphery", "outside")
    by_region = (plain.foveation.primary_by_region, lod.foveation.primary_by_region)
    for r, name in enumerate(names):
        print(
            f"{name:10} primary rays plain {by_region[0][r]:7,} fidelity {by_region[1][r]:7,}; "
            f"mean |difference| {diff[regions == r].mean():.4f}"
        )
    title = (
        f"atrium {args.triangles} triangles, 2×{args.width}×{args.height}, SPP {args.spp}, "
        f"max depth {config.max_depth}; fidelity {fidelity}"
    )
    rows = [
        [name, s.primary_rays, s.shadow_rays, s.reflection_rays, s.rays]
        + [round(1e3 * t, 2), round(s.compile_seconds, 2)]
        for name, s, t in (("plain", plain.stats, t_plain), ("fidelity", lod.stats, t_lod))
    ]
    cols = ["", "primary", "shadow", "reflection", "rays", "frame ms", "compile s"]
    figures = {
        "tables": [{"title": title, "columns": cols, "rows": rows}],
        "rays_vs_plain": round(lod.stats.rays / plain.stats.rays, 4),
        "speedup": round(t_plain / t_lod, 3),
        "mean_abs_diff": {name: round(float(diff[regions == r].mean()), 5) for r, name in enumerate(names)},
    }
    if args.reference_spp:
        reference = fovjax.render.render_stereo(
            scene, rig, spp=args.reference_spp, key=jax.random.key(0), config=config
        ).image
        print(f"mean |difference| from the full frame at SPP {args.reference_spp}:")
        errors = {}
        for r, name in enumerate(names):
            err = [np.abs(f.image - reference).mean(axis=-1)[regions == r].mean() for f in (plain, lod)]
            print(f"{name:10} plain {err[0]:.4f} fidelity {err[1]:.4f}")
            errors[name] = [round(float(e), 5) for e in err]
        figures[f"mean_abs_diff_from_full_spp{args.reference_spp}_plain_fidelity"] = errors
    with open("/proc/loadavg") as f:
        print(f"load average: {f.read().strip()}")
    write_record("fidelity", figures)


if __name__ == "__main__":
    main()
