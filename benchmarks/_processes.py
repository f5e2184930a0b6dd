"""What the benchmarks that compare settings in alternating processes share: the measured
renderer (the atrium, foveated 5°/10° at an off-centre gaze), the common arguments, and running
one measuring process that prints its result as a `RESULT {json}` line."""

from __future__ import annotations

import json
import subprocess
import sys

RESULT = "RESULT "
GAZE = ((0.4, 0.45), (0.4, 0.45))


def add_arguments(ap, *, repeats: int) -> None:
    """--rounds, --repeats and --size, as every alternating-process benchmark takes them."""
    ap.add_argument("--rounds", type=int, default=2, help="pairs of processes, the order alternated")
    ap.add_argument("--repeats", type=int, default=repeats, help="timed frames per process and frame")
    ap.add_argument("--size", type=int, nargs=2, default=(1280, 1024), metavar=("W", "H"))


def check_arguments(ap, args) -> None:
    if args.rounds < 1 or args.repeats < 1 or min(args.size) < 8:
        ap.error(
            "--rounds, --repeats must be >= 1 and --size at least 8 x 8, "
            f"got {args.rounds}, {args.repeats}, {args.size}"
        )


def atrium_renderer(size):
    """The `FoveatedRenderer` these benchmarks time: the atrium, 2 x W x H, max depth 5, SPP 1,
    foveated 5°/10°, no per-pixel outputs; frames at `GAZE`."""
    import fovjax
    import fovjax.scenes
    from fovjax.foveate import Foveation
    from fovjax.render import RenderConfig, StereoRig

    scene = fovjax.scenes.atrium()
    w, h = size
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=w, eye_height=h)
    foveation = Foveation(fovea_deg=5, periphery_deg=10, spp=1)
    return fovjax.FoveatedRenderer(scene, rig, foveation, RenderConfig(max_depth=5), diagnostics=())


def print_result(result: dict) -> None:
    print(RESULT + json.dumps(result), flush=True)


def run_measuring_process(benchmark: str, script: str, argv: list[str], env: dict) -> dict:
    """Run `script` with `argv` in a new process with environment `env`; its last RESULT line.
    Exits naming `benchmark` when the process fails."""
    done = subprocess.run(
        [sys.executable, script, *argv], env=env, capture_output=True, text=True, timeout=1800
    )
    lines = [ln for ln in done.stdout.splitlines() if ln.startswith(RESULT)]
    if done.returncode != 0 or not lines:
        sys.exit(f"{benchmark}: a measuring process failed ({done.returncode}): {done.stderr[-2000:]}")
    return json.loads(lines[-1][len(RESULT) :])
