"""The headset's renderer (`fovjax view --xr`): one foveated stereo frame for the newest headset
pose, with the rig built from that pose's views (`xr_stereo`).

The live state (thresholds, full and regions modes, the gaze source and its tracker, saving) is
the 2D viewer's `LiveRenderer`'s; what differs is where the rig and the gaze come from. The rig is
made per frame from the newest `XRPose` the page sent: its shape (eye size, field of view,
principal points) fixes the compiled program, so a `FoveatedRenderer` is prepared once per shape
(a headset's views keep one shape for the session; the first frame of a shape compiles) and
moved to each frame's pose (`with_rig`: traced values, nothing compiles). The gaze: a gaze
source's, in the headset display's coordinates, mapped into each rendered eye; with none, each
eye's straight-ahead point (fixed foveation, the lens centre of a headset).
"""

from __future__ import annotations

import math
import time

import jax
import numpy as np

from ..foveate import FoveatedFrame
from ._renderer import LiveRenderer, RenderedFrame, _fovea_centre, encode_jpeg
from ._xr_geometry import XRPose, XRStereo, head_angles, xr_stereo

FIXED_GAZE = "view centre (fixed foveation)"
# The rig the scene is prepared with before any headset pose (its arrays and BVH are shared by
# every headset rig; it is never rendered).
PREPARE_EYE_PIXELS = 16


