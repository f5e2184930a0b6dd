"""The live viewer (`fovjax view`): the page protocol's validation, the command's argument
checks, the server with a real WebSocket client (bad messages included) and the page in a real
headless Chromium driven by selenium.

The end-to-end tests share one `fovjax view` process (the command itself, on a free port), so
the frame program is compiled once for the module."""

from __future__ import annotations

import asyncio
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _extras
import numpy as np
import pytest

aiohttp = _extras.require("aiohttp", module_level=True)

from fovjax.cli import main  # noqa: E402
from fovjax.view import ACTIONS, MAX_MESSAGE_BYTES, MessageError, parse_message  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
START_TIMEOUT_S = 300  # compiling the frame program; generous for a loaded CI machine


# ---- the protocol ---------------------------------------------------------------------------------


def test_parse_message_accepts_each_kind():
    assert parse_message('{"type": "gaze", "eye": "left", "x": 0.25, "y": 1, "t": 12.5}') == {
        "type": "gaze",
        "eye": "left",
        "x": 0.25,
        "y": 1.0,
        "t": 12.5,
    }
    assert parse_message(b'{"type": "leave"}') == {"type": "leave"}
    for action in ACTIONS:
        assert parse_message(json.dumps({"type": "key", "action": action}))["action"] == action
    assert parse_message('{"type": "shown", "frame": 3, "latency_ms": null}')["latency_ms"] is None
    assert parse_message('{"type": "shown", "frame": 3}')["frame"] == 3


@pytest.mark.parametrize(
    ("message", "reason"),
    [
        ("not json", "malformed JSON"),
        ("[1, 2]", "JSON object"),
        ('{"x": 1}', "unknown message type"),
        ('{"type": "teleport"}', "unknown message type"),
        ('{"type": "gaze", "eye": "left", "x": NaN, "y": 0.5, "t": 1}', "x must be finite"),
        ('{"type": "gaze", "eye": "left", "x": 0.5, "y": Infinity, "t": 1}', "y must be finite"),
        ('{"type": "gaze", "eye": "left", "x": 1.5, "y": 0.5, "t": 1}', "x must be in [0.0, 1.0]"),
        ('{"type": "gaze", "eye": "left", "x": -0.1, "y": 0.5, "t": 1}', "x must be in"),
        ('{"type": "gaze", "eye": "left", "x": "0.5", "y": 0.5, "t": 1}', "x must be a number"),
        ('{"type": "gaze", "eye": "left", "x": true, "y": 0.5, "t": 1}', "x must be a number"),
        ('{"type": "gaze", "eye": "middle", "x": 0.5, "y": 0.5, "t": 1}', "eye must be"),
        ('{"type": "gaze", "eye": "left", "x": 0.5, "y": 0.5}', "missing keys ['t']"),
        ('{"type": "gaze", "eye": "left", "x": 0.5, "y": 0.5, "t": 1, "z": 2}', "unknown keys ['z']"),
        ('{"type": "leave", "why": "bored"}', "unknown keys ['why']"),
        ('{"type": "key", "action": "rm -rf"}', "unknown action"),
        ('{"type": "shown", "frame": -1}', "non-negative integer"),
        ('{"type": "shown", "frame": 1.5}', "non-negative integer"),
        ('{"type": "shown", "frame": 1, "latency_ms": NaN}', "latency_ms must be finite"),
        ('{"type": "leave", "pad": "' + "x" * MAX_MESSAGE_BYTES + '"}', "exceeds"),
        (b"\xff\xfe", "malformed JSON"),
        (123, "JSON text"),
    ],
)
def test_parse_message_rejects_with_the_reason(message, reason):
    with pytest.raises(MessageError) as info:
        parse_message(message)
    assert reason in str(info.value)


