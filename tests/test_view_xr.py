"""The headset viewer (`fovjax view --xr`): the rig made from WebXR views (symmetric, asymmetric
and canted frusta), the page's reprojection against the renderer's projection (the page's
geometry run in Node), the page protocol, the command's argument checks, the renderer in
process with a gaze tracker, and a whole session in headless Chromium with a WebXR emulation
runtime (npm's `iwer`, installed into a cache folder at test time, never committed).

Run as a program it captures the tutorial's screenshot from an emulated session:

    python tests/test_view_xr.py --screenshot docs/images/headset.png
"""

from __future__ import annotations

import io
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
import jax.numpy as jnp
import numpy as np
import pytest

aiohttp = _extras.require("aiohttp", module_level=True)

import fovjax  # noqa: E402
from fovjax.cli import main  # noqa: E402
from fovjax.view import (  # noqa: E402
    MessageError,
    XRPose,
    XRView,
    parse_xr_message,
    xr_stereo,
)
from fovjax.view._xr_geometry import head_angles, level_frame, quaternion_matrix  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
STATIC = ROOT / "fovjax" / "view" / "static"
START_TIMEOUT_S = 300  # compiling the frame program on a loaded machine
IWER_VERSION = "2.5.0"
IWER_DIR = Path(
    os.environ.get("FOVJAX_IWER_DIR") or Path.home() / ".cache" / "fovjax" / f"iwer-{IWER_VERSION}"
)
IWER_BUNDLE = IWER_DIR / "node_modules" / "iwer" / "build" / "iwer.min.js"
# The emulated headset's eyes are tiny: 2 x about 32x34 pixels (scale x the window's viewports).
WINDOW = (640, 420)
XR_SCALE = 0.1


def _need(why: str):
    """A tool the test needs is missing: a failure under FOVJAX_REQUIRE_EXTRAS=1, else a skip."""
    if _extras.required():
        pytest.fail(f"{why}; {_extras.REQUIRE_VARIABLE}=1 requires it", pytrace=False)
    pytest.skip(why)


# ---- the rig from the views -----------------------------------------------------------------------


def _quaternion(axis, degrees) -> list[float]:
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    half = math.radians(degrees) / 2
    return [*(axis * math.sin(half)).tolist(), math.cos(half)]


def _compose(q1, q2) -> list[float]:
    """q1 then q2 applied in q1's frame (q1 * q2), quaternions (x, y, z, w)."""
    x1, y1, z1, w1 = q1
    x2, y2, z2, w2 = q2
    return [
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
    ]


def _projection(left, right, bottom, top, near=0.1, far=100.0) -> list[float]:
    """A WebXR-style (column-major) frustum from tangents."""
    p = np.zeros((4, 4))
    p[0, 0] = 2 / (right - left)
    p[1, 1] = 2 / (top - bottom)
    p[0, 2] = (right + left) / (right - left)
    p[1, 2] = (top + bottom) / (top - bottom)
    p[2, 2] = -(far + near) / (far - near)
    p[2, 3] = -2 * far * near / (far - near)
    p[3, 2] = -1.0
    return p.T.reshape(-1).tolist()


def _pose(
    head_q,
    *,
    toe_deg=0.0,
    ipd=0.064,
    frusta=None,
    viewport=(1000, 1100),
    head_p=(0.1, -0.05, 0.2),
    eye_pitch_deg=0.0,
    t=5.0,
):
    """A headset pose: eyes at +-ipd/2 on the head's x axis, turned out by toe_deg (and the left
    eye pitched up, the right down by eye_pitch_deg: not a rig's eyes), frusta (left and right
    tangents) as given (default: a Quest-like asymmetric pair, mirrored)."""
    if frusta is None:
        frusta = ((-1.3, 0.9, -1.1, 0.95), (-0.9, 1.3, -1.1, 0.95))
    head_r = quaternion_matrix(head_q)
    views = []
    for eye, side, frustum in (("left", -1, frusta[0]), ("right", 1, frusta[1])):
        views.append(
            XRView(
                eye=eye,
                position=np.asarray(head_p) + head_r @ np.array([side * ipd / 2, 0.0, 0.0]),
                orientation=_compose(
                    _compose(head_q, _quaternion((0, 1, 0), -side * toe_deg)),
                    _quaternion((1, 0, 0), -side * eye_pitch_deg),
                ),
                projection=_projection(*frustum),
                viewport=viewport,
            )
        )
    return XRPose(t=t, position=head_p, orientation=head_q, views=tuple(views))


