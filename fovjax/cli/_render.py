"""`fovjax render`: Whitted-ray-trace a built-in scene or a scene file to an image.

With no arguments: the atrium, stereo (the thesis HMD: two 1280 x 1024 eyes side by side), one
sample per pixel, foveated around the display centres (fovea 5°, periphery 10°), written to
out/atrium.png, and the full render of the same frame for comparison (out/atrium_full.png), with
both ray counts and times printed. `--full` renders only the full frame; `--preview` draws the
geometry preview (primary rays only, coloured by surface normal and darkened with depth).
`--preset thesis` renders with the thesis's whole configuration (`fovjax.foveate.thesis_preset`).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from fovjax import cli
from fovjax._startup import describe_malloc

SCENE_ALIASES = {"cornell": "cornell_box"}
# How long a first run's build and compiles usually take: benchmarks/first_render.py's records
# (benchmarks/results/first_render-*), the atrium's 2 x 1280x1024 frames on a shared 2-core CPU.
HANDLERS_TYPICAL = "about 15 s on 2 cores"
PROGRAMS_TYPICAL = "about 5 s each"


def _head(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"--head takes YAW,PITCH,ROLL in degrees, got {text!r}")
    return values


def _gaze(text: str) -> tuple[tuple[float, float], tuple[float, float]]:
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        v = ()
    if len(v) != 4:
        raise argparse.ArgumentTypeError(
            f"--gaze takes LX,LY,RX,RY (normalised display coordinates per eye), got {text!r}"
        )
    return (v[0], v[1]), (v[2], v[3])


def _skip(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        values = (-1,)
    if any(v < 0 for v in values):
        raise argparse.ArgumentTypeError(
            f"--scene-skip takes file indices from 0, separated by commas (e.g. 2,4), got {text!r}"
        )
    return values


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "render",
        help="ray-trace a scene (default: the atrium, stereo, as on the thesis's HMD)",
        description="Whitted ray tracing (Blinn-Phong, shadow rays, reflections) of a built-in scene "
        "(atrium, cornell, spheres) or a scene file, from the scene's default viewpoint. Stereo by default: "
        "the thesis HMD (two 1280x1024 eyes, 90 degree horizontal field of view each, toed out 13 degrees, "
        "64 mm apart) side by side. PNG output is clipped and sRGB-encoded; EXR/HDR keep linear radiance.",
    )
    p.add_argument(
        "--scene",
        default="atrium",
        help="atrium, cornell, spheres, or a path (OBJ, glTF/GLB, PLY): a file, or a folder or a quoted "
        "glob pattern whose files make one scene",
    )
    p.add_argument(
        "--scene-skip",
        type=_skip,
        default=(),
        metavar="I,J,...",
        help="leave out these files of a scene of many, counted from 0 in name order with numbers "
        "compared as numbers (the thesis's Sponza: --scene 'sponza_*.obj' --scene-skip 2,4 --scene-scale 2)",
    )
    p.add_argument(
        "--scene-scale", type=float, default=1.0, help="multiply a scene file's positions (default 1)"
    )
    view = p.add_mutually_exclusive_group()
    view.add_argument(
        "--stereo", dest="stereo", action="store_true", default=True, help="both eyes (default)"
    )
    view.add_argument("--mono", dest="stereo", action="store_false", help="one camera")
    p.add_argument(
        "--spp",
        type=int,
        default=None,
        help="samples per pixel: 1, 4, 9, 16, ... (default 1; 4 with --preset thesis)",
    )
    p.add_argument(
        "--preset",
        choices=("thesis",),
        default=None,
        help="thesis: the thesis's whole configuration (docs/thesis.md): its regions (planar eccentricity "
        "at 16 px/degree, replacing --regions) and sampling (rule thesis-measured), the blur over every "
        "pixel, Blinn-Phong with the n.l payload on the specular, the contribution cut-off 0.01, the "
        "background 'bg color', depth 5 and SPP 4; --fovea/--periphery, --spp, --max-depth and the "
        "rest stay options",
    )
    p.add_argument("--seed", type=int, default=None, help="jitter the samples with this PRNG seed")
    p.add_argument(
        "--head",
        type=_head,
        default=(0.0, 0.0, 0.0),
        metavar="YAW,PITCH,ROLL",
        help="head pose in degrees (InertiaCube convention: yaw right, pitch up, roll right ear down)",
    )
    p.add_argument(
        "--envmap",
        default=None,
        help="lat-long environment map (.hdr, .exr, .png, ...) that rays which miss every surface see (the "
        "thesis's miss program samples one); without it they see the constant background colour "
        "(0.34, 0.55, 0.85), the thesis's OptiX 'bg color', not an environment map",
    )
    from fovjax import cli

    cli.add_regions(p)
    p.add_argument("--max-depth", type=int, default=5, help="reflection bounces (default 5, as the thesis)")
    p.add_argument("--width", type=int, default=1280, help="pixels per eye (stereo) or image width (mono)")
    p.add_argument("--height", type=int, default=1024)
    p.add_argument("--triangles", type=int, default=262_000, help="atrium size (triangles)")
    cli.add_backend(p)
    p.add_argument("--exposure", type=float, default=1.0, help="PNG exposure (linear scale before the clip)")
    p.add_argument("--tonemap", default="clip", choices=("clip", "reinhard"), help="PNG tone curve")
    p.add_argument("--preview", action="store_true", help="geometry preview (normal and depth) instead")
    p.add_argument(
        "--gaze",
        type=_gaze,
        default=((0.5, 0.5), (0.5, 0.5)),
        metavar="LX,LY,RX,RY",
        help="gaze per eye in normalised display coordinates, (0,0) top-left (default: the centres)",
    )
    p.add_argument("--fovea", type=float, default=5.0, help="fovea eccentricity in degrees (default 5)")
    p.add_argument("--periphery", type=float, default=10.0, help="periphery eccentricity (default 10)")
    p.add_argument("--full", action="store_true", help="render the full frame only (no foveation)")
    p.add_argument(
        "--no-reference", action="store_true", help="skip the full render next to the foveated one"
    )
    p.add_argument("--show-samples", action="store_true", help="also write the regions/samples debug view")
    p.add_argument(
        "-o", "--output", default=None, help="output image (.png, .exr, .hdr); default out/SCENE.png"
    )
    cli.add_size_check(p)
    p.set_defaults(func=run)


def _progress(step: int, total: int, text: str) -> None:
    print(f"[{step}/{total}] {text}", file=sys.stderr, flush=True)


def _load_scene(args):
    import fovjax

    name = SCENE_ALIASES.get(args.scene, args.scene)
    if name in fovjax.scenes.BUILTIN:
        kwargs = {"triangles": args.triangles} if name == "atrium" else {}
        return fovjax.scenes.BUILTIN[name](**kwargs)
    skip, scale = getattr(args, "scene_skip", ()), getattr(args, "scene_scale", 1.0)
    return fovjax.load_scene(args.scene, skip=skip, scale=scale)


def validate(args) -> Path:
    """Every argument of `fovjax render`, before anything is built or compiled; returns the
    output path."""
    from fovjax.files import HDR_SUFFIXES
    from fovjax.trace import start_embree_build

    files = cli.scene(args.scene)
    cli.number(args.scene_scale, "--scene-scale", gt=0)
    if not files and (args.scene_skip or args.scene_scale != 1.0):
        raise cli.UsageError(
            f"--scene-skip and --scene-scale apply to scene files, not the built-in {args.scene}"
        )
    for index in args.scene_skip:
        if index >= len(files):
            raise cli.UsageError(
                f"--scene-skip {index}: out of range, --scene {args.scene} has {len(files)} "
                f"file{'s' if len(files) != 1 else ''} (indices 0 to {len(files) - 1})"
            )
    if files and len(set(args.scene_skip)) == len(files):
        raise cli.UsageError(f"--scene-skip leaves none of the {len(files)} files of --scene {args.scene}")
    if args.spp is None:  # the preset's own (the thesis's user study: 4), else 1
        from fovjax.foveate import thesis_preset

        args.spp = thesis_preset().foveation.spp if args.preset == "thesis" else 1
    cli.squares(args.spp, "--spp")
    cli.seed(args.seed)
    cli.number(args.width, "--width", ge=1)
    cli.number(args.height, "--height", ge=1)
    cli.number(args.max_depth, "--max-depth", ge=0)
    cli.number(args.triangles, "--triangles", ge=1)
    cli.backend(args.backend)
    cli.number(args.exposure, "--exposure", gt=0)
    cli.head_gaze_fovea(args)
    args.envmap_image = None
    if args.envmap is not None:
        from fovjax.render import load_envmap

        cli.input_file(args.envmap, "--envmap")
        try:  # loaded here, once: a file that does not decode is refused before any work
            args.envmap_image = load_envmap(args.envmap)
        except (ValueError, OSError) as err:
            raise cli.UsageError(f"--envmap {args.envmap}: {err}") from None
    suffixes = (".png", *HDR_SUFFIXES)
    if args.preview:
        out = cli.output(
            Path(args.output or f"out/{_scene_name(args)}_preview.png"), "-o", suffixes=(".png",)
        )
    else:
        out = cli.output(args.output or f"out/{_scene_name(args)}.png", "-o", suffixes=suffixes)
        if args.stereo and not args.full and not args.no_reference:
            cli.output(out.with_name(out.stem + "_full" + out.suffix), "-o (the full render beside it)")
        if args.show_samples:
            cli.output(out.with_name(out.stem + "_samples.png"), "--show-samples")
    # Every value is checked: the native handlers (first run only) compile from here on, in the
    # background, while the size check (which estimates for the integrator they will run) and
    # the scene and its BVH go on.
    args.native_build = start_embree_build()
    if not args.stereo or args.preview:
        cli.frame_size(args, args.width, args.height, args.spp, kinds=("full",), eyes=1)
    else:
        foveated = not args.full
        kinds = ("foveated",) * foveated + ("full",) * (not foveated or not args.no_reference)
        cli.frame_size(args, args.width, args.height, args.spp, kinds=kinds)
    return out


def _scene_name(args) -> str:
    import fovjax

    name = SCENE_ALIASES.get(args.scene, args.scene)
    if name in fovjax.scenes.BUILTIN:
        return name
    files = fovjax.scene.scene_files(args.scene)  # load_scene's default name
    return files[0].stem if len(files) == 1 else files[0].resolve().parent.name


def run(args) -> int:
    out = validate(args)
    if args.preview:
        return _run_preview(args, out)
    return _run(args, out)


def _run(args, out: Path) -> int:
    import jax
    import numpy as np

    import fovjax
    from fovjax import render_stereo
    from fovjax.render import (
        RenderConfig,
        StereoRig,
        compile_cache_entries,
        describe_integrator,
        head_rotation,
        render,
        scene_arrays,
    )
    from fovjax.trace import build_bvh, describe_backend, last_build_info

    config = RenderConfig(max_depth=args.max_depth, backend=args.backend)
    preset = None
    if args.preset == "thesis":
        from fovjax.foveate import thesis_preset

        preset = thesis_preset(
            (args.fovea, args.periphery), spp=args.spp, eye_height=args.height, config=config
        )
        # the thesis's depth (5) is --max-depth's default; another given there is kept
        config = dataclasses.replace(preset.config, max_depth=args.max_depth)
    building = args.native_build
    programs = compile_cache_entries()  # None: the cache is off, every run compiles
    # jax.config's options are set at run time (pyright cannot see it).
    cache = jax.config.jax_compilation_cache_dir  # pyright: ignore[reportAttributeAccessIssue]
    if building is not None or programs == 0:
        # Whether the programs will call the native handlers: being built, or known at once
        # (loaded from the cache, or unavailable here).
        native = building is not None or bool(fovjax.trace.embree_status())
        _first_run_note(building, Path(cache) if programs == 0 else None, native)
    foveated = args.stereo and not args.full
    with_reference = foveated and not args.no_reference
    steps = 6 if with_reference else 4
    t0 = time.perf_counter()
    _progress(1, steps, f"building scene {args.scene}")
    scene = _load_scene(args)
    t_scene = time.perf_counter() - t0
    _progress(2, steps, f"BVH of {scene.num_triangles:,} triangles")
    bvh = build_bvh(scene)
    build = last_build_info()
    arrays = scene_arrays(scene, envmap=args.envmap_image, background=config.background)
    pose = fovjax.scenes.default_camera(scene)
    key = None if args.seed is None else jax.random.key(args.seed)
    compiling = {
        None: "compiling {} and rendering",
        0: "compiling {} (first run only) and rendering",
    }.get(programs, "compiling {} or loading it from the cache, and rendering")
    if foveated:
        _progress(3, steps, "foveated frame: " + compiling.format("its program"))
    else:
        _progress(3, steps, compiling.format("the frame's program"))
    if building is not None:
        _wait_for_native_build()
    reference = None
    if args.stereo:
        rig = StereoRig.from_pose(pose, eye_width=args.width, eye_height=args.height)
        if foveated:
            from fovjax.foveate import Foveation

            if preset is not None:
                fov = preset.foveation
            else:
                fov = Foveation(fovea_deg=args.fovea, periphery_deg=args.periphery, spp=args.spp)
                fov = cli.regions(fov, args, args.height)
            frame = render_stereo(
                arrays,
                rig,
                gaze=args.gaze,
                foveation=fov,
                head_pose=args.head,
                key=key,
                config=config,
                bvh=bvh,
            )
        else:
            frame = render_stereo(
                arrays, rig, head_pose=args.head, spp=args.spp, key=key, config=config, bvh=bvh
            )
    else:
        camera = fovjax.Camera.from_pose(pose, width=args.width, height=args.height)
        if any(args.head):
            camera = fovjax.Camera(
                position=camera.position,
                rotation=np.asarray(camera.rotation @ head_rotation(args.head), np.float32),
                vfov_deg=camera.vfov_deg,
                offset=camera.offset,
                width=camera.width,
                height=camera.height,
            )
        frame = render(arrays, camera, spp=args.spp, key=key, config=config, bvh=bvh)
    # Each image is written as soon as it is rendered: the first is there before the next compiles.
    _progress(4, steps, f"writing {out}")
    with cli.deferred_interrupt():
        frame.save(out, exposure=args.exposure, tonemap_curve=args.tonemap)
        cli.wrote(out)
    full_out = out.with_name(out.stem + "_full" + out.suffix)
    if with_reference:
        _progress(5, steps, "full frame: " + compiling.format("its program"))
        reference = render_stereo(
            arrays, rig, head_pose=args.head, spp=args.spp, key=key, config=config, bvh=bvh
        )
        _progress(6, steps, f"writing {full_out}")
        with cli.deferred_interrupt():
            reference.save(full_out, exposure=args.exposure, tonemap_curve=args.tonemap)
            cli.wrote(full_out)
    cached = ", BVH from cache" if build["from_cache"] else f", BVH built in {build['seconds']:.2f} s"
    print(f"scene {scene.name}: {scene.num_triangles:,} triangles (scene {t_scene:.2f} s{cached})")
    platform = jax.devices()[0].platform
    print(f"ray queries: {describe_backend(config.backend, platform)}")
    print(f"integrator: {describe_integrator(config, platform)}")
    memory = describe_malloc()  # None: not glibc's malloc, nothing to say
    if memory is not None:
        print(f"memory: {memory}")
    if preset is not None:
        f = preset.foveation
        print(
            f"preset thesis: regions {f.eccentricity} at {f.pixel_pitch_mm:.5f} mm per pixel, rule {f.rule}, "
            f"blur every pixel, specular {config.specular} with the n·l payload, cut-off "
            f"{config.min_contribution:g}, depth {config.max_depth}, SPP {args.spp}"
        )
    if foveated and isinstance(frame, fovjax.FoveatedFrame):
        f = frame.foveation
        print(
            f"foveated {f.fovea_deg:g}°/{f.periphery_deg:g}° {frame.stats.summary()} on {platform} -> "
            f"{out.resolve()}"
        )
        print(
            f"  primary rays by region (fovea, periphery, outside) {f.primary_by_region}; "
            f"ray budget {f.budget:,} samples, {f.padding:,} of them not needed this frame"
            + (f", {f.dropped:,} samples dropped (over the budget)" if f.dropped else "")
        )
        if args.show_samples:
            samples = out.with_name(out.stem + "_samples.png")
            with cli.deferred_interrupt():
                fovjax.save_image(samples, frame.debug_view)
                cli.wrote(samples)
            print(f"  regions and samples -> {samples.resolve()}")
        if reference is not None:
            r, s = reference.stats, frame.stats
            print(f"full     {r.summary()} -> {full_out.resolve()}")
            print(f"foveated / full: {_speed_text(s, r)}")
    else:
        print(f"{scene.name} {frame.stats.summary()} on {platform} -> {out.resolve()}")
    return 0


def _first_run_note(building: Path | None, programs: Path | None, native: bool = True) -> None:
    """Say, before the work, what a first run on this machine builds (the native handlers, into
    `building`) and compiles (the frame programs, cached in `programs`; `native`: with the native
    handlers), how long that usually takes and where it is kept for later runs."""
    kept = []
    if building is not None:
        doing = (
            f"building the native handlers (C++, {HANDLERS_TYPICAL}, while the scene loads; "
            "`fovjax build` does it ahead)"
        )
        kept.append((doing, building.parent))
    if programs is not None:
        typical = PROGRAMS_TYPICAL if native else "longer without the native handlers"
        kept.append((f"compiling the frame programs ({typical})", programs))
    if not kept:
        return
    folders = {folder for _, folder in kept}
    parents = {folder.parent for folder in folders}
    where = (
        f"{next(iter(parents))} ({', '.join(sorted(f.name + '/' for f in folders))})"
        if len(parents) == 1 and len(folders) > 1
        else " and ".join(str(f) for f in sorted(folders))
    )
    doing = " and ".join(what for what, _ in kept)
    print(
        f"first run on this machine: {doing}; kept in {where} for later runs",
        file=sys.stderr,
        flush=True,
    )


def _wait_for_native_build() -> None:
    """Wait for the native handlers' background build, saying so and how long it took."""
    from fovjax.trace import embree_status

    print("      waiting for the native handlers' build", file=sys.stderr, flush=True)
    found = embree_status()
    if found:
        seconds = found.info.get("compile_seconds", 0.0)
        print(f"      native handlers built in {seconds:.1f} s", file=sys.stderr, flush=True)
    else:
        print(f"      native handlers unavailable: {found.reason}", file=sys.stderr, flush=True)