# ---- the command's arguments ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--width", "0"], "--width"),
        (["--height", "100000"], "--height"),
        (["--spp", "3"], "--spp"),
        (["--fovea", "nan"], "--fovea"),
        (["--fovea", "12", "--periphery", "10"], "the fovea must be smaller than the periphery"),
        (["--periphery", "200"], "--periphery"),
        (["--port", "70000"], "--port"),
        (["--host", " "], "--host"),
        (["--host", "192.0.2.1"], "cannot listen on 192.0.2.1:8000"),
        (["--scene", "no_such_scene"], "no_such_scene"),
        (["--gaze", "telepathy:1"], "telepathy"),
        (["--gaze", "synthetic:fixed:a,b"], "fixed point"),
        (["--head", "synthetic:nod"], "sway"),
        (["--gaze", "replay:/no/such/file.jsonl"], "file.jsonl"),
        (["--save-dir", __file__], "not a folder"),
    ],
)
def test_bad_arguments_are_one_line_errors(args, named, capsys):
    assert main(["view", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fovjax view: error:") and named in err
    assert "Traceback" not in err and err.count("\n") == 1


def test_debug_shows_the_traceback_of_a_bad_argument():
    from fovjax.cli import UsageError

    with pytest.raises(UsageError, match="--width 0"):
        main(["--debug", "view", "--width", "0"])


@pytest.mark.parametrize(
    ("args", "missing", "named"),
    [([], "aiohttp", "pip install 'fovjax[view]'"), (["--backend", "embree"], "embreex", "fovjax[embree]")],
)
def test_a_missing_extra_is_exit_status_1(args, missing, named, capsys, monkeypatch, tmp_path):
    import importlib.util

    installed = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == missing else installed(name, *a)
    )
    monkeypatch.chdir(tmp_path)
    assert main(["view", "--port", "0", *args]) == 1
    err = capsys.readouterr().err
    assert err.startswith("fovjax view: error:") and named in err and "Traceback" not in err


def test_rendering_that_cannot_start_is_one_error_line(capsys, monkeypatch, tmp_path):
    from fovjax.view import LiveRenderer

    def fail(self):
        raise RuntimeError("out of device memory")

    monkeypatch.setattr(LiveRenderer, "warmup", fail)
    monkeypatch.chdir(tmp_path)
    assert main(["view", "--port", "0", "--width", "8", "--height", "8"]) == 1
    out, err = capsys.readouterr()
    assert "serving http://127.0.0.1:" in out
    assert err.startswith("fovjax view: error:") and err.count("\n") == 1, err
    assert "rendering failed: RuntimeError: out of device memory" in err and "Traceback" not in err


def test_key_actions_change_the_live_state():
    import fovjax
    from fovjax.foveate import THESIS_PAIRS, Foveation
    from fovjax.render import StereoRig
    from fovjax.view import LiveRenderer

    scene = fovjax.scenes.BUILTIN["spheres"]()
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=16, eye_height=12)
    r = LiveRenderer(scene, rig, Foveation(fovea_deg=5.0, periphery_deg=10.0))
    for i, pair in enumerate(THESIS_PAIRS, start=1):
        r.apply_action(f"preset_{i}")
        assert (r.fovea_deg, r.periphery_deg) == pair
    r.apply_action("preset_1")
    for _ in range(30):  # the fovea never reaches the periphery
        r.apply_action("fovea_up")
    assert r.fovea_deg < r.periphery_deg
    for _ in range(30):
        r.apply_action("fovea_down")
    assert 0 < r.fovea_deg
    for _ in range(200):
        r.apply_action("periphery_down")
    assert r.fovea_deg < r.periphery_deg
    r.apply_action("head_right")
    r.apply_action("head_up")
    assert r.head_keys == [5.0, 5.0]
    r.apply_action("head_reset")
    assert r.head_keys == [0.0, 0.0]
    assert not r.full and not r.debug
    r.apply_action("toggle_full")
    r.apply_action("toggle_debug")
    assert r.full and r.debug