def _corner_directions(view: XRView) -> np.ndarray:
    left, right, bottom, top = view.tangents()
    corners = np.array([[x, y, -1.0] for x in (left, right) for y in (bottom, top)])
    return (view.rotation() @ corners.T).T


def _image_xy(stereo, eye: int, local_direction) -> np.ndarray:
    """Where the renderer's own camera puts a `local` direction: normalised image coordinates."""
    world_r, _ = level_frame(fovjax.scenes.default_camera(fovjax.scenes.spheres()))
    camera = stereo.rig.eye_cameras(None)[eye]
    point = np.asarray(camera.position) + world_r @ np.asarray(local_direction)
    xy, depth = camera.project(jnp.asarray(point, jnp.float32))
    assert float(depth) > 0
    return np.asarray(xy) / [stereo.rig.eye_width, stereo.rig.eye_height]


ORIGIN = fovjax.scenes.default_camera(fovjax.scenes.spheres())


def test_symmetric_views_make_the_plain_rig():
    pose = _pose([0, 0, 0, 1], frusta=((-1, 1, -1, 1), (-1, 1, -1, 1)), viewport=(400, 400), head_p=(0, 0, 0))
    stereo = xr_stereo(pose, ORIGIN, scale=0.1)
    rig = stereo.rig
    assert (rig.eye_width, rig.eye_height, rig.fov_axis) == (40, 40, "vertical")
    assert float(rig.fov_deg) == pytest.approx(90.0, abs=2e-3)
    assert np.abs(np.asarray(rig.offsets)).max() == 0 and float(rig.toe_out_deg) == 0
    assert float(rig.ipd) == pytest.approx(0.064)
    left, right = rig.eye_cameras(None)
    # The head at the scene's viewpoint, level, eyes 64 mm apart across the viewing direction.
    np.testing.assert_allclose((np.asarray(left.position) + right.position) / 2, ORIGIN.position, atol=1e-6)
    assert stereo.position_error_m < 1e-9 and stereo.rotation_error_deg < 1e-6
    np.testing.assert_allclose(stereo.straight_ahead(), 0.5, atol=1e-6)


@pytest.mark.parametrize("toe_deg", [0.0, 5.0])
def test_asymmetric_canted_views_are_held_by_the_rendered_frusta(toe_deg):
    head_q = _compose(_quaternion((0, 1, 0), -20.0), _quaternion((1, 0, 0), 10.0))  # right 20°, up 10°
    pose = _pose(head_q, toe_deg=toe_deg)
    stereo = xr_stereo(pose, ORIGIN, scale=0.05)
    assert float(stereo.rig.toe_out_deg) == pytest.approx(toe_deg, abs=1e-6)
    # The rig expresses these views exactly: eyes where the views are, turned as they are.
    assert stereo.position_error_m < 1e-6 and stereo.rotation_error_deg < 1e-4
    assert head_angles(pose.rotation())[:2] == pytest.approx((20.0, 10.0), abs=1e-6)
    for eye, view in enumerate(pose.views):
        corners = np.stack([_image_xy(stereo, eye, d) for d in _corner_directions(view)])
        # Every corner of the headset's frustum is inside the rendered image (its principal point
        # moved off-centre: asymmetric), and the frustum fills it (tight on one axis at least).
        assert corners.min() > -1e-4 and corners.max() < 1 + 1e-4, corners
        spans = corners.max(axis=0) - corners.min(axis=0)
        assert spans.max() > 0.999
        # The page's numbers (rendered eye rotation and tangents) are the renderer's camera.
        for d in _corner_directions(view):
            assert stereo._image_point(eye, d) == pytest.approx(_image_xy(stereo, eye, d), abs=1e-4)
        # Fixed foveation: each eye's straight-ahead direction (its lens centre).
        forward = view.rotation() @ [0, 0, -1]
        assert stereo.straight_ahead()[eye] == pytest.approx(_image_xy(stereo, eye, forward), abs=1e-4)
    # A tracker's display coordinates: its corners are the headset frustum's corners.
    display = stereo.display_to_image([[0.0, 1.0], [1.0, 0.0]])
    lefts = _corner_directions(pose.views[0])
    rights = _corner_directions(pose.views[1])
    assert display[0] == pytest.approx(_image_xy(stereo, 0, lefts[0]), abs=1e-4)  # left, bottom
    assert display[1] == pytest.approx(_image_xy(stereo, 1, rights[3]), abs=1e-4)  # right, top
    # The same headset frame after frame: one rig shape, one compiled program.
    turned = _pose(_quaternion((0, 1, 0), 35.0), toe_deg=toe_deg, head_p=(0.3, 0.1, -0.2))
    assert xr_stereo(turned, ORIGIN, scale=0.05).shape == stereo.shape


