"""The live viewer's frame rate and gaze-to-display latency, measured in a real browser.

    python benchmarks/view_latency.py --width 320 --height 256
    python benchmarks/view_latency.py --width 640 --height 512 --seconds 30

Starts `fovjax view` (spheres scene by default, mouse gaze) on a free port, opens the page in
headless Chromium (selenium + chromedriver), waits for the first frame, then moves the mouse to a
new random point of the left eye every `--interval` seconds for `--seconds`. The page records,
for every mouse event that a frame was rendered from, the time from the event to the animation
frame that shows that frame (its own clock at both ends), and when each frame was shown.

The peer, in the same run (after the viewer has stopped, so they do not share the CPU): the
bare renderer, a `fovjax.FoveatedRenderer` with the same scene, size and foveation in a loop, timed
per call. Printed: medians, and the ratios viewer/bare (frame interval and latency against one
bare frame): the cost of the server, encoding, transfer and display on top of rendering. On a
shared, loaded machine the two halves can see different loads; the ratios against the viewer's
own server-side frame time (recorded per frame on the page, same moments) are the steadier ones.
"""

from __future__ import annotations

import argparse
import os
import random
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _record import write_record

ROOT = Path(__file__).resolve().parents[1]


def chromium():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium") or shutil.which("google-chrome")
    profile = tempfile.mkdtemp(prefix="fovjax-view-bench-")
    for flag in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        "--window-size=1400,1000",
        f"--user-data-dir={profile}",
    ):
        options.add_argument(flag)
    return webdriver.Chrome(options=options, service=Service(shutil.which("chromedriver"))), profile


def wait(driver, script, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = driver.execute_script(script)
        if value:
            return value
        time.sleep(0.05)
    raise SystemExit(f"timed out: {script}")


def measure_viewer(args) -> dict:
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    cmd = [sys.executable, "-m", "fovjax", "view", "--scene", args.scene, "--width", str(args.width)]
    cmd += ["--height", str(args.height), "--port", "0", "--save-dir", tempfile.mkdtemp()]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    started = time.monotonic()
    url = re.search(r"serving (\S+)", proc.stdout.readline()).group(1)
    driver, profile = chromium()
    try:
        driver.get(url)
        wait(driver, "return window.fovjaxView && window.fovjaxView.displayed >= 1", 600)
        first_frame_s = time.monotonic() - started
        canvas = driver.find_element(By.ID, "frame")
        w, h = driver.execute_script(
            "const r = arguments[0].getBoundingClientRect(); return [r.width, r.height];", canvas
        )
        driver.execute_script(
            "const v = window.fovjaxView; v.latencies = []; v.shownAt = []; v.serverMs = [];"
        )
        rng = random.Random(0)
        end = time.monotonic() + args.seconds
        moves = 0
        while time.monotonic() < end:
            x, y = rng.uniform(0.1, 0.9), rng.uniform(0.1, 0.9)
            ActionChains(driver, duration=0).move_to_element_with_offset(
                canvas, int(x * w / 2 - w / 2), int(y * h - h / 2)
            ).perform()
            moves += 1
            time.sleep(args.interval)
        latencies, shown, server_ms, stats = driver.execute_script(
            "const v = window.fovjaxView; return [v.latencies, v.shownAt, v.serverMs, v.stats];"
        )
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)
        proc.terminate()
        proc.wait(30)
    intervals = [b - a for a, b in zip(shown, shown[1:], strict=False)]
    return {
        "first_frame_s": first_frame_s,
        "moves": moves,
        "frames": len(shown),
        "fps": 1000.0 / statistics.median(intervals),
        "latencies": latencies,
        "latency_ms": statistics.median(latencies),
        "latency_p90_ms": sorted(latencies)[int(0.9 * (len(latencies) - 1))],
        "server_frame_ms": statistics.median(server_ms),
        "rays": stats["rays"],
        "server_ms": stats["ms"],
    }


def measure_bare(args, frames: int) -> float:
    import jax

    import fovjax
    from fovjax.foveate import FoveatedRenderer, Foveation
    from fovjax.render import StereoRig

    scene = fovjax.scenes.BUILTIN["cornell_box" if args.scene == "cornell" else args.scene]()
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(scene), eye_width=args.width, eye_height=args.height
    )
    # Prepared once, as the viewer's renderer is: each frame passes only gaze and key.
    renderer = FoveatedRenderer(scene, rig, Foveation())
    rng = random.Random(0)
    times = []
    for k in range(frames + 1):
        gaze = ((rng.uniform(0.1, 0.9), rng.uniform(0.1, 0.9)),) * 2
        t0 = time.perf_counter()
        renderer.render(gaze, key=jax.random.fold_in(jax.random.key(0), k))
        if k:  # the first call compiles
            times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--width", type=int, default=320)
    p.add_argument("--height", type=int, default=256)
    p.add_argument("--scene", default="spheres")
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--interval", type=float, default=0.1, help="seconds between mouse moves (0.1)")
    p.add_argument("--bare-frames", type=int, default=30)
    args = p.parse_args()
    v = measure_viewer(args)
    bare_ms = measure_bare(args, args.bare_frames)
    ms = v["server_ms"]
    print(f"fovjax view, {args.scene}, 2x{args.width}x{args.height}, fovea 5/10 deg, spp 1, mouse gaze")
    print(f"  first frame on the page {v['first_frame_s']:.1f} s after start (compile included)")
    print(
        f"  viewer: {v['fps']:.1f} fps (median frame interval, {v['frames']} frames), gaze->display "
        f"latency median {v['latency_ms']:.1f} ms, p90 {v['latency_p90_ms']:.1f} ms "
        f"({len(v['latencies'])} of {v['moves']} mouse moves rendered)"
    )
    print(
        f"  last frame's stages (ms): render {ms['render']:.1f}, host {ms['host']:.1f}, "
        f"gaze {ms['gaze']:.1f}, encode {ms['encode']:.1f}, server total {ms['frame']:.1f}; "
        f"{v['rays']:,} rays"
    )
    print(
        f"  bare render_stereo: {bare_ms:.1f} ms per frame ({1000 / bare_ms:.1f} fps), "
        f"median of {args.bare_frames}"
    )
    interval = 1000.0 / v["fps"]
    print(
        f"  viewer's own frames: {v['server_frame_ms']:.1f} ms median on the server (render, gaze, encode); "
        f"frame interval / that = {interval / v['server_frame_ms']:.2f}, "
        f"latency / that = {v['latency_ms'] / v['server_frame_ms']:.2f}"
    )
    print(
        f"  ratios: viewer fps / bare fps = {v['fps'] * bare_ms / 1000:.2f}; "
        f"latency / bare frame = {v['latency_ms'] / bare_ms:.2f}"
    )
    cols = [
        "per eye",
        "viewer fps",
        "latency median (p90) ms",
        "server frame ms",
        "bare render_stereo ms (fps)",
    ]
    row = [
        f"2×{args.width}×{args.height} ({args.seconds:g} s)",
        round(v["fps"], 2),
        f"{v['latency_ms']:.0f} ({v['latency_p90_ms']:.0f})",
        round(v["server_frame_ms"], 1),
        f"{bare_ms:.0f} ({1000 / bare_ms:.1f})",
        round(interval / v["server_frame_ms"], 3),
    ]
    title = f"The live viewer: {args.scene}, 5°/10°, SPP 1, mouse moved every {args.interval:g} s"
    table = {"title": title, "columns": [*cols, "frame interval / server frame"], "rows": [row]}
    write_record("view_latency", {"tables": [table], "first_frame_s": round(v["first_frame_s"], 1)})


if __name__ == "__main__":
    main()