def test_view_imports_only_public_names_of_other_packages():
    import ast

    private = []
    for path in sorted((ROOT / "fovjax" / "view").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level == 1 or (node.level == 0 and not (node.module or "").startswith("fovjax")):
                continue  # the view package itself, or another distribution
            parts = (node.module or "").split(".") + [alias.name for alias in node.names]
            if any(part.startswith("_") for part in parts if part not in ("", "__future__")):
                private.append(f"{path.name}:{node.lineno}")
    assert not private, private


def test_binocular_gaze_points_both_eyes_at_one_scene_point():
    """Oracle: the right eye's gaze, traced back, lands where the left eye's came from."""
    import fovjax
    from fovjax.render import StereoRig
    from fovjax.trace import build_bvh
    from fovjax.view import binocular_gaze

    scene = fovjax.scenes.BUILTIN["spheres"]()
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=160, eye_height=128)
    bvh = build_bvh(scene)
    for pose in ((0.0, 0.0, 0.0), (10.0, -5.0, 0.0)):
        for xy in ((0.5, 0.5), (0.8, 0.3), (0.6, 0.7)):
            gaze = binocular_gaze(bvh, rig, pose, "left", xy)
            np.testing.assert_allclose(gaze[0], xy, atol=1e-6)
            assert np.all((gaze[1] > 0) & (gaze[1] < 1))  # seen by both eyes here
            back = binocular_gaze(bvh, rig, pose, "right", gaze[1])
            np.testing.assert_allclose(back[0], xy, atol=2e-3)
    with pytest.raises(ValueError, match="finite"):
        binocular_gaze(bvh, rig, None, "left", (math.nan, 0.5))


def test_tracker_gaze_and_full_mode_in_process(tmp_path):
    """A gaze source spec drives the fovea through the tracker; "full" renders every pixel."""
    import fovjax
    from fovjax.foveate import Foveation
    from fovjax.render import StereoRig
    from fovjax.view import LiveRenderer

    scene = fovjax.scenes.BUILTIN["spheres"]()
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=48, eye_height=32)
    r = LiveRenderer(
        scene, rig, Foveation(fovea_deg=10.0, periphery_deg=20.0), gaze="synthetic:fixed:0.3,0.4"
    )
    r.open()
    try:
        r.warmup()
        time.sleep(0.1)  # samples arrive at 120 Hz
        stats = r.render_next().stats
        assert stats["gaze_source"] == "synthetic:fixed:0.3,0.4" and stats["tracking_state"] == "ok"
        assert stats["gaze_left"] == pytest.approx([0.3, 0.4], abs=1e-6)
        assert stats["fovea_centre"][0] == pytest.approx([0.3, 0.4], abs=0.05)
        assert stats["ms"]["compile"] == 0.0  # warmup compiled what the frames use
        assert re.fullmatch(r"\d+ samples", stats["source_status"])
        foveated_rays = stats["primary_rays"]
        r.apply_action("toggle_full")
        full = r.render_next()
        assert full.stats["mode"] == "full" and full.stats["primary_rays"] == 2 * 48 * 32 > foveated_rays
        paths = r.save(tmp_path)
        assert json.loads(paths[-1].read_text())["mode"] == "full"
        r.apply_action("toggle_full")
        # Served (the programs are compiled now): the latency is measured on the source's clock,
        # and mouse gaze from the page is ignored while a source drives the gaze.
        run(_serve_tracker(r))
    finally:
        r.close()


def test_tracking_loss_resets_a_temporal_history_once(monkeypatch):
    """As in run_session: the frame where the tracker's state becomes "lost" drops the history
    (a temporal method's reused samples); staying lost or tracking again does not."""
    import fovjax
    from fovjax.foveate import Foveation
    from fovjax.render import StereoRig
    from fovjax.view import LiveRenderer

    scene = fovjax.scenes.BUILTIN["spheres"]()
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=48, eye_height=32)
    r = LiveRenderer(
        scene, rig, Foveation(fovea_deg=10.0, periphery_deg=20.0), gaze="synthetic:fixed:0.3,0.4"
    )
    states = iter(["ok", "lost", "lost", "ok", "degraded", "lost"])
    gaze = np.array([[0.3, 0.4], [0.3, 0.4]], np.float32)

    def tracked(now):
        return gaze, 10.0, 20.0, {"tracking_state": next(states)}, math.nan

    monkeypatch.setattr(r, "_tracked_gaze", tracked)
    resets, render = [], r.renderer.render

    def spy(*args, **kwargs):
        resets.append(kwargs["reset"])
        return render(*args, **kwargs)

    monkeypatch.setattr(r.renderer, "render", spy)
    shown = [r.render_next().stats["history_reset"] for _ in range(6)]
    assert resets == shown == [False, True, False, False, False, True]