def test_eyes_the_rig_cannot_express_are_measured_and_still_covered():
    pose = _pose([0, 0, 0, 1], eye_pitch_deg=2.0)  # each eye pitched 2° off the head's
    stereo = xr_stereo(pose, ORIGIN, scale=0.05)
    assert stereo.rotation_error_deg == pytest.approx(2.0, abs=1e-6)
    for eye, view in enumerate(pose.views):
        corners = np.stack([_image_xy(stereo, eye, d) for d in _corner_directions(view)])
        assert corners.min() > -1e-4 and corners.max() < 1 + 1e-4, corners


def test_head_angles_invert_the_head_rotation():
    from fovjax.render import head_rotation

    for angles in [(0, 0, 0), (30, -20, 10), (-150, 60, -45), (179, 5, 80)]:
        assert head_angles(np.asarray(head_rotation(angles))) == pytest.approx(angles, abs=1e-3)


@pytest.mark.parametrize(
    ("change", "named"),
    [
        (lambda p: p.update(scale=0), "scale must be a positive number"),
        (lambda p: p.update(scale=40.0), "over 8192 per side"),
        (lambda p: p.update(toe_deg=70.0), "not a headset's eyes"),
        (lambda p: p.update(eye_pitch_deg=40.0, frusta=((-1, 1, -2, 2), (-1, 1, -2, 2))), "reaches 90°"),
    ],
)
def test_views_that_cannot_be_rendered_say_why(change, named):
    args = {"scale": 0.1, "toe_deg": 0.0, "frusta": None, "eye_pitch_deg": 0.0}
    change(args)
    scale = args.pop("scale")
    with pytest.raises(ValueError, match=named):
        xr_stereo(_pose([0, 0, 0, 1], **args), ORIGIN, scale=scale)


# ---- the page's reprojection, run in Node -----------------------------------------------------------


