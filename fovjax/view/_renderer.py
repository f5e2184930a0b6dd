"""The viewer's renderer: the live state (gaze, head, thresholds, modes) and one frame at a time.

`LiveRenderer.render_next()` renders one foveated (or full) stereo frame for the newest gaze
and head pose through its `fovjax.FoveatedRenderer` (made once) and encodes it as a JPEG. It is
called from one worker thread only (the server's single-thread executor); the page's inputs
(`set_mouse`, `apply_action`, ...) arrive on the event loop's thread and only replace small
values under a lock, so a frame always reads one consistent, newest state.

Gaze: from the mouse (one eye points, the other eye's gaze follows from the rig's geometry,
`binocular_gaze`), or from a source spec through a `fovjax.devices.GazeTracker` (hold, widen,
recover as in `fovjax session`). Head: keys (yaw/pitch steps) and, with a head source, its pose
through a `HeadTracker` plus the key offsets.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import threading
import time
from pathlib import Path

import jax
import numpy as np

from ..foveate import FoveatedFrame

HEAD_STEP_DEG = 5.0
FOVEA_STEP_DEG = 0.5
PERIPHERY_STEP_DEG = 1.0
MAX_THRESHOLD_DEG = 90.0
MIN_GAP_DEG = 0.5
JPEG_QUALITY = 90


@dataclasses.dataclass(frozen=True)
class RenderedFrame:
    """One rendered frame: the JPEG shown, its statistics (JSON-ready), and what `save` writes."""

    number: int
    jpeg: bytes
    stats: dict
    image: np.ndarray
    debug_image: np.ndarray | None
    gaze_t: float | None  # page time (ms) of the mouse event it used, None for a tracker
    gaze_timestamp: float | None  # tracker sample time (s, source clock), None for the mouse
    gaze_new: bool  # the first frame to use this gaze event


def encode_jpeg(image: np.ndarray, quality: int = JPEG_QUALITY) -> bytes:
    """Linear RGB (H, W, 3) -> JPEG bytes, tone-mapped and sRGB-encoded as `save_image` does PNGs."""
    from PIL import Image

    from ..files import linear_to_srgb, tonemap

    rgb8 = np.round(linear_to_srgb(tonemap(np.asarray(image, np.float32))) * 255).astype(np.uint8)
    buf = io.BytesIO()
    # No chroma subsampling: the debug view's one-pixel region edges stay their colour.
    Image.fromarray(rgb8).save(buf, format="JPEG", quality=quality, subsampling=0)
    return buf.getvalue()


def _fovea_centre(regions: np.ndarray) -> list:
    """Per eye, the mean (x, y) of the foveal pixels (normalised display coordinates), None
    where an eye has none: where the sharp region of the frame actually is."""
    out = []
    h, w = regions.shape[1:]
    for eye in regions:
        rows, cols = np.nonzero(eye == 0)
        out.append(
            None if rows.size == 0 else [float((cols.mean() + 0.5) / w), float((rows.mean() + 0.5) / h)]
        )
    return out


def _source_status(source) -> str:
    """One line on a source's connection, for the overlay (a device that is unreachable says so)."""
    from ..devices import ThreadedSource

    st = source.status
    text = f"{st.samples} samples"
    if isinstance(source, ThreadedSource):  # a live device: is it there?
        text = f"{'connected' if st.connected else 'not connected'}, {text}"
    if st.errors:
        text += f", {st.errors} errors (last: {st.last_error})"
    return text