async def _serve_tracker(renderer):
    from fovjax.view import Viewer

    viewer = Viewer(renderer, port=0)
    await viewer.start()
    try:
        client = await Client.connect(viewer.url.replace("http://", "ws://") + "ws")
        try:
            await client.send(json.dumps({"type": "gaze", "eye": "left", "x": 0.9, "y": 0.9, "t": 1.0}))
            for _ in range(5):
                stats, _ = await client.frame(timeout=120)
            assert stats["mode"] == "foveated" and stats["tracking_state"] == "ok"
            assert stats["gaze_left"] == pytest.approx([0.3, 0.4], abs=1e-6)
            assert stats["latency"]["count"] >= 1 and stats["latency"]["last_ms"] > 0
            assert stats["ignored_messages"] == 1
        finally:
            await client.close()
    finally:
        await viewer.stop()


# ---- the server: one `fovjax view` process for the module ---------------------------------------------


class ViewProcess:
    def __init__(self, args, save_dir: Path):
        self.log = tempfile.NamedTemporaryFile("w+", suffix=".log", delete=False)  # noqa: SIM115
        env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "fovjax", "view", *args, "--port", "0", "--save-dir", str(save_dir)],
            stdout=subprocess.PIPE,
            stderr=self.log,
            text=True,
            env=env,
            cwd=ROOT,
        )
        self.started = time.monotonic()
        line = self.proc.stdout.readline()
        match = re.search(r"serving (http://\S+)", line)
        if match is None:
            self.stop()
            raise AssertionError(f"fovjax view printed no URL: {line!r}; log: {self.stderr()}")
        self.url = match.group(1)
        self.port = int(re.search(r":(\d+)/", self.url).group(1))

    def ws_url(self) -> str:
        base = self.url.replace("http://", "ws://").split("?")[0]
        query = self.url.partition("?")[2]
        return base + "ws" + (f"?{query}" if query else "")

    def stderr(self) -> str:
        return Path(self.log.name).read_text()

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, sig=signal.SIGINT, timeout=30.0) -> int:
        if self.alive():
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode


@pytest.fixture(scope="module")
def save_dir():
    with tempfile.TemporaryDirectory() as d:
        yield Path(d)


@pytest.fixture(scope="module")
def server(save_dir):
    view = ViewProcess(["--scene", "spheres", "--width", "160", "--height", "128"], save_dir)
    yield view
    view.stop()


class Client:
    """A WebSocket client speaking the page's protocol."""

    def __init__(self, session, ws):
        self.session, self.ws = session, ws

    @classmethod
    async def connect(cls, url):
        session = aiohttp.ClientSession()
        return cls(session, await session.ws_connect(url, max_msg_size=0))

    async def close(self):
        await self.ws.close()
        await self.session.close()

    async def send(self, message):
        await (self.ws.send_bytes(message) if isinstance(message, bytes) else self.ws.send_str(message))

    async def next(self, timeout=START_TIMEOUT_S):
        """The next message: a dict (JSON) or ("jpeg", bytes)."""
        msg = await self.ws.receive(timeout=timeout)
        if msg.type == aiohttp.WSMsgType.TEXT:
            return json.loads(msg.data)
        if msg.type == aiohttp.WSMsgType.BINARY:
            return ("jpeg", msg.data)
        return ("closed", msg.type, self.ws.close_code)

    async def frame(self, ack=True, latency_ms=None, timeout=START_TIMEOUT_S):
        """The next frame's statistics and JPEG (acknowledged unless ack=False)."""
        deadline = time.monotonic() + timeout
        while True:
            msg = await self.next(max(deadline - time.monotonic(), 0.01))
            if isinstance(msg, dict) and msg["type"] == "frame":
                kind, jpeg = await self.next(timeout)
                assert kind == "jpeg"
                if ack:
                    await self.send(
                        json.dumps({"type": "shown", "frame": msg["frame"], "latency_ms": latency_ms})
                    )
                return msg, jpeg
            assert not (isinstance(msg, tuple) and msg[0] == "closed"), msg


def run(coro):
    return asyncio.run(coro)


def _decode(jpeg: bytes) -> np.ndarray:
    import io

    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(jpeg)).convert("RGB"))