def test_the_pages_reprojection_is_the_renderers_projection():
    """xr_math.js's `frameUV` (what the fragment shader does per display pixel) against the
    renderer's own cameras: a display ray of the view at a newer head pose lands on the pixel
    the renderer put that direction at."""
    node = shutil.which("node")
    if node is None:
        _need("no node on PATH to run the page's geometry (the WebXR emulator needs Node and npm too)")
    rendered = _pose(_quaternion((0, 1, 0), -20.0), toe_deg=5.0)
    stereo = xr_stereo(rendered, ORIGIN, scale=0.05)
    now = _pose(_compose(_quaternion((0, 1, 0), -26.0), _quaternion((1, 0, 0), 4.0)), toe_deg=5.0)
    ndc = [[x, y] for x in np.linspace(-0.95, 0.95, 9) for y in np.linspace(-0.95, 0.95, 9)]
    page = stereo.page_json()
    script = """
const M = require(process.argv[1]);
const input = JSON.parse(require("fs").readFileSync(0, "utf8"));
const out = input.eyes.map((eye, i) => {
  const inv = M.mat4Invert(input.projections[i]);
  const m = M.renderFromView(eye.rotation, input.orientations[i]);
  return input.ndc.map((p) => M.frameUV(m, eye.tangents, inv, p));
});
process.stdout.write(JSON.stringify(out));
"""
    payload = {
        "eyes": page["eyes"],
        "projections": [v.projection.tolist() for v in now.views],
        "orientations": [v.orientation.tolist() for v in now.views],
        "ndc": ndc,
    }
    proc = subprocess.run(
        [node, "-e", script, str(STATIC / "xr_math.js")],
        input=json.dumps(payload),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    uvs = json.loads(proc.stdout)
    inside = 0
    for eye, view in enumerate(now.views):
        inv = np.linalg.inv(np.asarray(view.projection).reshape(4, 4).T)
        for (x, y), uv in zip(ndc, uvs[eye], strict=True):
            p = inv @ [x, y, -1.0, 1.0]
            direction = view.rotation() @ (p[:3] / p[3])
            want = _image_xy(stereo, eye, direction / np.linalg.norm(direction))
            if uv is None:  # off the rendered frame: the renderer's projection says so too
                assert want.min() < 1e-4 or want.max() > 1 - 1e-4, (eye, x, y, want)
            else:
                inside += 1
                assert uv == pytest.approx(want, abs=1e-4), (eye, x, y)
    assert inside > len(ndc)  # most display rays of both eyes fall on the frame


# ---- the protocol ------------------------------------------------------------------------------------


def _pose_message(**changes) -> dict:
    view = {
        "eye": "left",
        "position": [-0.03, 0, 0],
        "orientation": [0, 0, 0, 1],
        "projection": _projection(-1, 1, -1, 1),
        "viewport": [400, 400],
    }
    msg = {
        "type": "xr_pose",
        "t": 12.5,
        "head": {"position": [0, 0, 0], "orientation": [0, 0, 0, 1]},
        "views": [view, {**view, "eye": "right", "position": [0.03, 0, 0]}],
    }
    msg.update(changes)
    return msg


def test_parse_xr_message_accepts_each_kind():
    pose = parse_xr_message(json.dumps(_pose_message()))["pose"]
    assert isinstance(pose, XRPose) and [v.eye for v in pose.views] == ["left", "right"]
    reversed_views = _pose_message()
    reversed_views["views"].reverse()
    assert parse_xr_message(json.dumps(reversed_views))["pose"].views[0].eye == "left"
    assert parse_xr_message('{"type": "xr_state", "state": "ended", "reason": ""}')["state"] == "ended"
    shown = {
        "type": "shown",
        "frame": 3,
        "display_hz": 72.0,
        "render_hz": None,
        "pose_age_ms": 20.5,
        "reprojection_deg": 1.5,
    }
    assert parse_xr_message(json.dumps(shown))["reprojection_deg"] == 1.5
    assert parse_xr_message('{"type": "key", "action": "fovea_up"}') == {"type": "key", "action": "fovea_up"}


def _bad_view(**changes) -> dict:
    msg = _pose_message()
    msg["views"][1].update(changes)
    return msg


@pytest.mark.parametrize(
    ("message", "reason"),
    [
        ("[1]", "expected a JSON object"),
        ('{"type": "gaze", "eye": "left", "x": 0, "y": 0, "t": 0}', "unknown message type 'gaze'"),
        ('{"type": "key", "action": "head_left"}', "the head pose comes from the headset"),
        (_pose_message(views=[_pose_message()["views"][0]]), "views must be a list of two"),
        (_bad_view(eye="left"), "two views, left and right"),
        (_bad_view(eye="none"), "view eye must be 'left' or 'right'"),
        (_bad_view(viewport=[0, 457]), "a mono device"),
        (_bad_view(orientation=[0, 0, 0, 2]), "unit quaternion"),
        (_bad_view(position=[0, float("nan"), 0]), "position must be 3 finite numbers"),
        (_bad_view(projection=[1.0] * 16), "not a perspective frustum"),
        (_bad_view(extra=1), "unknown keys ['extra']"),
        (_pose_message(t=-1), "pose t must be a time"),
        ('{"type": "xr_state", "state": "bored", "reason": ""}', "state must be one of"),
        (
            '{"type": "shown", "frame": 1, "display_hz": -1, "render_hz": null, "pose_age_ms": null, '
            '"reprojection_deg": null}',
            "display_hz must be in",
        ),
        (json.dumps({"type": "xr_state", "state": "ended", "reason": "x" * 5000}), "exceeds the 4096-byte"),
    ],
)
def test_parse_xr_message_rejects_with_the_reason(message, reason):
    data = message if isinstance(message, str) else json.dumps(message)
    with pytest.raises(MessageError, match=re.escape(reason)):
        parse_xr_message(data)


# ---- the command ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--xr", "--study", "pair", "--participant", "p01", "-o", "x"], "--xr with --study pair"),
        (["--xr", "--width", "64"], "--width with --xr"),
        (["--xr", "--head", "synthetic:sway"], "the head pose comes from the headset"),
        (["--xr", "--regions", "thesis"], "--regions thesis with --xr"),
        (["--xr", "--xr-scale", "0"], "--xr-scale"),
        (["--xr-scale", "0.5"], "--xr-scale: only with --xr"),
    ],
)
def test_bad_arguments_are_one_line_errors(args, named, capsys):
    assert main(["view", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fovjax view: error:") and named in err, err
    assert "Traceback" not in err and err.count("\n") == 1


def test_an_unreachable_tracker_is_one_line_before_serving(capsys, monkeypatch, tmp_path):
    import socket

    monkeypatch.chdir(tmp_path)
    with socket.socket() as probe:  # a port nothing listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    assert main(["view", "--xr", "--port", "0", "--gaze", f"pupil:127.0.0.1:{port}"]) == 1
    out, err = capsys.readouterr()
    assert "serving" not in out
    assert err.startswith("fovjax view: error:") and f"pupil:127.0.0.1:{port}" in err, err
    assert "could not connect" in err and err.count("\n") == 1 and "Traceback" not in err


# ---- the renderer in process, with a gaze tracker ---------------------------------------------------


def test_renderer_follows_the_headset_and_maps_the_trackers_gaze(tmp_path):
    from fovjax.foveate import Foveation
    from fovjax.render import RenderConfig
    from fovjax.view import XRRenderer

    scene = fovjax.scenes.spheres()
    live = XRRenderer(
        scene,
        Foveation(fovea_deg=5.0, periphery_deg=10.0),
        scale=0.02,
        config=RenderConfig(max_depth=1),
        gaze="synthetic:fixed:0.25,0.75",
    )
    live.open()
    try:
        assert not live.in_session
        with pytest.raises(RuntimeError, match="enter VR"):
            live.render_next()
        first = _pose([0, 0, 0, 1], viewport=(1200, 1200), head_p=(0, 0, 0))
        assert live.set_pose(first) is True  # a new shape: its first frame compiles
        frame = live.render_next()  # compiles
        assert live.in_session and live.set_pose(first) is False
        deadline = time.monotonic() + 30
        while frame.stats["tracking_state"] != "ok" and time.monotonic() < deadline:
            time.sleep(0.02)  # the source's first samples
            frame = live.render_next()
        assert frame.stats["tracking_state"] == "ok", frame.stats["tracking_state"]
        stats = frame.stats
        stereo = xr_stereo(first, live.origin, 0.02)
        assert stats["size"] == [live.rig.eye_width, live.rig.eye_height] == [26, 24]
        assert stats["gaze_source"] == "gaze source synthetic:fixed:0.25,0.75"
        # The tracker's display point, mapped into each rendered (larger, off-centre) eye image.
        want = stereo.display_to_image([[0.25, 0.75], [0.25, 0.75]])
        assert stats["gaze_left"] == pytest.approx(want[0], abs=1e-5)
        assert stats["gaze_right"] == pytest.approx(want[1], abs=1e-5)
        assert stats["head_pose"] == pytest.approx([0, 0, 0], abs=1e-6)
        image = np.asarray(frame.image)
        assert image.shape == (24, 52, 3) and image.std() > 0.01
        # The head turns right 30°: the next frame renders there, with the same program.
        live.set_pose(_pose(_quaternion((0, 1, 0), -30.0), viewport=(1200, 1200), head_p=(0, 0, 0)))
        turned = live.render_next()
        assert turned.stats["head_pose"][0] == pytest.approx(30.0, abs=1e-4)
        assert turned.stats["ms"]["compile"] == 0
        assert np.abs(np.asarray(turned.image) - image).mean() > 0.01
        live.end_session()
        assert not live.in_session
        paths = live.save(tmp_path)
        assert json.loads(paths[-1].read_text())["xr"]["eyes"][1]["eye"] == "right"
    finally:
        live.close()


# ---- a session in headless Chromium with the WebXR emulator ----------------------------------------


def _iwer_bundle() -> Path:
    """The WebXR emulation runtime's browser bundle, installed into a cache folder on first use."""
    if IWER_BUNDLE.exists():
        return IWER_BUNDLE
    npm = shutil.which("npm")
    if npm is None:
        _need(f"no npm on PATH to fetch the WebXR emulator iwer@{IWER_VERSION}")
    IWER_DIR.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run(
        [npm, "install", "--prefix", str(IWER_DIR), "--no-audit", "--no-fund", f"iwer@{IWER_VERSION}"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    if proc.returncode != 0 or not IWER_BUNDLE.exists():
        lines = [line for line in proc.stderr.splitlines() if line.strip() and "complete log" not in line]
        _need(
            f"npm could not fetch the WebXR emulator iwer@{IWER_VERSION} into {IWER_DIR}: "
            + "; ".join(lines[:2] or ["no output"])
        )
    return IWER_BUNDLE


def _emulator_script(bundle: Path) -> str:
    # A stereo headset (the emulator's default is mono); its views fill the window.
    return (
        bundle.read_text()
        + "\n;window.fovjaxHeadset = new IWER.XRDevice(IWER.metaQuest3, {stereoEnabled: true});"
        + "window.fovjaxHeadset.installRuntime({forceInstall: true});"
    )


def _chromium(window=WINDOW):
    _extras.require("selenium")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    binary = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    driver_path = shutil.which("chromedriver")
    if binary is None or driver_path is None:
        # A system package, as for tests/test_view.py's browser test: a skip that says why.
        why = "no chromium/chromedriver on PATH (.ci/run puts Debian's chromium and chromium-driver there)"
        pytest.skip(why)
    options = webdriver.ChromeOptions()
    options.binary_location = binary
    profile = tempfile.mkdtemp(prefix="fovjax-view-xr-chromium-")
    for flag in (
        "--headless",
        "--no-sandbox",
        # WebGL2 on the CPU (SwiftShader): the page's reprojection draws with it.
        "--enable-unsafe-swiftshader",
        "--use-angle=swiftshader",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        f"--window-size={window[0]},{window[1]}",
        f"--user-data-dir={profile}",
    ):
        options.add_argument(flag)
    driver = webdriver.Chrome(options=options, service=Service(driver_path))
    driver.fovjax_profile = profile
    return driver


class XRProcess:
    """`fovjax view --xr` as a program, on a free port, its log kept."""

    def __init__(self, args):
        self.log = tempfile.NamedTemporaryFile("w+", suffix=".log", delete=False)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "fovjax", "view", "--xr", "--port", "0", *args],
            cwd=tempfile.mkdtemp(prefix="fovjax-view-xr-"),
            env={**os.environ, "PYTHONPATH": str(ROOT)},
            stdout=subprocess.PIPE,
            stderr=self.log,
            text=True,
        )
        line = self.proc.stdout.readline()
        match = re.search(r"serving (http://\S+)", line)
        if match is None:
            self.stop()
            raise AssertionError(f"fovjax view --xr printed no URL: {line!r}; log: {self.stderr()}")
        self.url = match.group(1)

    def stderr(self) -> str:
        return Path(self.log.name).read_text()

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode


@pytest.fixture(scope="module")
def browser():
    driver = _chromium()
    yield driver
    driver.quit()
    shutil.rmtree(driver.fovjax_profile, ignore_errors=True)


@pytest.fixture(scope="module")
def xr_server():
    # Every pixel foveal (the eyes' corners are within 60° of their centres): the frames show the
    # scene, not a sparse periphery's sampling pattern, so that two frames compare pixel by pixel.
    args = ["--fovea", "60", "--periphery", "80", "--spp", "4", "--max-depth", "1", "--verbose"]
    view = XRProcess(["--scene", "spheres", "--xr-scale", str(XR_SCALE), *args])
    yield view
    view.stop()


def _wait(driver, script, timeout=60.0, what=""):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = driver.execute_script(script)
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(
        f"timed out waiting for {what or script}: {driver.execute_script('return window.fovjaxXR')}"
    )


def _inject(driver, source: str) -> str:
    return driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": source})["identifier"]


def _screenshot(driver) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(driver.get_screenshot_as_png())).convert("RGB"), np.float32)