class LiveRenderer:
    """The live state and the frame loop's body; see the module docstring.

    `scene`, `rig`: what to render (or `scene` a `fovjax.FoveatedRenderer` that brings rig,
    foveation and config, which stay None); `foveation`: the starting `Foveation`; `config`: a
    `RenderConfig`; `gaze`: None for the mouse or a gaze source spec; `head`: None for keys or a
    head source spec; `tracker`: the `GazeTracker` for a gaze source (default one)."""

    def __init__(self, scene, rig, foveation, *, config=None, gaze=None, head=None, tracker=None, seed=0):
        from ..devices import GazeTracker, HeadTracker, source_from_spec
        from ..foveate import FoveatedRenderer

        # The scene prepared once (arrays, BVH, budget): a `FoveatedRenderer`, or one made here.
        if isinstance(scene, FoveatedRenderer):
            given = {"rig": rig, "foveation": foveation, "config": config}
            clashing = [name for name, value in given.items() if value is not None]
            if clashing:
                raise ValueError(
                    f"LiveRenderer: the scene is a FoveatedRenderer, which has its own {', '.join(clashing)}"
                )
            self.renderer = scene
        else:
            self.renderer = FoveatedRenderer(scene, rig, foveation, config)
        self.rig = self.renderer.rig
        self.config = self.renderer.config
        self.base_foveation = foveation = self.renderer.foveation
        self.bvh = self.renderer.bvh
        self.key = jax.random.key(seed)
        self.gaze_spec, self.head_spec = gaze, head
        # Sources are built (not opened) here, so a bad spec fails before any rendering.
        self.gaze_source = None if gaze is None else source_from_spec(gaze, "gaze")
        self.head_source = None if head is None else source_from_spec(head, "head")
        self.tracker = (tracker or GazeTracker()) if gaze is not None else None
        self.head_tracker = HeadTracker() if head is not None else None
        self._omega_full = None
        self._lock = threading.Lock()
        self.fovea_deg = float(foveation.fovea_deg)
        self.periphery_deg = float(foveation.periphery_deg)
        self.full = False
        self.debug = False
        self.head_keys = [0.0, 0.0]  # yaw, pitch from the keys (degrees)
        self._mouse = None  # (eye, x, y, t) of the newest mouse event
        self._mouse_seq = 0
        self._mouse_inside = False
        self._used_seq = -1
        self._used_timestamp = math.nan
        self._tracking_state: str | None = None  # the gaze tracker's state at the last frame
        self._last_gaze = np.full((2, 2), 0.5, np.float32)
        self._last_frame_s = 0.0
        self.frames = 0
        self.last: RenderedFrame | None = None

    # ---- inputs (event-loop thread) -----------------------------------------------------------

    def set_mouse(self, eye: str, x: float, y: float, t: float) -> None:
        with self._lock:
            self._mouse = (eye, float(x), float(y), float(t))
            self._mouse_seq += 1
            self._mouse_inside = True

    def mouse_left(self) -> None:
        with self._lock:
            self._mouse_inside = False

    def apply_action(self, action: str) -> str:
        """Apply a key action (not "save", which the server runs on the render thread); returns
        what changed, for the log and the page."""
        from ..foveate import THESIS_PAIRS

        with self._lock:
            if action.startswith("head_"):
                if action == "head_reset":
                    self.head_keys = [0.0, 0.0]
                else:
                    axis, sign = {
                        "head_left": (0, -1.0),
                        "head_right": (0, 1.0),
                        "head_up": (1, 1.0),
                        "head_down": (1, -1.0),
                    }[action]
                    limit = 180.0 if axis == 0 else 85.0
                    value = self.head_keys[axis] + sign * HEAD_STEP_DEG
                    self.head_keys[axis] = float(np.clip(value, -limit, limit))
                return f"head yaw {self.head_keys[0]:+.0f}°, pitch {self.head_keys[1]:+.0f}°"
            if action in ("fovea_up", "fovea_down"):
                step = FOVEA_STEP_DEG if action == "fovea_up" else -FOVEA_STEP_DEG
                self.fovea_deg = float(
                    np.clip(self.fovea_deg + step, FOVEA_STEP_DEG, self.periphery_deg - MIN_GAP_DEG)
                )
            elif action in ("periphery_up", "periphery_down"):
                step = PERIPHERY_STEP_DEG if action == "periphery_up" else -PERIPHERY_STEP_DEG
                self.periphery_deg = float(
                    np.clip(self.periphery_deg + step, self.fovea_deg + MIN_GAP_DEG, MAX_THRESHOLD_DEG)
                )
            elif action.startswith("preset_"):
                self.fovea_deg, self.periphery_deg = (float(v) for v in THESIS_PAIRS[int(action[-1]) - 1])
            elif action == "toggle_full":
                self.full = not self.full
                return "full quality" if self.full else "foveated"
            elif action == "toggle_debug":
                self.debug = not self.debug
                return "regions/samples view" if self.debug else "image view"
            else:
                raise ValueError(f"LiveRenderer.apply_action: unknown action {action!r}")
            # Thresholds fix the static ray budget: a pair not rendered before compiles once.
            return f"fovea {self.fovea_deg:g}°, periphery {self.periphery_deg:g}° (a new pair compiles once)"

    # ---- render thread --------------------------------------------------------------------------

    def open(self) -> None:
        """Open the gaze and head sources (those not open yet); a device error says which."""
        for source in (self.gaze_source, self.head_source):
            if source is not None and not source.is_open:
                source.open()

    def close(self) -> None:
        for source in (self.gaze_source, self.head_source):
            if source is not None:
                source.close()

    def foveation(self, fovea_deg: float, periphery_deg: float):
        return dataclasses.replace(self.base_foveation, fovea_deg=fovea_deg, periphery_deg=periphery_deg)

    def warmup(self) -> float:
        """Compile the starting configuration and the gaze mapping; returns seconds taken."""
        t0 = time.perf_counter()
        # The same argument kinds as every frame's (a key: jittered; a pose), so the frames reuse it.
        fov = self.foveation(self.fovea_deg, self.periphery_deg)
        self._render(self._last_gaze, fov, (0.0, 0.0, 0.0), False, self.key, self.debug)
        if self.gaze_source is None:
            self._binocular("left", (0.5, 0.5), (0.0, 0.0, 0.0))
        return time.perf_counter() - t0

    def _binocular(self, eye, xy, pose):
        from ._gaze import binocular_gaze

        return binocular_gaze(self.bvh, self.rig, pose, eye, xy)

    def _render(self, gaze, foveation, pose, full, key=None, debug=False, reset=False):
        from ..foveate import DEBUG_VIEW_DIAGNOSTICS

        if full:
            if reset:  # full frames keep no history, but the foveated ones after them would
                self.renderer.reset_history()
            return self.renderer.render_full(head_pose=pose, key=key)
        # Only the per-pixel outputs the frame shows: the regions (the fovea's centre), and the
        # debug view's while it is on (its first frame compiles that program, as the first
        # full frame does).
        return self.renderer.render(
            ((0.5, 0.5), (0.5, 0.5)) if gaze is None else gaze,
            head_pose=pose,
            key=key,
            thresholds=(foveation.fovea_deg, foveation.periphery_deg),
            diagnostics=("region", *DEBUG_VIEW_DIAGNOSTICS) if debug else ("region",),
            reset=reset,
        )

    def _tracked_gaze(self, now: float):
        """Gaze, thresholds and tracking state from the gaze source (tracker with fallback)."""
        from ..devices import widen_thresholds
        from ..session import full_eccentricity

        tracker, source = self.tracker, self.gaze_source
        if tracker is None or source is None:
            raise RuntimeError("the viewer has no gaze source to track")
        tf = tracker.step(now, source.drain(), display_time=now + self._last_frame_s)
        fovea, periphery = self.fovea_deg, self.periphery_deg
        if tf.widening > 0 and self.base_foveation.method.widens_fovea:  # see `Weier2016`
            if self._omega_full is None:
                self._omega_full = full_eccentricity(self.rig, self.base_foveation)
            omega_full = max(self._omega_full, periphery)
            fovea, periphery = widen_thresholds(fovea, periphery, tf.widening, omega_full)
        gaze = np.clip(np.array([tf.left, tf.right], np.float32), 0.0, 1.0)
        if not np.isfinite(gaze).all():
            gaze = self._last_gaze
        info = {
            "tracking_state": str(tf.state),
            "widening": float(tf.widening),
            "gaze_age_ms": float(tf.sample_age * 1e3) if math.isfinite(tf.sample_age) else None,
            "rejected_samples": int(sum(tf.rejected.values())),
            "source_status": _source_status(self.gaze_source),
        }
        return gaze, fovea, periphery, info, float(tf.sample_timestamp)

    def render_next(self) -> RenderedFrame:
        """Render one frame for the newest inputs (render thread only)."""
        t_start = time.perf_counter()
        now = time.monotonic()
        with self._lock:
            mouse, mouse_seq, inside = self._mouse, self._mouse_seq, self._mouse_inside
            fovea, periphery = self.fovea_deg, self.periphery_deg
            full, debug = self.full, self.debug
            yaw_keys, pitch_keys = self.head_keys
        head_state = "keys"
        pose = [yaw_keys, pitch_keys, 0.0]
        if self.head_tracker is not None and self.head_source is not None:
            hf = self.head_tracker.step(now, self.head_source.drain())
            pose = [hf.yaw + yaw_keys, hf.pitch + pitch_keys, hf.roll]
            head_state = str(hf.state)
        gaze_t = gaze_timestamp = None
        gaze_new = False
        reset = False
        t0 = time.perf_counter()
        if self.gaze_source is None:
            if mouse is None:
                gaze = self._last_gaze
                info = {"tracking_state": "mouse: not over the frame yet"}
            else:
                eye, x, y, gaze_t = mouse
                # The other eye's gaze depends on the head pose too: recomputed every frame.
                gaze = self._binocular(eye, (x, y), tuple(pose))
                gaze_new = mouse_seq != self._used_seq
                self._used_seq = mouse_seq
                info = {"tracking_state": f"mouse ({eye} eye)" if inside else "mouse left the frame: held"}
        else:
            gaze, fovea, periphery, info, gaze_timestamp = self._tracked_gaze(now)
            # Tracking lost: a temporal method's history is dropped (as run_session does), so
            # the frames after the loss do not reuse samples shaded for a gaze no longer known.
            state = str(info["tracking_state"])
            reset = state == "lost" and self._tracking_state != "lost"
            self._tracking_state = state
            if math.isfinite(gaze_timestamp):
                gaze_new = gaze_timestamp != self._used_timestamp
                self._used_timestamp = gaze_timestamp
            else:
                gaze_timestamp = None
        self._last_gaze = np.asarray(gaze, np.float32)
        gaze_s = time.perf_counter() - t0
        foveation = self.foveation(fovea, periphery)
        frame_key = jax.random.fold_in(self.key, self.frames)
        t0 = time.perf_counter()
        frame = self._render(self._last_gaze, foveation, tuple(pose), full, frame_key, debug, reset)
        call_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        foveated = frame if isinstance(frame, FoveatedFrame) else None
        debug_image = foveated.debug_view if (debug and foveated is not None) else None
        debug_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        jpeg = encode_jpeg(debug_image if debug_image is not None else frame.image)
        encode_s = time.perf_counter() - t0
        s = frame.stats
        stats = {
            "frame": self.frames,
            "size": [self.rig.eye_width, self.rig.eye_height],
            "mode": "full" if full else "foveated",
            "view": "debug" if debug_image is not None else "image",
            "gaze_source": "mouse" if self.gaze_source is None else self.gaze_spec,
            "gaze_left": [float(v) for v in self._last_gaze[0]],
            "gaze_right": [float(v) for v in self._last_gaze[1]],
            "gaze_new": gaze_new,
            "head_source": "keys" if self.head_source is None else self.head_spec,
            "head_state": head_state,
            "history_reset": reset,
            "head_pose": [float(v) for v in pose],
            "fovea_deg": None if full else fovea,
            "periphery_deg": None if full else periphery,
            "spp": s.spp,
            "rays": s.rays,
            "primary_rays": s.primary_rays,
            "shadow_rays": s.shadow_rays,
            "reflection_rays": s.reflection_rays,
            "pixels": 2 * self.rig.eye_width * self.rig.eye_height,
            "ms": {
                "gaze": gaze_s * 1e3,
                "compile": s.compile_seconds * 1e3,
                "render": s.render_seconds * 1e3,
                # render_stereo's host work around the compiled program (transfers, stats).
                "host": max(call_s - s.compile_seconds - s.render_seconds, 0.0) * 1e3,
                "debug": debug_s * 1e3,
                "encode": encode_s * 1e3,
            },
            **info,
        }
        if foveated is not None:
            fs = foveated.foveation
            stats["rays_by_region"] = dict(
                zip(("fovea", "periphery", "outside"), fs.primary_by_region, strict=True)
            )
            stats["budget"] = fs.budget
            stats["dropped_samples"] = fs.dropped
            if foveated.regions is not None:  # the viewer always asks for them
                stats["fovea_centre"] = _fovea_centre(foveated.regions)
        stats["ms"]["frame"] = (time.perf_counter() - t_start) * 1e3
        self._last_frame_s = time.perf_counter() - t_start
        result = RenderedFrame(
            number=self.frames,
            jpeg=jpeg,
            stats=stats,
            image=frame.image,
            debug_image=debug_image,
            gaze_t=gaze_t,
            gaze_timestamp=gaze_timestamp,
            gaze_new=gaze_new,
        )
        self.frames += 1
        self.last = result
        return result

    def save(self, directory, extra: dict | None = None) -> list[Path]:
        """Write the newest frame (PNG), its regions/samples view when shown, and its statistics
        (JSON) to `directory`; returns the paths."""
        from ..files import atomic_path, save_image

        frame = self.last
        if frame is None:
            raise ValueError("nothing rendered yet")
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        stem = directory / f"view_{frame.number:06d}"
        paths = [save_image(stem.with_suffix(".png"), frame.image)]
        if frame.debug_image is not None:
            paths.append(save_image(stem.parent / (stem.name + "_debug.png"), frame.debug_image))
        stats_path = stem.with_suffix(".json")
        with atomic_path(stats_path) as tmp:  # complete or absent, as the images are
            tmp.write_text(json.dumps({**frame.stats, **(extra or {})}, indent=1) + "\n")
        paths.append(stats_path)
        return paths