# ---- the page in a real browser --------------------------------------------------------------------


def _chromium():
    """A headless Chromium through selenium, or the reason there is none."""
    _extras.require("selenium")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    binary = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    driver_path = shutil.which("chromedriver")
    if binary is None or driver_path is None:
        return (
            None,
            "no chromium/chromedriver on PATH (.ci/run installs Debian's chromium and chromium-driver)",
        )
    options = webdriver.ChromeOptions()
    options.binary_location = binary
    profile = tempfile.mkdtemp(prefix="fovjax-view-chromium-")
    for flag in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        "--window-size=1400,900",
        f"--user-data-dir={profile}",
    ):
        options.add_argument(flag)
    driver = webdriver.Chrome(options=options, service=Service(driver_path))
    driver.fovjax_profile = profile
    return driver, None


@pytest.fixture(scope="module")
def browser():
    driver, why = _chromium()
    if driver is None:
        pytest.skip(why)
    yield driver
    driver.quit()
    shutil.rmtree(driver.fovjax_profile, ignore_errors=True)


def _wait(driver, script, timeout=START_TIMEOUT_S, what=""):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = driver.execute_script(script)
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what or script}")


# The left eye's fovea ring in the regions/samples view, from the canvas's pixels: green
# (0.1, 1, 0.1) in linear RGB, after JPEG, searched within a box around the mouse (away from the
# scene's green sphere). Returns the ring's centre (normalised) or null.
RING_CENTRE_JS = """
const [bx0, bx1, by0, by1] = arguments;
const c = document.getElementById('frame');
const w = c.width / 2, h = c.height;
const d = c.getContext('2d').getImageData(0, 0, w, h).data;
let sx = 0, sy = 0, n = 0;
for (let y = Math.floor(by0 * h); y < by1 * h; y++) for (let x = Math.floor(bx0 * w); x < bx1 * w; x++) {
  const i = 4 * (y * w + x);
  if (d[i + 1] > 150 && d[i + 1] - Math.max(d[i], d[i + 2]) > 60) { sx += x + 0.5; sy += y + 0.5; n++; }
}
return n < 4 ? null : [sx / n / w, sy / n / h, n];
"""


def _move_mouse(driver, canvas, eye_x, eye_y):
    """Put the mouse at (eye_x, eye_y) of the left eye's display."""
    from selenium.webdriver.common.action_chains import ActionChains

    rect = driver.execute_script(
        "const r = arguments[0].getBoundingClientRect(); return [r.width, r.height];", canvas
    )
    # Offsets from the element's centre (selenium 4).
    dx = int(round(eye_x * rect[0] / 2 - rect[0] / 2))
    dy = int(round(eye_y * rect[1] - rect[1] / 2))
    ActionChains(driver).move_to_element_with_offset(canvas, dx, dy).perform()
    return (dx + rect[0] / 2) / (rect[0] / 2), (dy + rect[1] / 2) / rect[1]


def test_browser_shows_frames_and_the_fovea_follows_the_mouse(server, browser):
    try:
        _browser_session(server, browser)
    finally:
        browser.get("about:blank")  # the page leaves: the next clients are served