def _speed_text(foveated, full) -> str:
    """The foveated frame against the full one, saying what is compared: the rays traced and
    the compiled programs' run time of one frame each (compiling not counted)."""
    ratio = full.render_seconds / foveated.render_seconds if foveated.render_seconds > 0 else float("inf")
    if ratio >= 1:
        verdict = f"the foveated frame {ratio:.1f}x faster"
    else:
        verdict = (
            f"the foveated frame {1 / ratio:.1f}x slower (its passes over the whole screen, selecting "
            "samples and filling and blurring the gaps, can cost more than the rays it saves, as on "
            "small frames)"
        )
    return (
        f"rays {foveated.rays / full.rays:.3f} ({foveated.rays:,} vs {full.rays:,}), time of one frame "
        f"each, compiling not counted, {foveated.render_seconds:.2f} s vs {full.render_seconds:.2f} s: "
        f"{verdict}; one run of each on this machine (benchmarks/mitsuba_frame.py times a loop of "
        "frames for the figures in docs/performance.md)"
    )


def _run_preview(args, out: Path) -> int:
    import jax
    import numpy as np

    import fovjax
    from fovjax.cli._preview import normal_depth_image_jit
    from fovjax.files import save_image
    from fovjax.trace import build_bvh, last_build_info

    t0 = time.perf_counter()
    scene = _load_scene(args)
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

    with cli.deferred_interrupt():
        save_image(out, np.asarray(image))
        cli.wrote(out)
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
