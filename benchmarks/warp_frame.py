"""The stereo frame on a GPU with the Warp integrator, timed and profiled.

    python benchmarks/warp_frame.py              # on a CUDA machine (benchmarks/gpu.sh runs it)
    python benchmarks/warp_frame.py --dry-run    # 2 x 64x48, one repeat, no record: a check anywhere

The atrium at 2 x 1280x1024 (`--size`), depth 5, the default `RenderConfig` (integrator "auto":
on CUDA the Whitted loop in one Warp kernel launch per frame, fovjax/render/_warp_whitted.py):
the full frame at SPP 1 and 4 and the foveated 5°/10° frame at SPP 1 and 4 at an off-centre
gaze, each compiled and run once (warm-up), then `--repeats` frames of each kind in turn (so
that the machine's load falls on all alike), medians, each frame with a fresh key; through a
`FoveatedRenderer` made once per SPP (`render` and `render_full`), as a frame loop runs them. Beside them
in the same run, on the same device: the full SPP 1 frame with the JAX integrator
(`integrator="jax"`, what ran on CUDA before) as the baseline, and the thesis's RTX 2060 figures
(Table 4: full SPP 1 9.6 ms, SPP 4 38.3 ms; foveated 5°/10° SPP 4 17.3 ms; its goal 120 fps).

Then one full and one foveated frame (SPP `--profile-spp`) are recorded with `jax.profiler`
(a Perfetto trace) and summarised per frame: the device's kernels (count, total time) and
memory copies device to host and host to device, the host's CUDA API calls that wait for the
device (names containing "Synchroniz") and launch work (kernels, graphs), the most frequent
events of each, and the Python callbacks: how many times XLA entered Python through Warp's FFI
handlers during the frame (counted by wrapping them before fovjax makes any: the mesh id's, the
kernel's unless XLA replays it from a CUDA graph, and any Warp ray query's). The summary goes
into the record with the timings (benchmarks/results/warp_frame-*.json); the trace itself is
left in `--trace-dir` (printed).

Which integrator ran is printed (`describe_integrator`); on a CPU it is the native one (the
Warp kernel runs there only when called directly, as tests/test_render_warp.py does), so a
dry run checks this script, not the GPU's figures.
"""

from __future__ import annotations

import argparse
import collections
import functools
import gzip
import json
import re
import statistics
import sys
import tempfile
import time
from pathlib import Path

import jax

import fovjax
import fovjax.scenes
from fovjax.foveate import FoveatedRenderer, Foveation
from fovjax.render import RenderConfig, StereoRig, describe_integrator
from fovjax.trace import build_bvh, describe_backend

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _record import write_record  # noqa: E402

# An off-centre gaze (each eye looking up and to the left of its display centre), as
# benchmarks/foveation.py --speedup.
OFF_CENTRE = ((0.32, 0.38), (0.28, 0.38))
PAIR = (5.0, 10.0)
# The thesis's Table 4 (Sponza, RTX 2060, OptiX, 2 x 1280x1024): ms per frame.
THESIS_MS = {("full", 1): 1000 / 103.88, ("full", 4): 1000 / 26.12, ("foveated", 1): 1000 / 60.16}
THESIS_MS[("foveated", 4)] = 1000 / 57.84
GOAL_MS = 1000 / 120  # the thesis's unmet goal

# ---- Python callbacks: XLA entering Python through Warp's FFI handlers ---------------------------

CALLBACKS: collections.Counter = collections.Counter()


def count_warp_callbacks() -> str:
    """Wrap Warp's FFI handlers (`jax_kernel`'s and `jax_callable`'s) so that each entry from XLA
    is counted in CALLBACKS by target name. Must run before fovjax makes any (they bind the
    handler when made). Returns what is counted, or why nothing is."""
    try:
        from warp._src.jax import ffi
    except ImportError as exc:
        return f"not counted (Warp's FFI module: {exc})"
    wrapped = []
    for cls in (getattr(ffi, "FfiKernel", None), getattr(ffi, "FfiCallable", None)):
        if cls is None or not hasattr(cls, "ffi_callback"):
            continue
        original = cls.ffi_callback

        def counted(self, call_frame, platform, original=original):
            CALLBACKS[self.name] += 1
            return original(self, call_frame, platform)

        cls.ffi_callback = counted
        wrapped.append(cls.__name__)
    if not wrapped:
        return "not counted (this Warp has no FfiKernel/FfiCallable)"
    return f"counted at Warp's {' and '.join(wrapped)} FFI handlers"


# ---- the profile's summary ---------------------------------------------------------------------