def _browser_session(server, browser):
    from selenium.webdriver.common.by import By

    browser.get(server.url)
    _wait(browser, "return window.fovjaxView && window.fovjaxView.displayed >= 1", what="a frame on the page")
    # The module's first client: the time from the command's start to a frame shown on the page.
    print(f"first frame on the page {time.monotonic() - server.started:.1f} s after `fovjax view` started")
    pixels = browser.execute_script(
        "const c = document.getElementById('frame'); const d = c.getContext('2d')"
        ".getImageData(0, 0, c.width, c.height).data; let lo = 255, hi = 0;"
        "for (let i = 0; i < d.length; i += 4) { lo = Math.min(lo, d[i + 1]); hi = Math.max(hi, d[i + 1]); }"
        "return [c.width, c.height, lo, hi];"
    )
    assert pixels[:2] == [320, 128] and pixels[3] - pixels[2] > 50  # a rendered scene is on the canvas
    assert "fps" in browser.find_element(By.ID, "overlay").text
    canvas = browser.find_element(By.ID, "frame")

    browser.find_element(By.TAG_NAME, "body").send_keys("v")  # the regions/samples view
    _wait(browser, "return window.fovjaxView.stats.view === 'debug'", what="the debug view", timeout=120)
    rings = []
    for target in ((0.3, 0.5), (0.75, 0.25)):
        x, y = _move_mouse(browser, canvas, *target)
        stats = _wait(
            browser,
            f"const s = window.fovjaxView.stats; return s.view === 'debug' && "
            f"Math.abs(s.gaze_left[0] - {x}) < 0.02 && Math.abs(s.gaze_left[1] - {y}) < 0.02 && s;",
            timeout=60,
            what=f"the reported gaze at {target}",
        )
        assert stats["tracking_state"] == "mouse (left eye)"
        assert stats["fovea_centre"][0] == pytest.approx([x, y], abs=0.03)
        # The next frame shown: its sharp region (the fovea ring drawn in the page) is at the mouse.
        frame = stats["frame"]
        _wait(browser, f"return window.fovjaxView.stats.frame > {frame}", timeout=60, what="the next frame")
        box = (max(x - 0.15, 0), min(x + 0.15, 1), max(y - 0.15, 0), min(y + 0.15, 1))
        ring = browser.execute_script(RING_CENTRE_JS, *box)
        assert ring is not None, "no fovea ring in the displayed frame"
        assert ring[0] == pytest.approx(x, abs=0.04) and ring[1] == pytest.approx(y, abs=0.04)
        rings.append(ring)
    assert rings[1][0] - rings[0][0] > 0.3 and rings[0][1] - rings[1][1] > 0.1
    latency = _wait(
        browser,
        "const s = window.fovjaxView.stats; return s.latency.count > 0 && s.latency;",
        timeout=60,
        what="a gaze-to-display latency",
    )
    assert latency["last_ms"] > 0
    browser.find_element(By.TAG_NAME, "body").send_keys("v")
    _wait(browser, "return window.fovjaxView.stats.view === 'image'", what="the image view", timeout=60)
    assert server.alive()


def test_serves_the_page_and_frames(server):
    async def go():
        async with aiohttp.ClientSession() as session:
            async with session.get(server.url) as page:
                assert page.status == 200 and "viewer.js" in await page.text()
            async with session.get(server.url.split("?")[0] + "static/viewer.js") as js:
                assert js.status == 200 and "WebSocket" in await js.text()
            async with session.get(server.url.split("?")[0] + "static/../_server.py") as bad:
                assert bad.status == 404
        client = await Client.connect(server.ws_url())
        try:
            stats, jpeg = await client.frame()
            image = _decode(jpeg)
            assert image.shape == (128, 320, 3)
            assert image.std() > 5  # a rendered scene, not a blank
            assert stats["size"] == [160, 128] and stats["mode"] == "foveated"
            assert stats["rays"] > 0 and sum(stats["rays_by_region"].values()) == stats["primary_rays"]
        finally:
            await client.close()

    run(go())


def test_mouse_gaze_moves_the_fovea_and_latency_is_recorded(server):
    async def go():
        client = await Client.connect(server.ws_url())
        try:
            await client.frame()
            centres = []
            for x in (0.25, 0.75):
                await client.send(
                    json.dumps({"type": "gaze", "eye": "left", "x": x, "y": 0.5, "t": 1000.0 * x})
                )
                for _ in range(20):
                    stats, _ = await client.frame(latency_ms=12.5)
                    if stats["gaze_left"][0] == pytest.approx(x, abs=1e-6):
                        break
                assert stats["gaze_left"] == pytest.approx([x, 0.5], abs=1e-6)
                assert stats["tracking_state"] == "mouse (left eye)"
                # The sharp region of the frame, from the frame's own region map, is at the gaze.
                assert stats["fovea_centre"][0] == pytest.approx([x, 0.5], abs=0.03)
                centres.append(stats["fovea_centre"])
            # The right eye follows from the rig's geometry: it moved the same way.
            assert centres[1][1][0] > centres[0][1][0]
            stats, _ = await client.frame()
            assert stats["latency"]["count"] >= 1 and stats["latency"]["last_ms"] == 12.5
        finally:
            await client.close()

    run(go())


