"""Where a frame program's time goes, measured inside the one compiled program.

    python benchmarks/profile_frame.py                   # full and foveated, 2 x 1280x1024, SPP 1
    python benchmarks/profile_frame.py --frames foveated --top 30
    python benchmarks/profile_frame.py --size 640 512 --spp 4
    python benchmarks/profile_frame.py --frames foveated --size 640 512 --method weier2016

Renders the atrium's stereo frame (one `FoveatedRenderer`: `render_full` and/or `render`,
foveated 5°/10° at an off-centre gaze, backend auto), then records `--repeats` frames with
JAX's profiler. XLA:CPU reports every operation (a fusion, an FFI call, a scatter) it runs,
with its duration and thread; the program's optimised HLO (dumped by XLA) says which source
line each operation came from, and so which stage of the frame it belongs to. The table is ms
per frame by stage, summed over both of the CPU's worker threads (so the stages can add up to
more than the frame's wall time where they ran in parallel), then the slowest operations with
their source. Control-flow operations (loops, conditionals) are left out of the sums: their
time is that of the operations inside them, which are counted themselves.

Unlike `benchmarks/foveation.py --profile` (each stage compiled and timed on its own, with
the cost of materialising what the fused program never does), this is the fused program's own
time. Writes a record (benchmarks/results/profile_frame-*.json). FOVJAX_KEEP_HLO=1 keeps XLA's
HLO dump (its folder is printed) to look an operation up.
"""

from __future__ import annotations

import argparse
import collections
import glob
import os
import re
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

DUMP = tempfile.mkdtemp(prefix="fovjax-profile-hlo-")
# Before JAX starts: the optimised HLO of every program, for the operations' source lines.
os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + f" --xla_dump_to={DUMP}").strip()

import jax  # noqa: E402
from jax.profiler import ProfileData  # noqa: E402

import fovjax  # noqa: E402
import fovjax.scenes  # noqa: E402
from fovjax.foveate import Foveation  # noqa: E402
from fovjax.render import RenderConfig, StereoRig  # noqa: E402
from fovjax.trace import build_bvh  # noqa: E402

# Stage of an operation: the first rule whose (file, function) pattern matches a frame of its
# source stack, innermost first.
STAGES = (
    (
        "native camera frame (rays, trace, shade, shadows, reflections, box filter)",
        r"render/_native\.py:\d+\(native_camera_frame\b",
    ),
    (
        "native integrator (trace, shade, shadows, reflections)",
        r"(render|foveate)/_native\.py:\d+\((native_whitted|native_whitted_slots)\b",
    ),
    ("sampling + compaction", r"foveate/_native\.py:\d+\(native_select_samples"),
    ("fill / blur", r"foveate/_native\.py:\d+\(native_fill_and_blur"),
    ("ray queries (native)", r"trace/_embree\.py|trace/_warp\.py"),
    (
        "ray queries (JAX: traversal, batching)",
        r"trace/_(traverse|packet|kernel|query)\.py:\d+\((?!hit_geometry)",
    ),
    ("hit recomputed (differentiable t, u, v)", r"hit_geometry"),
    (
        "eccentricity, regions, P(ω)",
        r"foveate/_eccentricity\.py|foveate/_frame\.py:\d+\(eccentricities|foveate/_config\.py:\d+\(Foveation\.probability",
    ),
    (
        "sampling + compaction",
        r"foveate/_(sampling|positions)\.py|foveate/_frame\.py:\d+\((select_samples|_slot_samples|slot_rays|traced_mask|traced_count)",
    ),
    ("accumulate", r"foveate/_frame\.py:\d+\((accumulate|tile_sums|grid_sums)"),
    ("method: pixels listed (select_pixels)", r"foveate/_methods/_sparse\.py:\d+\(select_pixels"),
    ("method: reprojection", r"foveate/_methods/_weier\.py:\d+\((reproject|_reproject_eye|occluded_leaks)"),
    ("method: hit points (first_hit_points)", r"foveate/_frame\.py:\d+\((first_hit_points|_first_points)"),
    ("method: layers, filters, history", r"foveate/_methods/_(guenter|patney|weier)\.py"),
    ("fill / blur", r"foveate/_fill\.py"),
    (
        "surfaces (gathers, normals, textures)",
        r"render/_integrator\.py:\d+\((surface_at|diffuse_color|bilinear_wrap|_texture_lod)",
    ),
    ("lights and shadow rays", r"render/_integrator\.py:\d+\((_shadow_rays|_light_sum|_trace_shadows)"),
    ("shading, reflection spawn", r"render/_integrator\.py:\d+\((_finish_shading|_trace_and_shade)"),
    (
        "queues, compaction of rays",
        r"render/_integrator\.py:\d+\((_append|_live_first|_depth0|_reflection_level|_reflection_levels|_primary_level|_queue_level|_tile_level|radiance_in_chunks|chunk_loop)",
    ),
    ("camera rays", r"scene/_camera\.py|render/_frame\.py:\d+\(stereo_sample_rays"),
    ("image out", r"render/_frame\.py|render/_stereo\.py"),
)
CONTROL = re.compile(r"^(while|cond|conditional|call)(\.\d+)?$")