SYNC = re.compile(r"synchroniz", re.I)
LAUNCH = re.compile(r"(cu|cuda)(Launch|GraphLaunch|LaunchKernel)", re.I)
MEMCPY_DTOH = re.compile(r"memcpy.*(dtoh|d2h|devicetohost)", re.I)
MEMCPY_HTOD = re.compile(r"memcpy.*(htod|h2d|hosttodevice)", re.I)


def _events(trace_dir: Path) -> tuple[list[dict], dict]:
    """The complete events of the Perfetto trace under `trace_dir`, and the process names."""
    files = sorted(trace_dir.rglob("*.trace.json.gz")) + sorted(trace_dir.rglob("perfetto_trace.json.gz"))
    if not files:
        raise FileNotFoundError(f"no Perfetto trace under {trace_dir}")
    with gzip.open(files[-1], "rt") as f:
        data = json.load(f)
    events = data["traceEvents"] if isinstance(data, dict) else data
    processes = {}
    for e in events:
        if e.get("ph") == "M" and e.get("name") == "process_name":
            processes[e["pid"]] = e.get("args", {}).get("name", "")
    return [e for e in events if e.get("ph") == "X"], processes


def summarise_trace(trace_dir: Path, frames: int, callbacks: int, top: int = 12) -> dict:
    """Per frame: device events (kernels, copies each way, their time), host events that wait for
    the device or launch work, Python callbacks, the Python tracer's function calls, and the most
    frequent other event names on each side."""
    events, processes = _events(trace_dir)
    device_kernels, dtoh, htod, syncs, launches = [], [], [], [], []
    by_name = {"device": collections.Counter(), "host": collections.Counter()}
    python_events = 0
    for e in events:
        name = str(e.get("name", ""))
        # XLA names a device's planes "/device:GPU:0" (its streams are threads there), the host's
        # "/host:CPU".
        on_device = processes.get(e.get("pid"), "").startswith("/device:")
        if not on_device and name.startswith("$"):  # the Python tracer's function calls
            python_events += 1
            continue
        by_name["device" if on_device else "host"][name] += 1
        if on_device:
            if MEMCPY_DTOH.search(name):
                dtoh.append(e)
            elif MEMCPY_HTOD.search(name):
                htod.append(e)
            elif not re.search(r"memcpy|memset", name, re.I):
                device_kernels.append(e)
        else:
            if SYNC.search(name):
                syncs.append(e)
            if LAUNCH.search(name):
                launches.append(e)

    def per_frame(n):
        return round(n / frames, 2)

    return {
        "frames": frames,
        "device_kernels": per_frame(len(device_kernels)),
        "device_kernel_ms": round(sum(e.get("dur", 0) for e in device_kernels) / 1000 / frames, 3),
        "memcpy_device_to_host": per_frame(len(dtoh)),
        "memcpy_host_to_device": per_frame(len(htod)),
        "host_syncs": per_frame(len(syncs)),
        "host_launch_calls": per_frame(len(launches)),
        "python_callbacks": per_frame(callbacks),
        "python_function_events": per_frame(python_events),
        "top_device_events": by_name["device"].most_common(top),
        "top_host_events": by_name["host"].most_common(top),
        "host_syncs_by_name": collections.Counter(e["name"] for e in syncs).most_common(top),
    }


def profile_frame(render, trace_root: Path, label: str) -> dict:
    """One frame of `render` (already compiled) under `jax.profiler`, summarised."""
    trace_dir = trace_root / label
    before = sum(CALLBACKS.values())
    with jax.profiler.trace(str(trace_dir), create_perfetto_trace=True):
        frame = render(jax.random.key(20_000))
        jax.block_until_ready(frame.image)
    callbacks = sum(CALLBACKS.values()) - before
    summary = summarise_trace(trace_dir, 1, callbacks)
    summary["render_ms"] = 1000 * frame.stats.render_seconds
    return summary