def test_bad_messages_are_logged_and_ignored(server):
    bad = [
        "not json",
        '{"type": "gaze", "eye": "left", "x": NaN, "y": 0.5, "t": 1}',
        '{"type": "gaze", "eye": "left", "x": 7, "y": 0.5, "t": 1}',
        '{"type": "gaze", "eye": "left", "x": 0.5, "y": 0.5, "t": 1, "evil": true}',
        '{"type": "key", "action": "__import__"}',
        '{"type": "shown", "frame": 123456}',
        '{"type": "leave", "pad": "' + "x" * (4 * MAX_MESSAGE_BYTES) + '"}',
        b"\x00\x01binary",
        "[]",
    ]

    async def go():
        client = await Client.connect(server.ws_url())
        try:
            before, _ = await client.frame()
            for message in bad:
                await client.send(message)
            await client.send(json.dumps({"type": "gaze", "eye": "right", "x": 0.6, "y": 0.4, "t": 5.0}))
            for _ in range(20):
                stats, _ = await client.frame()
                if stats["gaze_right"] == pytest.approx([0.6, 0.4], abs=1e-6):
                    break
            assert stats["gaze_right"] == pytest.approx([0.6, 0.4], abs=1e-6)
            assert stats["ignored_messages"] >= before["ignored_messages"] + len(bad)
        finally:
            await client.close()
        # Far too large: aiohttp closes that connection with 1009; the server goes on. The client
        # sees 1009 when the server's close frame arrives before the socket is torn down and 1006
        # (abnormal) when it does not (a race with the client still sending), so the client's
        # code is only checked to be one of the two; the server's own log says why it closed.
        client = await Client.connect(server.ws_url())
        try:
            try:
                await client.send('{"type": "leave", "pad": "' + "x" * (1 << 20) + '"}')
            except ConnectionError:
                # The same race one step earlier: the server closed the connection before the
                # client had written the whole frame. The server's log is checked below.
                pass
            else:
                for _ in range(50):
                    msg = await client.next(timeout=60)
                    if isinstance(msg, tuple) and msg[0] == "closed":
                        break
                assert msg[0] == "closed" and msg[2] in (1009, 1006)
        finally:
            await client.close()
        client = await Client.connect(server.ws_url())
        try:
            stats, _ = await client.frame()
            assert stats["frame"] > 0
        finally:
            await client.close()

    run(go())
    assert server.alive()
    log = server.stderr()
    for reason in ("malformed JSON", "x must be finite", "x must be in", "unknown keys ['evil']", "exceeds"):
        assert reason in log, reason
    assert "binary message" in log and "Traceback" not in log
    # The server side of the too-large close, whatever code the client saw.
    assert re.search(r"connection error: Message size \d+ exceeds limit", log)


def test_never_more_than_one_frame_in_flight(server):
    """A page that does not acknowledge gets no further frames (they are dropped, not queued)."""

    async def go():
        client = await Client.connect(server.ws_url())
        try:
            first, _ = await client.frame(ack=False)
            extra = []
            with pytest.raises(TimeoutError):
                while True:
                    extra.append(await client.next(timeout=3.0))
            assert not any(isinstance(m, dict) and m["type"] == "frame" for m in extra)
            await client.send(json.dumps({"type": "shown", "frame": first["frame"]}))
            stats, _ = await client.frame()
            assert stats["frame"] > first["frame"] + 1  # frames rendered meanwhile were dropped
            assert stats["dropped_frames"] > first["dropped_frames"]
        finally:
            await client.close()

    run(go())


def test_clients_are_served_in_turn(server):
    async def go():
        a = await Client.connect(server.ws_url())
        b = None
        try:
            await a.frame()
            b = await Client.connect(server.ws_url())
            status = await b.next(timeout=30)
            assert status["type"] == "status" and status["state"] == "waiting"
            await b.send(json.dumps({"type": "key", "action": "head_right"}))  # ignored: not its turn
            stats, _ = await a.frame()
            assert stats["clients"] == 2
            await a.close()
            a = None
            stats, _ = await b.frame()
            assert stats["head_pose"][0] == 0.0
            await b.send(json.dumps({"type": "key", "action": "head_right"}))
            for _ in range(20):
                stats, _ = await b.frame()
                if stats["head_pose"][0] == 5.0:
                    break
            assert stats["head_pose"][0] == 5.0
            await b.send(json.dumps({"type": "key", "action": "head_reset"}))
        finally:
            for c in (a, b):
                if c is not None:
                    await c.close()

    run(go())