def _sections(text: str) -> dict[str, dict[int, str]]:
    out = {}
    for name in ("FileNames", "FunctionNames", "FileLocations", "StackFrames"):
        m = re.search(r"^" + name + r"\n((?:\d+ .*\n)+)", text, re.M)
        out[name] = (
            {}
            if m is None
            else {int(i): rest for i, rest in (ln.split(" ", 1) for ln in m.group(1).splitlines())}
        )
    return out


def source_of(hlo_text: str):
    """name → (result type, [file:line(function), ...] innermost first, fovjax frames only)."""
    tables = _sections(hlo_text)
    files, funcs, locs, frames = (
        tables[k] for k in ("FileNames", "FunctionNames", "FileLocations", "StackFrames")
    )

    def chain(fid):
        out, seen = [], set()
        while fid and fid not in seen and fid in frames:
            seen.add(fid)
            d = dict(re.findall(r"(\w+)=(\d+)", frames[fid]))
            loc = dict(re.findall(r"(\w+)=(\d+)", locs.get(int(d["file_location_id"]), "")))
            if loc:
                path = files[int(loc["file_name_id"])].strip('"')
                if "/fovjax/" in path and "site-packages" not in path:
                    func = funcs[int(loc["function_name_id"])].strip('"')
                    out.append(f"{path.split('/fovjax/')[-1]}:{loc.get('line')}({func})")
            fid = int(d.get("parent_frame_id", 0))
        return out

    where = {}
    for m in re.finditer(r"^\s*(?:ROOT )?%?([\w.\-]+) = (\S+) .*?stack_frame_id=(\d+)", hlo_text, re.M):
        where[m.group(1)] = (m.group(2), chain(int(m.group(3))))
    return where


def stage_of(stack: list[str]) -> str:
    for frame in stack:
        for stage, pattern in STAGES:
            if re.search(pattern, frame):
                return stage
    return "other"