# ---- the frames --------------------------------------------------------------------------------


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, nargs=2, default=(1280, 1024), metavar=("W", "H"), help="per eye")
    ap.add_argument("--spp", type=int, nargs="+", default=[1, 4])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--profile-spp", type=int, default=1)
    ap.add_argument("--no-baseline", action="store_true", help="skip the JAX integrator's full frame")
    ap.add_argument("--trace-dir", default=None, help="where the profiles go (default: a temporary folder)")
    ap.add_argument("--dry-run", action="store_true", help="2 x 64x48, one repeat, no record")
    ap.add_argument("--note", default=None, help="the record's note: the run's conditions")
    args = ap.parse_args(argv)
    if args.dry_run:
        args.size, args.repeats = (64, 48), 1
    counting = count_warp_callbacks()
    w, h = args.size
    scene = fovjax.scenes.atrium()
    bvh = build_bvh(scene)
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=w, eye_height=h)
    config = RenderConfig()
    device = jax.devices()[0]
    platform = device.platform
    print(
        f"atrium {scene.num_triangles:,} triangles, stereo 2 x {w}x{h}, depth {config.max_depth}, "
        f"jax {jax.__version__} on {device.device_kind} ({platform})\n"
        f"integrator: {describe_integrator(config, platform)}\n"
        f"ray queries: {describe_backend(config.backend, platform)}\n"
        f"Python callbacks {counting}",
        flush=True,
    )

    # One renderer per SPP, made once, as a frame loop holds it (the scene on the device once;
    # `render_foveated` and `render_stereo` copy it there on every call).
    @functools.cache
    def renderer(spp, cfg=config):
        foveation = Foveation.thesis(PAIR, spp=spp)
        return FoveatedRenderer(scene, rig, foveation, cfg, bvh=bvh, diagnostics=())

    def full(spp, cfg=config):
        return lambda k: renderer(spp, cfg).render_full(key=k)

    def foveated(spp):
        return lambda k: renderer(spp).render(OFF_CENTRE, key=k)

    renders = {}
    for spp in args.spp:
        renders[("full", spp)] = full(spp)
        renders[("foveated", spp)] = foveated(spp)
    if not args.no_baseline:
        renders[("full, JAX integrator", 1)] = full(1, RenderConfig(integrator="jax"))
    compile_s, rays, times = {}, {}, collections.defaultdict(list)
    for key, render in renders.items():
        t0 = time.perf_counter()
        frame = render(jax.random.key(10_000))
        jax.block_until_ready(frame.image)
        compile_s[key] = frame.stats.compile_seconds
        print(f"  {key[0]} SPP {key[1]}: warm-up {time.perf_counter() - t0:.1f} s", flush=True)
    for i in range(args.repeats):
        for key, render in renders.items():
            frame = render(jax.random.key(i))
            times[key].append(1000 * frame.stats.render_seconds)
            rays[key] = frame.stats.rays
    rows = []
    for key in renders:
        ms = statistics.median(times[key])
        thesis = THESIS_MS.get(key)
        rows.append(
            [
                key[0],
                key[1],
                round(ms, 2),
                rays[key],
                round(rays[key] / ms / 1e3, 1),
                None if thesis is None else round(thesis, 1),
                round(compile_s[key], 1),
            ]
        )
        print(
            f"  {key[0]:>22} SPP {key[1]}: {ms:8.2f} ms  {rays[key]:>11,} rays  "
            f"{rays[key] / ms / 1e3:7.1f} Mrays/s"
            + ("" if thesis is None else f"  (thesis RTX 2060: {thesis:.1f} ms)")
            + f"  frames {[round(t, 1) for t in times[key]]}",
            flush=True,
        )

    trace_root = Path(args.trace_dir or tempfile.mkdtemp(prefix="fovjax-warp-frame-trace-"))
    profiles = {}
    for kind in ("full", "foveated"):
        key = (kind, args.profile_spp)
        render = renders.get(key) or (full if kind == "full" else foveated)(args.profile_spp)
        if key not in renders:
            jax.block_until_ready(render(jax.random.key(10_000)).image)
        profiles[kind] = profile_frame(render, trace_root, f"{kind}-spp{args.profile_spp}")
        p = profiles[kind]
        print(
            f"  profile, {kind} SPP {args.profile_spp} ({p['render_ms']:.1f} ms): "
            f"{p['device_kernels']:g} device kernels ({p['device_kernel_ms']:.2f} ms), "
            f"copies device->host {p['memcpy_device_to_host']:g}, "
            f"host->device {p['memcpy_host_to_device']:g}, "
            f"host syncs {p['host_syncs']:g}, launch calls {p['host_launch_calls']:g}, "
            f"Python callbacks {p['python_callbacks']:g}",
            flush=True,
        )
    print(f"traces: {trace_root}")
    figures = {
        "eye": [w, h],
        "platform": platform,
        "device": device.device_kind,
        "integrator": describe_integrator(config, platform),
        "ray_queries": describe_backend(config.backend, platform),
        "python_callbacks_counted": counting,
        "callbacks_by_target": dict(CALLBACKS),
        "profiles": profiles,
        "tables": [
            {
                "title": f"Stereo frames, atrium, 2 × {w}×{h}, depth {config.max_depth}, foveated "
                f"{PAIR[0]:g}°/{PAIR[1]:g}° at an off-centre gaze, {device.device_kind} (medians of "
                f"{args.repeats})",
                "columns": ["frame", "SPP", "ms", "rays", "Mrays/s", "thesis RTX 2060 ms", "compile s"],
                "rows": rows,
            }
        ],
    }
    if args.dry_run:
        print("dry run: no record")
        return 0
    write_record("warp_frame", figures, note=args.note)
    return 0


if __name__ == "__main__":
    sys.exit(main())