class XRRenderer(LiveRenderer):
    """The live state of `LiveRenderer` rendering for a headset's poses (see the module docstring).

    Args:
        scene: a `fovjax.Scene`.
        foveation: the starting `Foveation`.
        origin: the scene viewpoint the headset's `local` space starts at (default: the scene's
            default camera).
        scale: rendered pixels per headset pixel along each side (1: the headset's resolution).
        config: a `RenderConfig`.
        gaze: None for fixed foveation at each eye's view centre, or a gaze source spec (its gaze
            in the headset display's normalised coordinates).
        tracker: the `GazeTracker` for a gaze source (default one).
        seed: the PRNG seed of the sampling.
    """

    def __init__(
        self, scene, foveation, *, origin=None, scale=1.0, config=None, gaze=None, tracker=None, seed=0
    ):
        from ..render import StereoRig
        from ..scene import default_camera

        if not (isinstance(scale, int | float) and math.isfinite(scale) and scale > 0):
            raise ValueError(f"XRRenderer: scale must be a positive number, got {scale!r}")
        self.origin = default_camera(scene) if origin is None else origin
        prepare = StereoRig.from_pose(
            self.origin, eye_width=PREPARE_EYE_PIXELS, eye_height=PREPARE_EYE_PIXELS
        )
        super().__init__(scene, prepare, foveation, config=config, gaze=gaze, tracker=tracker, seed=seed)
        self.scene = scene
        self.scale = float(scale)
        self._prepared = {}  # rig shape -> FoveatedRenderer
        self._pose: XRPose | None = None
        self._in_session = False
        self.stereo: XRStereo | None = None

    @property
    def gaze_description(self) -> str:
        return FIXED_GAZE if self.gaze_source is None else f"gaze source {self.gaze_spec}"

    # ---- inputs (event-loop thread) -----------------------------------------------------------

    def set_pose(self, pose: XRPose) -> bool:
        """Take the newest headset pose; returns whether its views have a shape not rendered yet
        (its first frame compiles)."""
        if not isinstance(pose, XRPose):
            raise TypeError(f"XRRenderer.set_pose: expected an XRPose, got {type(pose).__name__}")
        shape = xr_stereo(pose, self.origin, self.scale).shape
        with self._lock:
            self._pose = pose
            self._in_session = True
        return shape not in self._prepared

    def end_session(self) -> None:
        """The session ended (or its page left): nothing to render until the next pose (a frame
        being rendered now still renders the last one)."""
        with self._lock:
            self._in_session = False

    @property
    def in_session(self) -> bool:
        """Whether a headset pose came since the last `end_session`."""
        with self._lock:
            return self._in_session

    # ---- render thread --------------------------------------------------------------------------

    def warmup(self) -> float:
        """Nothing to compile before a headset's views are known (their shape makes the
        program): returns 0."""
        return 0.0

    def _renderer_for(self, stereo: XRStereo):
        from ..foveate import FoveatedRenderer

        prepared = self._prepared.get(stereo.shape)
        if prepared is None:
            prepared = self._prepared[stereo.shape] = FoveatedRenderer(
                self.scene, stereo.rig, self.base_foveation, self.config, bvh=self.bvh
            )
            self._omega_full = None  # the widest fovea depends on the rig's field of view
        return prepared.with_rig(stereo.rig)

    def render_next(self) -> RenderedFrame:
        """Render one frame for the newest headset pose (render thread only)."""
        t_start = time.perf_counter()
        now = time.monotonic()
        with self._lock:
            pose = self._pose
            fovea, periphery = self.fovea_deg, self.periphery_deg
            full, debug = self.full, self.debug
        if pose is None:
            raise RuntimeError("no headset pose yet: enter VR on the page")
        t0 = time.perf_counter()
        stereo = xr_stereo(pose, self.origin, self.scale)
        self.renderer = self._renderer_for(stereo)
        self.rig, self.stereo = stereo.rig, stereo
        rig_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        gaze_timestamp = None
        gaze_new = False
        reset = False
        if self.gaze_source is None:
            gaze = stereo.straight_ahead()
            info = {"tracking_state": FIXED_GAZE}
        else:
            display_gaze, fovea, periphery, info, gaze_timestamp = self._tracked_gaze(now)
            gaze = stereo.display_to_image(display_gaze)
            state = str(info["tracking_state"])
            reset = state == "lost" and self._tracking_state != "lost"
            self._tracking_state = state
            if math.isfinite(gaze_timestamp):
                gaze_new = gaze_timestamp != self._used_timestamp
                self._used_timestamp = gaze_timestamp
            else:
                gaze_timestamp = None
        self._last_gaze = np.clip(np.asarray(gaze, np.float32), 0.0, 1.0)
        gaze_s = time.perf_counter() - t0
        frame_key = jax.random.fold_in(self.key, self.frames)
        t0 = time.perf_counter()
        # The headset's orientation is in the rig: head pose zero.
        frame = self._render(
            self._last_gaze, self.foveation(fovea, periphery), (0.0, 0.0, 0.0), full, frame_key, debug, reset
        )
        call_s = time.perf_counter() - t0
        foveated = frame if isinstance(frame, FoveatedFrame) else None
        debug_image = foveated.debug_view if (debug and foveated is not None) else None
        t0 = time.perf_counter()
        jpeg = encode_jpeg(debug_image if debug_image is not None else frame.image)
        encode_s = time.perf_counter() - t0
        s = frame.stats
        stats = {
            "frame": self.frames,
            "size": [stereo.rig.eye_width, stereo.rig.eye_height],
            "mode": "full" if full else "foveated",
            "view": "debug" if debug_image is not None else "image",
            "gaze_source": self.gaze_description,
            "gaze_left": [float(v) for v in self._last_gaze[0]],
            "gaze_right": [float(v) for v in self._last_gaze[1]],
            "gaze_new": gaze_new,
            "head_source": "headset (WebXR)",
            "head_state": "tracked",
            "history_reset": reset,
            "head_pose": [float(v) for v in head_angles(pose.rotation())],
            "head_position": [float(v) for v in pose.position],
            "fovea_deg": None if full else fovea,
            "periphery_deg": None if full else periphery,
            "spp": s.spp,
            "rays": s.rays,
            "primary_rays": s.primary_rays,
            "shadow_rays": s.shadow_rays,
            "reflection_rays": s.reflection_rays,
            "pixels": 2 * stereo.rig.eye_width * stereo.rig.eye_height,
            "xr": stereo.page_json(),
            "ms": {
                "rig": rig_s * 1e3,
                "gaze": gaze_s * 1e3,
                "compile": s.compile_seconds * 1e3,
                "render": s.render_seconds * 1e3,
                "host": max(call_s - s.compile_seconds - s.render_seconds, 0.0) * 1e3,
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
            if foveated.regions is not None:
                stats["fovea_centre"] = _fovea_centre(foveated.regions)
        stats["ms"]["frame"] = (time.perf_counter() - t_start) * 1e3
        self._last_frame_s = time.perf_counter() - t_start
        result = RenderedFrame(
            number=self.frames,
            jpeg=jpeg,
            stats=stats,
            image=frame.image,
            debug_image=debug_image,
            gaze_t=None,
            gaze_timestamp=gaze_timestamp,
            gaze_new=gaze_new,
        )
        self.frames += 1
        self.last = result
        return result