def _shift(image, reference, most=80) -> int:
    """The horizontal shift (display pixels) that best lays `image` on `reference`, from the
    middle band of both eyes' views (where `image`'s column x shows `reference`'s x - shift)."""
    h, w = reference.shape[:2]
    eye = w // 2
    band = slice(int(0.3 * h), int(0.8 * h))
    lo, hi = int(0.3 * eye), int(0.6 * eye)  # inside every frame whatever the turn (right)

    def cost(dx):
        return np.mean(
            [
                np.abs(image[band, x0 + lo : x0 + hi] - reference[band, x0 + lo - dx : x0 + hi - dx]).mean()
                for x0 in (0, eye)
            ]
        )

    return min(range(-most, most + 1), key=cost)


def _turn_head(driver, yaw_deg: float, pitch_deg: float = 0.0) -> None:
    """The emulated headset turned right by yaw_deg (about -y), then up by pitch_deg."""
    q = _compose(_quaternion((0, 1, 0), -yaw_deg), _quaternion((1, 0, 0), pitch_deg))
    driver.execute_script(f"window.fovjaxHeadset.quaternion.set({q[0]}, {q[1]}, {q[2]}, {q[3]});")


def _displayed_after(driver, frames: int) -> None:
    """Wait until `frames` more display frames are drawn."""
    start = driver.execute_script("return window.fovjaxXR.displayFrames")
    _wait(
        driver, f"return window.fovjaxXR.displayFrames >= {start + frames}", what=f"{frames} display frames"
    )