def profile(render, repeats: int, label: str):
    """(ms per frame by stage, top operations, wall ms per frame) of `repeats` frames."""
    before = set(glob.glob(os.path.join(DUMP, "*after_optimizations.txt")))
    frame = render(0)
    render(1)
    trace_dir = tempfile.mkdtemp(prefix="fovjax-profile-trace-")
    walls = []
    jax.profiler.start_trace(trace_dir)
    for i in range(repeats):
        t0 = time.perf_counter()
        render(2 + i)
        walls.append(time.perf_counter() - t0)
    jax.profiler.stop_trace()
    dumps = set(glob.glob(os.path.join(DUMP, "*after_optimizations.txt"))) - before
    dumps = [p for p in dumps if "buffer-assignment" not in p]
    where = {}
    for path in sorted(dumps, key=os.path.getsize):  # the frame program last: its names win
        where.update(source_of(Path(path).read_text()))
    data = ProfileData.from_file(glob.glob(os.path.join(trace_dir, "**", "*.xplane.pb"), recursive=True)[0])
    by_op, count = collections.Counter(), collections.Counter()
    for plane in data.planes:
        if plane.name != "/host:CPU":
            continue
        for line in plane.lines:
            if not line.name.startswith("tf_XLA"):
                continue
            for event in line.events:
                name = event.name
                if name.startswith(("end:", "ThreadpoolListener", "ThunkExecutor")) or CONTROL.match(name):
                    continue
                by_op[name] += event.duration_ns / 1e6 / repeats
                count[name] += 1
    shutil.rmtree(trace_dir, ignore_errors=True)
    stages = collections.Counter()
    for name, ms in by_op.items():
        stages[stage_of(where.get(name, ("", []))[1])] += ms
    top = [
        (
            name,
            ms,
            count[name] // repeats,
            where.get(name, ("?", []))[0],
            " < ".join(where.get(name, ("", []))[1][:2]),
        )
        for name, ms in by_op.most_common()
    ]
    wall = 1000 * statistics.median(walls)
    print(
        f"\n{label}: {wall:.0f} ms per frame (wall, median of {repeats}; "
        f"compile {frame.stats.compile_seconds:.1f} s)"
    )
    return stages, top, wall, frame


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", nargs="+", choices=("full", "foveated"), default=("full", "foveated"))
    ap.add_argument("--size", type=int, nargs=2, default=(1280, 1024), metavar=("W", "H"))
    ap.add_argument("--spp", type=int, default=1)
    ap.add_argument("--pair", type=float, nargs=2, default=(5.0, 10.0))
    ap.add_argument("--gaze", type=float, nargs=2, default=(0.4, 0.45))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--top", type=int, default=15, help="slowest operations listed per frame")
    ap.add_argument("--backend", choices=fovjax.trace.BACKENDS, default="auto")
    ap.add_argument("--method", default="thesis", help="the foveated frame's method (a registered name)")
    args = ap.parse_args(argv)
    if args.repeats < 1 or args.spp < 1 or min(args.size) < 8:
        ap.error(
            "--repeats and --spp must be positive and --size at least 8 x 8, "
            f"got {args.repeats}, {args.spp}, {args.size}"
        )
    scene = fovjax.scenes.atrium()
    bvh = build_bvh(scene)
    w, h = args.size
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=w, eye_height=h)
    config = RenderConfig(max_depth=5, backend=args.backend)
    gaze = (tuple(args.gaze), tuple(args.gaze))
    foveation = Foveation(
        fovea_deg=args.pair[0], periphery_deg=args.pair[1], spp=args.spp, method=args.method
    )
    print(
        f"atrium {scene.num_triangles:,} triangles, 2 x {w}x{h}, SPP {args.spp}, depth 5, backend "
        f"{args.backend} ({fovjax.trace.describe_backend(args.backend, jax.devices()[0].platform)}), "
        f"method {args.method}, "
        f"jax {jax.__version__}, {os.cpu_count()} CPUs"
    )
    # One renderer prepared once (scene arrays and BVH on the device), called per frame.
    renderer = fovjax.FoveatedRenderer(scene, rig, foveation, config, bvh=bvh, diagnostics=())
    renders = {
        "full": lambda k: renderer.render_full(key=jax.random.key(k)),
        "foveated": lambda k: renderer.render(gaze, key=jax.random.key(k)),
    }
    results = {}
    for kind in args.frames:
        stages, top, wall, frame = profile(renders[kind], args.repeats, f"{kind} frame")
        results[kind] = {"stages": stages, "top": top, "wall": wall, "compile": frame.stats.compile_seconds}
        for name, ms, n, shape, src in top[: args.top]:
            print(f"  {ms:8.1f} ms  x{n:<5d} {name:40s} {shape[:34]:34s} {src}")
    names = [*dict.fromkeys(s for s, _ in STAGES), "other"]  # a stage may have several rules
    kinds = list(results)
    print("\nms per frame by stage (both worker threads; the wall time is the frame's)")
    print(f"  {'stage':42s}" + "".join(f"{k:>12s}" for k in kinds))
    rows = []
    for stage in names:
        if all(results[k]["stages"].get(stage, 0.0) < 0.05 for k in kinds):
            continue
        cells = [round(results[k]["stages"].get(stage, 0.0), 1) for k in kinds]
        rows.append([stage, *cells])
        print(f"  {stage:42s}" + "".join(f"{c:12.1f}" for c in cells))
    summed = [round(sum(results[k]["stages"].values()), 1) for k in kinds]
    walls = [round(results[k]["wall"], 1) for k in kinds]
    rows += [["sum of operations", *summed], ["frame (wall)", *walls]]
    print(f"  {'sum of operations':42s}" + "".join(f"{c:12.1f}" for c in summed))
    print(f"  {'frame (wall)':42s}" + "".join(f"{c:12.1f}" for c in walls))
    if os.environ.get("FOVJAX_KEEP_HLO") != "1":
        shutil.rmtree(DUMP, ignore_errors=True)
    else:
        print(f"HLO kept in {DUMP}")
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _record import write_record

    write_record(
        "profile_frame",
        {
            "tables": [
                {
                    "title": (
                        f"Inside the frame program: ms per frame by stage, 2 x {w}x{h}, SPP {args.spp}, "
                        f"foveated {args.pair[0]:g}°/{args.pair[1]:g}° at gaze {args.gaze}, "
                        f"backend {args.backend}, method {args.method} "
                        "(operations on both worker threads; the last row is the frame's wall time)"
                    ),
                    "columns": ["stage", *kinds],
                    "rows": rows,
                }
            ],
            "top_operations": {k: [list(t[:4]) + [t[4]] for t in results[k]["top"][:25]] for k in kinds},
            "compile_s": {k: results[k]["compile"] for k in kinds},
        },
    )
    return results


if __name__ == "__main__":
    main()