async def _save(server) -> list[Path]:
    """Press the save key once a frame is shown; the paths the page is told."""
    client = await Client.connect(server.ws_url())
    try:
        await client.frame()
        await client.send(json.dumps({"type": "key", "action": "save"}))
        for _ in range(50):
            msg = await client.next(timeout=60)
            if isinstance(msg, dict) and msg["type"] == "saved":
                return [Path(p) for p in msg["paths"]]
            if isinstance(msg, dict) and msg["type"] == "frame":
                kind, _ = await client.next()
                await client.send(json.dumps({"type": "shown", "frame": msg["frame"]}))
        raise AssertionError("no 'saved' message")
    finally:
        await client.close()


def test_save_writes_the_frame_and_its_statistics(server, save_dir):
    paths = run(_save(server))
    png, stats_path = (
        [p for p in paths if p.suffix == ".png"][0],
        [p for p in paths if p.suffix == ".json"][0],
    )
    assert png.parent == save_dir.resolve() and png.is_file() and stats_path.is_file()
    stats = json.loads(stats_path.read_text())
    assert stats["rays"] > 0 and "latency" in stats and stats["size"] == [160, 128]


# ---- safety and life cycle -------------------------------------------------------------------------


def test_other_addresses_need_the_token_and_ctrl_c_exits_cleanly(tmp_path):
    view = ViewProcess(["--scene", "spheres", "--width", "8", "--height", "8", "--host", "0.0.0.0"], tmp_path)
    try:
        assert "?token=" in view.url
        token = view.url.split("?token=")[1]
        assert len(token) >= 16
        local = view.url.replace("0.0.0.0", "127.0.0.1")
        bare = local.split("?")[0]

        async def go():
            async with aiohttp.ClientSession() as session:
                for url, status in ((bare, 403), (bare + "?token=wrong", 403), (local, 200)):
                    async with session.get(url) as r:
                        assert r.status == status, url
                with pytest.raises(aiohttp.WSServerHandshakeError):
                    await session.ws_connect(bare + "ws")
                ws = await session.ws_connect(bare + "ws?token=" + token)
                await ws.close()
                # A page from another site may not connect (WebSockets are not bound by CORS).
                with pytest.raises(aiohttp.WSServerHandshakeError):
                    await session.ws_connect(
                        bare + "ws?token=" + token, headers={"Origin": "http://evil.example"}
                    )

        run(go())
        assert view.alive()
    finally:
        # Most likely while the frame program compiles: the render thread is inside XLA.
        code = view.stop(signal.SIGINT, timeout=30)
    assert code == 130, view.stderr()  # not -6 or -11 (the interpreter finalised around XLA)
    assert "fovjax view: interrupted; nothing was written" in view.stderr()
    assert "Traceback" not in view.stderr()


def test_default_binding_is_loopback_without_token(server):
    assert server.url.startswith("http://127.0.0.1:") and "token" not in server.url


def test_port_in_use_is_a_clear_error(server, capsys):
    assert main(["view", "--port", str(server.port)]) == 2
    err = capsys.readouterr().err
    assert "cannot listen on 127.0.0.1:" in err and str(server.port) in err and "Traceback" not in err


def test_ctrl_c_while_serving_exits_130_naming_the_saved_frames(server, save_dir):
    """Last: it ends the module's server."""
    assert server.alive()
    saved = run(_save(server))
    assert server.stop(signal.SIGINT, timeout=30) == 130
    log = server.stderr()
    assert "fovjax view: interrupted; wrote" in log and "(complete); nothing else" in log, log
    assert saved and all(path.name in log for path in saved), (saved, log)
    assert not list(save_dir.glob(".*part*"))  # no half-written file left behind
    assert "Traceback" not in log