def _enter_vr(driver, server) -> dict:
    from selenium.webdriver.common.by import By

    driver.get(server.url)
    _wait(
        driver, "return window.fovjaxXR && window.fovjaxXR.supported === true", what="immersive-vr (emulated)"
    )
    _wait(driver, "return window.fovjaxXR.info !== null", what="the server's xr_info")
    driver.find_element(By.ID, "enter").click()
    _wait(driver, "return window.fovjaxXR.mode === 'vr'", what="the immersive session")
    return _wait(
        driver,
        "const x = window.fovjaxXR; return x.framesShown >= 2 && x.shownStats",
        timeout=START_TIMEOUT_S,
        what="frames in the headset",
    )


def test_a_headset_session_in_headless_chromium(xr_server, browser):
    from selenium.webdriver.common.by import By

    script = _inject(browser, _emulator_script(_iwer_bundle()))
    try:
        _headset_session(xr_server, browser, By)
    finally:
        browser.execute_cdp_cmd("Page.removeScriptToEvaluateOnNewDocument", {"identifier": script})
        browser.get("about:blank")


YAW_DEG = 12.0


def _headset_session(server, driver, By):
    stats = _enter_vr(driver, server)
    gaze_line = driver.find_element(By.ID, "gaze").get_attribute("textContent")
    assert gaze_line.startswith("gaze: view centre (fixed foveation)")
    # Both eyes' views reached the renderer: the rig is the one the page's views make.
    pose = parse_xr_message(json.dumps(driver.execute_script("return window.fovjaxXR.lastPose")))["pose"]
    stereo = xr_stereo(pose, ORIGIN, XR_SCALE)
    assert stats["size"] == [stereo.rig.eye_width, stereo.rig.eye_height]
    assert max(stats["size"]) <= 64
    for got, want in zip(stats["xr"]["eyes"], stereo.page_json()["eyes"], strict=True):
        assert got["eye"] == want["eye"]
        assert got["position"] == pytest.approx(want["position"], abs=1e-6)
        assert got["tangents"] == pytest.approx(want["tangents"], abs=1e-6)
    assert stats["xr"]["ipd_m"] == pytest.approx(0.063, abs=1e-6)  # the emulator's IPD
    assert stats["gaze_source"] == "view centre (fixed foveation)"
    assert stats["gaze_left"] == pytest.approx(stereo.straight_ahead()[0].tolist(), abs=1e-6)
    assert stats["head_pose"] == pytest.approx([0, 0, 0], abs=1e-3)
    driver.execute_script("window.fovjaxXR.hud = false;")

    # Hold the frame (rendered looking ahead) and turn the head: the held frame is reprojected.
    driver.execute_script("window.fovjaxXR.setHold(true);")
    held = driver.execute_script("return window.fovjaxXR.shownStats.frame")
    _displayed_after(driver, 3)
    ahead = _screenshot(driver)
    _turn_head(driver, YAW_DEG)
    _displayed_after(driver, 3)
    reprojected = _screenshot(driver)
    x = driver.execute_script("return window.fovjaxXR")
    assert x["shownStats"]["frame"] == held
    assert x["reprojectionDeg"] == pytest.approx(YAW_DEG, abs=0.1)
    assert x["poseAgeMs"] > 0 and x["displayHz"] > 0
    # Released: a frame rendered at the turned pose arrives, then held again for the comparison.
    driver.execute_script("window.fovjaxXR.setHold(false);")
    turned = _wait(
        driver,
        f"const s = window.fovjaxXR.shownStats; return Math.abs(s.head_pose[0] - {YAW_DEG}) < 0.01 && s;",
        timeout=120,
        what="a frame rendered at the turned head pose",
    )
    driver.execute_script("window.fovjaxXR.setHold(true);")
    _displayed_after(driver, 3)
    assert driver.execute_script("return window.fovjaxXR.reprojectionDeg") < 0.1
    rendered_there = _screenshot(driver)
    driver.execute_script("window.fovjaxXR.setHold(false);")
    # Where the scene is on the display: the frame rendered looking ahead, shown unturned, sits
    # where the head's turn says away from the frame rendered at the turned pose; reprojected to
    # the turned pose, it sits on it.
    view = pose.views[0]
    expected = view.viewport[0] / 2 * view.projection[0] * math.tan(math.radians(YAW_DEG))
    unturned, kept = _shift(ahead, rendered_there), _shift(reprojected, rendered_there)
    print(
        f"display shift to the frame rendered there: unturned {unturned} px (the turn: {expected:.1f}), "
        f"reprojected {kept} px"
    )
    assert unturned == pytest.approx(expected, rel=0.25)
    assert abs(kept) <= max(3, 0.15 * expected)
    assert turned["head_pose"][0] == pytest.approx(YAW_DEG, abs=0.01)

    # The page's measurements, reported to the server and logged one line per frame.
    overlay = driver.find_element(By.ID, "overlay").get_attribute("textContent")
    assert "head pose age at display" in overlay and "reprojection" in overlay
    lines = re.findall(
        r"xr frame (\d+): 2x(\d+)x(\d+) foveated, render [\d.]+ ms, render rate [\d.–]+(?: Hz)?, display "
        r"[\d.]+ Hz, head pose age at display -?[\d.]+ ms, reprojection ([\d.]+)°",
        server.stderr(),
    )
    assert len(lines) >= 2, server.stderr()[-2000:]
    assert [int(v) for v in lines[-1][1:3]] == stats["size"]

    # The session ends (the headset's own menu): back to the 2D page.
    driver.execute_script("window.fovjaxHeadset.activeSession.end();")
    _wait(driver, "return window.fovjaxXR.mode === '2d'", what="the 2D page")
    assert driver.find_element(By.ID, "status").text == "left VR: back to the 2D page"
    enter = driver.find_element(By.ID, "enter")
    assert enter.is_displayed() and enter.is_enabled() and enter.text == "Enter VR"
    deadline = time.monotonic() + 30
    while "left VR: back to the 2D page" not in server.stderr() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert "left VR: back to the 2D page" in server.stderr()


@pytest.mark.parametrize(
    ("injected", "says"),
    [
        (None, "WebXR is here but no immersive-vr device"),
        ("delete Navigator.prototype.xr;", "no WebXR in this browser (navigator.xr is missing)"),
    ],
    ids=["no-headset", "no-webxr"],
)
def test_a_browser_without_webxr_is_told_in_one_line(xr_server, browser, injected, says):
    from selenium.webdriver.common.by import By

    script = None if injected is None else _inject(browser, injected)
    try:
        browser.get(xr_server.url)
        text = _wait(
            browser,
            "const s = document.getElementById('support');"
            "return s.className === 'unsupported' && s.textContent;",
            what="the page's verdict on WebXR",
        )
        assert text.startswith(says) and "\n" not in text
        assert not browser.find_element(By.ID, "enter").is_enabled()
        deadline = time.monotonic() + 30
        logged = []
        while not logged and time.monotonic() < deadline:
            logged = [line for line in xr_server.stderr().splitlines() if says in line]
            time.sleep(0.1)
        assert len(logged) == 1 and "cannot enter VR" in logged[0], xr_server.stderr()[-2000:]
    finally:
        if script is not None:
            browser.execute_cdp_cmd("Page.removeScriptToEvaluateOnNewDocument", {"identifier": script})
        browser.get("about:blank")


# ---- the tutorial's screenshot ---------------------------------------------------------------------


def capture(path: Path, scale: float = 0.5, window=(1280, 560)) -> None:
    """An emulated session's view in the headset (both eyes, the text panel) saved as `path`:
    the head turned to the spheres, the thesis's 10°/20° pair."""
    server = XRProcess(["--scene", "spheres", "--xr-scale", str(scale), "--fovea", "10", "--periphery", "20"])
    driver = _chromium(window)
    try:
        _inject(driver, _emulator_script(_iwer_bundle()))
        _enter_vr(driver, server)
        _turn_head(driver, 6.0, -13.0)
        turned = "const s = window.fovjaxXR.shownStats; return Math.abs(s.head_pose[1] + 13) < 0.01"
        _wait(driver, turned, 120, what="a frame rendered at the turned head")
        _displayed_after(driver, 8)
        driver.save_screenshot(str(path))
    finally:
        driver.quit()
        shutil.rmtree(driver.fovjax_profile, ignore_errors=True)
        server.stop()


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--screenshot", type=Path, required=True, help="where to save the PNG")
    capture(parser.parse_args().screenshot)
