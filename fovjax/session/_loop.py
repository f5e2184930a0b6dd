"""Render a sequence of foveated stereo frames driven by gaze and head-pose sources.

Two clocks:

- "virtual": frame k is displayed at t = k / fps on a simulated clock shared with the sources
  (they are re-clocked onto it before they open; recordings and synthetic gaze are paced on it),
  so a session that renders slower than real time still sees the gaze exactly as it was at each
  frame's time, and the same inputs give the same frames.
- "wall": frames are rendered as fast as they can be on the gaze source's clock
  (`time.monotonic` for specs), for live devices; each frame uses whatever samples arrived since
  the previous one. The program is compiled before the first frame (`warmup` renders every
  widening level once), so a
  tracker that goes silent does not freeze the display while a new program compiles.

The default picks "wall" for live devices (serial, Pupil, ViewPoint, InterSense) and "virtual"
for recordings and synthetic gaze.

Per frame: every sample that arrived goes through the `GazeTracker` (quality filter, hold, widen,
recover) and the `HeadTracker`; the tracker's widening turns into the frame's fovea and
periphery thresholds, widened towards the largest eccentricity any pixel of the display can have
(widening 1: every pixel is foveal, full quality); then the session's `FoveatedRenderer`
renders the frame. The thresholds are traced values: every widening level runs on the one
compiled program. Gaze the tracker
accepts slightly off screen (within its `max_offscreen`) is clamped to the screen edge.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import importlib.util
import json
import math
import time
import warnings
from pathlib import Path

import jax
import numpy as np

# Schemes of live devices: their samples arrive in real time, so the default clock is "wall".
LIVE_SCHEMES = ("serial", "pupil", "viewpoint", "intersense")
CLOCKS = ("virtual", "wall")


class VirtualClock:
    """A clock that moves only when told to (seconds)."""

    def __init__(self, start: float = 0.0):
        self.now = float(start)

    def __call__(self) -> float:
        return self.now

    def set(self, t: float) -> None:
        self.now = float(t)


@dataclasses.dataclass(frozen=True)
class SessionFrame:
    """One frame's statistics (also a row of `session.csv`).

    `time_s`: the frame's time on the session clock; `latency_s`: sample-to-frame latency, from
    the timestamp of the gaze sample the frame follows to the frame's display (virtual clock:
    its display time; wall clock: when its rendering finished); `gaze_age_s`: that sample's age
    when the frame started; `gaze_*`: the gaze rendered from (normalised display coordinates
    per eye); `fovea_pixels`: foveal pixels of both eyes; `rejected_samples`: bad samples so far
    (cumulative); `render_s`/`compile_s`: the compiled program's run time and the compile time
    this frame paid (0 when the program was cached).

    The sources' state when the frame started (`head_*` None without a head source):
    `*_connected` (a device's link is up; a recording or synthetic source: open),
    `*_samples` (samples it delivered so far, of any quality), `*_reconnects` (connections
    after the first), `*_errors` (connection and read errors so far) and `*_sample_age_s` (the
    age of its newest sample; inf before the first)."""

    frame: int
    time_s: float
    tracking_state: str
    widening: float
    widening_step: int
    saccade: bool
    gaze_age_s: float
    latency_s: float
    gaze_left: tuple[float, float]
    gaze_right: tuple[float, float]
    head_state: str
    head_pose: tuple[float, float, float]
    fovea_deg: float
    periphery_deg: float
    fovea_pixels: int
    primary_rays: int
    shadow_rays: int
    reflection_rays: int
    dropped: int
    render_s: float
    compile_s: float
    rejected_samples: int
    path: str
    gaze_connected: bool = False
    gaze_samples: int = 0
    gaze_reconnects: int = 0
    gaze_errors: int = 0
    gaze_sample_age_s: float = math.inf
    head_connected: bool | None = None
    head_samples: int | None = None
    head_reconnects: int | None = None
    head_errors: int | None = None
    head_sample_age_s: float | None = None
    # Pixels shown from earlier frames' samples (`Weier2016`) or blended with them (`Patney2016`):
    # a temporal foveation method's reuse.
    reused_pixels: int = 0

    @property
    def rays(self) -> int:
        return self.primary_rays + self.shadow_rays + self.reflection_rays


@dataclasses.dataclass(frozen=True)
class SessionResult:
    """What `run_session` did: per-frame stats, the summary (also in `session.json`), the output
    directory and the video (None when not written)."""

    frames: list[SessionFrame]
    summary: dict
    out: Path | None
    video: Path | None

    def states(self) -> list[str]:
        return [f.tracking_state for f in self.frames]


def _scheme(spec) -> str | None:
    return spec.partition(":")[0] if isinstance(spec, str) else None


def _is_live(spec_or_source) -> bool:
    if spec_or_source is None:
        return False
    if isinstance(spec_or_source, str):
        return _scheme(spec_or_source) in LIVE_SCHEMES
    from ..devices import ThreadedSource

    return isinstance(spec_or_source, ThreadedSource)


def _source(spec_or_source, kind, clock, duration, name, wait=None):
    """A source for `spec_or_source` on `clock`: specs are built on it (a live device given
    `wait` seconds to connect), source objects that are not open yet are re-clocked onto it (an
    open one must already use it)."""
    if spec_or_source is None:
        return None
    if isinstance(spec_or_source, str):
        from ..devices import source_from_spec

        return source_from_spec(spec_or_source, kind, duration=duration, clock=clock, connect_timeout=wait)
    from ..devices import Source

    source = spec_or_source
    if not isinstance(source, Source):
        raise ValueError(
            f"run_session: {name} must be a source spec such as 'replay:FILE' or a fovjax.devices "
            f"source, got {type(source).__name__}"
        )
    if source.kind != kind:
        raise ValueError(f"run_session: {name} is a {source.kind} source, not {kind}")
    if source.is_open:
        if source.clock is not clock:
            raise ValueError(
                f"run_session: {name} source is already open on another clock; pass it unopened "
                "so the session can put it on its clock"
            )
    else:
        source.clock = clock
    return source


def full_eccentricity(rig, foveation) -> float:
    """The largest eccentricity (degrees) any pixel of either eye's display can have for any
    gaze on that display -- the fovea that covers the whole screen -- rounded up to 0.1°.
    Eccentricity is measured in the eye's own camera, so the head pose does not matter."""
    from ..foveate.internal import full_eccentricity as largest

    return largest(rig, foveation)


def _check_count(frames, seconds, fps) -> int:
    if frames is None and seconds is None:
        raise ValueError("SessionConfig: give frames= or seconds=")
    if frames is not None and seconds is not None:
        raise ValueError(f"SessionConfig: give frames= or seconds=, not both (got {frames}, {seconds})")
    try:
        rate = float(fps)
    except (TypeError, ValueError):
        rate = math.nan
    if isinstance(fps, bool) or not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"SessionConfig: fps must be a positive number, got {fps!r}")
    if frames is not None:
        if isinstance(frames, bool) or not isinstance(frames, int | np.integer):
            raise ValueError(f"SessionConfig: frames must be an integer, got {frames!r}")
        n = int(frames)
    else:
        if isinstance(seconds, bool) or not (isinstance(seconds, int | float) and math.isfinite(seconds)):
            raise ValueError(f"SessionConfig: seconds must be a finite number, got {seconds!r}")
        n = int(round(seconds * rate))
    if n < 1:
        raise ValueError(
            f"SessionConfig: need at least one frame, got frames={frames}, seconds={seconds}, fps={fps}"
        )
    return n


@dataclasses.dataclass(frozen=True)
class SessionConfig:
    """How long a session runs and on which clock (`run_session(session=...)`).

    Args:
        frames: how many frames; or `seconds` × `fps` (give one of the two).
        seconds: the session's length in seconds (instead of `frames`).
        fps: frames per second of the session's clock.
        clock: "virtual" (frame k at k/fps, sources paced on the same clock: deterministic),
            "wall", or None (wall for live devices, else virtual).
        fresh_key_per_frame: a new sampling pattern every frame (the key folded with the frame
            number); False renders every frame with the session's key.
        warmup: compile every widening level before the first frame (None: on the wall clock
            only).
        wait: seconds a live device may take to connect (None:
            `fovjax.devices.DEFAULT_CONNECT_TIMEOUT`).

    Raises:
        ValueError: neither or both of `frames` and `seconds`, fewer than one frame, a bad `fps`,
            `clock` or `wait` (naming the value).
    """

    frames: int | None = None
    seconds: float | None = None
    fps: float = 30.0
    clock: str | None = None
    fresh_key_per_frame: bool = True
    warmup: bool | None = None
    wait: float | None = None

    def __post_init__(self):
        _check_count(self.frames, self.seconds, self.fps)
        if self.clock is not None and self.clock not in CLOCKS:
            raise ValueError(f"SessionConfig: clock must be one of {CLOCKS} or None, got {self.clock!r}")
        if self.wait is not None and (
            isinstance(self.wait, bool)
            or not isinstance(self.wait, int | float)
            or not (math.isfinite(self.wait) and self.wait >= 0)
        ):
            raise ValueError(
                f"SessionConfig: wait must be a finite number of seconds >= 0, got {self.wait!r}"
            )

    @property
    def n_frames(self) -> int:
        """The number of frames the session renders."""
        return _check_count(self.frames, self.seconds, self.fps)


@dataclasses.dataclass(frozen=True)
class SessionOutput:
    """What a session writes (`run_session(out=...)`; a plain path is `SessionOutput(path)`).

    Args:
        directory: the directory for `frame_00000.png`..., `session.csv` (one row per frame) and
            `session.json` (``{"summary": ..., "frames": [...]}``).
        video: also write `session.mp4` (the `video` extra).
        debug: also write the regions and samples view, `debug_00000.png`...
    """

    directory: str | Path
    video: bool = False
    debug: bool = False

    def __post_init__(self):
        if not isinstance(self.directory, str | Path):
            raise ValueError(
                f"SessionOutput: directory must be a path (str or pathlib.Path), got {self.directory!r}"
            )
        for name in ("video", "debug"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"SessionOutput: {name} must be True or False, got {getattr(self, name)!r}")


# The keywords `run_session` took before `SessionConfig`, `SessionOutput` and `FoveatedRenderer`,
# still accepted (with a DeprecationWarning) because the tutorials showed them.
_OLD_SESSION = ("frames", "seconds", "fps", "clock", "fresh_key_per_frame", "warmup", "wait")
_OLD_OUTPUT = ("video", "debug")
_OLD_RENDERER = ("foveation", "config", "envmap", "bvh")


def _upgrade_old_keywords(old: dict, session, out, tracker):
    """`session`, `out`, `tracker` and the renderer's arguments from the old keywords in `old`,
    each use warned of with its replacement; an unknown keyword is a TypeError as Python's own."""
    unknown = sorted(set(old) - {*_OLD_SESSION, *_OLD_OUTPUT, *_OLD_RENDERER, "policy"})
    if unknown:
        raise TypeError(f"run_session() got an unexpected keyword argument {unknown[0]!r}")
    if not old:
        return session, out, tracker, {}

    def moved(names, where):
        warnings.warn(
            f"run_session({', '.join(f'{n}=' for n in names)}) is deprecated; pass {where}",
            DeprecationWarning,
            stacklevel=4,
        )

    given = [n for n in _OLD_SESSION if n in old]
    if given:
        if session is not None:
            raise ValueError(f"run_session: give session= or the old {', '.join(given)}=, not both")
        moved(given, "session=fovjax.session.SessionConfig(...)")
        session = SessionConfig(**{n: old[n] for n in given})
    given = [n for n in _OLD_OUTPUT if n in old]
    if given:
        if any(old[n] for n in given):
            if out is None:
                raise ValueError("run_session: video=True and debug=True write files; give out=")
            if isinstance(out, SessionOutput):
                raise ValueError(f"run_session: give out=SessionOutput(...) or the old {', '.join(given)}=")
            out = SessionOutput(out, **{n: old[n] for n in given})
        moved(given, "out=fovjax.session.SessionOutput(directory, video=..., debug=...)")
    if "policy" in old:
        if tracker is not None:
            raise ValueError("run_session: give policy= or tracker=, not both (the tracker has its policy)")
        from ..devices import GazeTracker

        moved(["policy"], "tracker=fovjax.devices.GazeTracker(policy=...)")
        tracker = GazeTracker(policy=old["policy"])
    renderer = {n: old[n] for n in _OLD_RENDERER if n in old}
    if renderer:
        moved(list(renderer), "a fovjax.FoveatedRenderer(scene, rig, foveation, config, envmap=, bvh=)")
    return session, out, tracker, renderer


def _describe(spec_or_source) -> str | None:
    if spec_or_source is None or isinstance(spec_or_source, str):
        return spec_or_source
    return type(spec_or_source).__name__


def run_session(
    renderer,
    rig=None,
    *,
    gaze,
    head=None,
    session: SessionConfig | None = None,
    out: SessionOutput | str | Path | None = None,
    tracker=None,
    key: jax.Array | None = None,
    progress: bool = True,
    **old,
) -> SessionResult:
    """Render a session: foveated stereo frames following a gaze source (and a head source).

    Sources are opened before anything is compiled. Each frame feeds the samples that arrived to
    the `GazeTracker`; while the gaze is stale the fovea is held, then widened towards full quality,
    and narrowed again when good samples return. Every widening level runs on one compiled
    program. Ctrl-C ends the session early; the frames so far are kept and logged
    (``summary["interrupted"]``); every file written is complete.

    Args:
        renderer: the `fovjax.FoveatedRenderer` (scene, rig, foveation when tracking is good,
            render config), or a `Scene` to render with `FoveatedRenderer(scene, rig)`.
        rig: with a `Scene`, its `StereoRig` (default: the scene's default camera at the rig's
            default size); None with a renderer (it has its rig).
        gaze: a spec ("synthetic:scanpath:0", "replay:FILE", "serial:PORT", "pupil:HOST:PORT",
            ...) or an unopened `fovjax.devices` source.
        head: a head-pose source or spec, or None (head still).
        session: the `SessionConfig`: frames (or seconds), fps, clock, warm-up, connect wait.
        out: where to write the frames and the log: a `SessionOutput` (with the video and the
            debug views), a directory (`SessionOutput(directory)`), or None (nothing written).
        tracker: the `fovjax.devices.GazeTracker` (default `GazeTracker()`; its `policy` sets
            the fallback). Its `geometry`, when None, is set to the renderer's rig's; a tracker
            whose policy maps one eye's gaze through another rig is refused.
        key: the PRNG key (default key 0), folded with the frame number unless
            `session.fresh_key_per_frame` is False.
        progress: print progress.
        **old: the keywords of the earlier signature (`frames`, `fps`, `out`'s `video`/`debug`,
            `policy`, `foveation`, `config`, ...): accepted with a `DeprecationWarning` naming
            the replacement.

    Returns:
        A `SessionResult`: the frames' `SessionFrame` rows (tracking state, widening, latency,
        gaze, thresholds, rays, times, each source's state) and the summary
        (``summary["sources"]``, ``summary["warnings"]`` when a source never delivered a sample).

    Raises:
        DeviceError: a live device did not connect within `session.wait` seconds (naming the
            spec, the device and the reason).
        ValueError: a bad spec or argument.
        TypeError: `session` is not a `SessionConfig`, `renderer` neither a renderer nor a scene.

    Example:
        ```python
        renderer = fovjax.FoveatedRenderer(scene, rig, Foveation(fovea_deg=5, periphery_deg=10))
        result = fovjax.run_session(renderer, gaze="replay:data/recordings/synthetic_scanpath_seed0.jsonl",
                                    session=fovjax.SessionConfig(frames=30, fps=30), out="out/session")
        print(result.summary["tracking_states"])
        ```
    """
    from ..devices import DEFAULT_CONNECT_TIMEOUT, GazeTracker, HeadTracker, RigGeometry, widen_thresholds
    from ..files import deferred_interrupt, interrupt_flag
    from ..foveate import DEBUG_VIEW_DIAGNOSTICS, FoveatedRenderer
    from ..scene import Scene

    session, out, tracker, renderer_args = _upgrade_old_keywords(old, session, out, tracker)
    if session is None:
        raise ValueError("run_session: give session=SessionConfig(frames=...) (or seconds=...)")
    if not isinstance(session, SessionConfig):
        raise TypeError(f"run_session: session must be a SessionConfig, got {type(session).__name__}")
    if tracker is not None and not isinstance(tracker, GazeTracker):
        raise TypeError(
            f"run_session: tracker must be a fovjax.devices.GazeTracker, got {type(tracker).__name__}"
        )
    if out is not None and not isinstance(out, SessionOutput):
        out = SessionOutput(out)
    n_frames = session.n_frames
    rate = float(session.fps)
    if gaze is None:
        raise ValueError("run_session: gaze must be a source spec or a fovjax.devices source, got None")
    clock = session.clock
    if clock is None:
        clock = "wall" if (_is_live(gaze) or _is_live(head)) else "virtual"
    video, debug = (out.video, out.debug) if out is not None else (False, False)
    if video and importlib.util.find_spec("imageio_ffmpeg") is None:
        raise ImportError(
            "run_session: SessionOutput(video=True) needs imageio-ffmpeg: pip install 'fovjax[video]'"
        )
    tracker = tracker or GazeTracker()
    head_tracker = HeadTracker()
    # Only the per-pixel outputs the loop reads (the regions: `fovea_pixels`; the debug view's
    # with `debug`), fixed for the session: one compiled program.
    diagnostics = ("region", *DEBUG_VIEW_DIAGNOSTICS) if debug else ("region",)
    # The scene prepared once (arrays, BVH, budget, levels of detail), not per frame.
    if isinstance(renderer, FoveatedRenderer):
        clashing = [name for name, value in {"rig": rig, **renderer_args}.items() if value is not None]
        if clashing:
            raise ValueError(
                f"run_session: the renderer has its own {', '.join(clashing)}; pass them when making it"
            )
        renderer = renderer.with_foveation(renderer.foveation, diagnostics=diagnostics)
    elif isinstance(renderer, Scene):
        foveation, config = renderer_args.pop("foveation", None), renderer_args.pop("config", None)
        renderer = FoveatedRenderer(
            renderer, rig, foveation, config, diagnostics=diagnostics, **renderer_args
        )
    else:
        raise TypeError(
            "run_session: renderer must be a fovjax.FoveatedRenderer or a fovjax.Scene, "
            f"got {type(renderer).__name__}"
        )
    rig, foveation = renderer.rig, renderer.foveation
    # The tracker's rig: its one-eye fallback "map" goes through the rig the frames show.
    geometry = RigGeometry.from_rig(rig)
    if tracker.geometry is None:
        tracker.geometry = geometry
    elif tracker.policy.single_eye == "map" and not tracker.geometry.matches(geometry):
        raise ValueError(
            f"run_session: the tracker maps one eye's gaze through {tracker.geometry}, "
            f"not the renderer's rig {geometry}; give GazeTracker(geometry=None) to use the renderer's"
        )
    omega_full = float(max(full_eccentricity(rig, foveation), foveation.periphery_deg))

    vclock = VirtualClock() if clock == "virtual" else None
    # Wall clock: a source object keeps its own clock and the session runs on it.
    now = vclock if vclock is not None else (time.monotonic if isinstance(gaze, str) else gaze.clock)
    # Synthetic sources end after `duration`; on the wall clock rendering may be slower than the
    # timeline, so there they never end.
    duration = n_frames / rate + 1.0 if vclock is not None else None
    wait = DEFAULT_CONNECT_TIMEOUT if session.wait is None else session.wait
    gaze_source = _source(gaze, "gaze", now, duration, "gaze", wait)
    if gaze_source is None:  # not reached: gaze was checked above
        raise ValueError("run_session: gaze must be a source spec or a fovjax.devices source, got None")
    head_source = _source(head, "head", now, duration, "head", wait)
    key = jax.random.key(0) if key is None else key
    out = Path(out.directory) if out is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    video_path = out / "session.mp4" if (out is not None and video) else None

    def thresholds_at(widening: float) -> tuple[float, float]:
        fovea, periphery = float(foveation.fovea_deg), float(foveation.periphery_deg)
        if not foveation.method.widens_fovea:  # its history covers the widening (`Weier2016`)
            return fovea, periphery
        return widen_thresholds(fovea, periphery, widening, omega_full)

    warmup = clock == "wall" if session.warmup is None else session.warmup
    warmup_s = 0.0
    rows: list[SessionFrame] = []
    last_sample = {"gaze": -math.inf, "head": -math.inf}
    writer = None
    bar = None
    interrupted = False
    started = time.perf_counter()
    # Ctrl-C sets `stop` (checked every frame) as well as raising KeyboardInterrupt.
    interrupt = interrupt_flag()
    stop = interrupt.__enter__()
    try:
        # Open before compiling: a device that cannot connect says so at once.
        gaze_source.open()
        if head_source is not None:
            head_source.open()
        if warmup:
            t0 = time.perf_counter()
            steps = tracker.policy.widen_steps
            for step in range(steps + 1):
                if stop.is_set():
                    raise KeyboardInterrupt
                renderer.render(head_pose=(0.0, 0.0, 0.0), key=key, thresholds=thresholds_at(step / steps))
            warmup_s = time.perf_counter() - t0
        # A temporal method (`Foveation.method`) keeps the session's frames' history only.
        renderer.reset_history()
        previous_state = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=n_frames, unit="frame", desc="session")
        if video_path is not None:
            import imageio.v2 as iio

            with _forking_ffmpeg():
                writer = iio.get_writer(
                    video_path, format="FFMPEG", fps=rate, codec="libx264", macro_block_size=1
                )
        last_frame_s = 0.0
        for k in range(n_frames):
            if stop.is_set():
                raise KeyboardInterrupt
            if vclock is not None:
                vclock.set(k / rate)  # not a running sum: no drift over long sessions
            t = now()
            # Wall clock: the frame is shown about one frame's rendering time from now.
            display_time = t if vclock is not None else t + last_frame_s
            gaze_samples = gaze_source.drain()
            head_samples = head_source.drain() if head_source is not None else []
            for role, got in (("gaze", gaze_samples), ("head", head_samples)):
                if got:
                    last_sample[role] = max(last_sample[role], got[-1].timestamp)
            states = _source_states(gaze_source, head_source, last_sample, t)
            tf = tracker.step(t, gaze_samples, display_time=display_time)
            hf = head_tracker.step(t, head_samples) if head_source is not None else None
            pose = (hf.yaw, hf.pitch, hf.roll) if hf is not None else (0.0, 0.0, 0.0)
            thresholds = thresholds_at(tf.widening)
            gaze_xy = np.clip(np.array([tf.left, tf.right], np.float32), 0.0, 1.0)
            frame_key = jax.random.fold_in(key, k) if session.fresh_key_per_frame else key
            # Tracking lost: a temporal method's history is dropped (the frame starts from none).
            lost = str(tf.state) == "lost" and previous_state != "lost"
            previous_state = str(tf.state)
            frame = renderer.render(gaze_xy, head_pose=pose, key=frame_key, thresholds=thresholds, reset=lost)
            shown = now() if vclock is None else display_time
            last_frame_s = max(shown - t, 0.0)
            with deferred_interrupt():  # a frame's files and its row: whole or not at all
                path = ""
                if out is not None:
                    path = str(frame.save(out / f"frame_{k:05d}.png"))
                    if debug:
                        from ..files import save_image

                        save_image(out / f"debug_{k:05d}.png", frame.debug_view)
                    if writer is not None:
                        with _forking_ffmpeg():
                            writer.append_data(_video_frame(frame.image))
                rows.append(
                    SessionFrame(
                        frame=k,
                        time_s=float(t),
                        tracking_state=str(tf.state),
                        widening=float(tf.widening),
                        widening_step=int(tf.widening_step),
                        saccade=bool(tf.saccade),
                        gaze_age_s=float(tf.sample_age),
                        latency_s=float(shown - tf.sample_timestamp)
                        if math.isfinite(tf.sample_timestamp)
                        else math.inf,
                        gaze_left=(float(gaze_xy[0][0]), float(gaze_xy[0][1])),
                        gaze_right=(float(gaze_xy[1][0]), float(gaze_xy[1][1])),
                        head_state=str(hf.state) if hf is not None else "none",
                        head_pose=(float(pose[0]), float(pose[1]), float(pose[2])),
                        fovea_deg=float(frame.foveation.fovea_deg),
                        periphery_deg=float(frame.foveation.periphery_deg),
                        fovea_pixels=int(np.count_nonzero(frame.regions == 0)),
                        primary_rays=frame.stats.primary_rays,
                        shadow_rays=frame.stats.shadow_rays,
                        reflection_rays=frame.stats.reflection_rays,
                        dropped=frame.foveation.dropped,
                        render_s=frame.stats.render_seconds,
                        compile_s=frame.stats.compile_seconds,
                        rejected_samples=int(sum(tf.rejected.values())),
                        path=path,
                        **states,
                        reused_pixels=frame.foveation.reused,
                    )
                )
            if bar is not None:
                bar.set_postfix_str(
                    f"{tf.state} {thresholds[0]:.0f}°/{thresholds[1]:.0f}° {frame.stats.rays / 1e6:.2f} Mrays"
                )
                bar.update(1)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        interrupt.__exit__(None, None, None)
        interrupted = interrupted or stop.is_set()
        gaze_source.close()
        if head_source is not None:
            head_source.close()
        if writer is not None:
            with _forking_ffmpeg():
                writer.close()
        if bar is not None:
            bar.close()
    summary = _summary(
        rows,
        n_frames=n_frames,
        fps=rate,
        clock=clock,
        gaze=_describe(gaze),
        head=_describe(head),
        rig=rig,
        foveation=foveation,
        omega_full=omega_full,
        policy=tracker.policy,
        warmup_s=warmup_s,
        wall_s=time.perf_counter() - started,
        interrupted=interrupted,
    )
    summary["sources"], summary["warnings"] = _source_report(
        {"gaze": gaze_source, "head": head_source}, last_sample, now(), rows, interrupted
    )
    if out is not None:
        with deferred_interrupt():
            _write_log(out, rows, summary)
    return SessionResult(
        frames=rows,
        summary=summary,
        out=out,
        video=video_path,
    )


def _source_states(gaze_source, head_source, last_sample: dict, t: float) -> dict:
    """The `SessionFrame` fields describing the sources at time `t`."""
    from ..devices import ThreadedSource

    states = {}
    for role, source in (("gaze", gaze_source), ("head", head_source)):
        if source is None:
            continue
        st = source.status
        live = isinstance(source, ThreadedSource)
        states[f"{role}_connected"] = bool(st.connected) if live else source.is_open
        states[f"{role}_samples"] = int(st.samples)
        states[f"{role}_reconnects"] = max(int(st.connects) - 1, 0)
        states[f"{role}_errors"] = int(st.errors)
        states[f"{role}_sample_age_s"] = float(t - last_sample[role])
    return states


def _source_report(sources: dict, last_sample: dict, t: float, rows, interrupted: bool):
    """Each source's final state for the summary, and a warning per source that never
    delivered a sample over a session that rendered frames."""
    report, warnings_ = {}, []
    for role, source in sources.items():
        if source is None:
            continue
        st = source.status
        age = t - last_sample[role]
        report[role] = {
            "spec": source.spec if source.spec is not None else type(source).__name__,
            "device": source.describe(),
            "connected": bool(st.connected),
            "samples": int(st.samples),
            "reconnects": max(int(st.connects) - 1, 0),
            "errors": int(st.errors),
            "last_error": st.last_error,
            "last_sample_age_s": float(age) if math.isfinite(age) else None,
        }
        if rows and st.samples == 0:
            fallback = "every frame used the fallback (the fovea widened)"
            why = f"; last error: {st.last_error}" if st.last_error else ""
            warnings_.append(
                f"the {role} source {report[role]['spec']} ({report[role]['device']}) never delivered "
                f"a sample in {len(rows)} frame(s){' (interrupted)' if interrupted else ''}, "
                f"connected {st.connects} time(s), {st.errors} error(s){why}; "
                + (fallback if role == "gaze" else "the head stayed still")
            )
    return report, warnings_


@contextlib.contextmanager
def _forking_ffmpeg():
    """imageio-ffmpeg runs ffmpeg as a subprocess (fork then exec at once), which JAX's warning
    about forking a multithreaded process does not apply to."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
        yield


def _video_frame(image: np.ndarray) -> np.ndarray:
    """8-bit sRGB as the PNGs, padded to even sides (H.264 in yuv420p needs them)."""
    from ..files import linear_to_srgb, tonemap

    rgb8 = np.round(linear_to_srgb(tonemap(image)) * 255).astype(np.uint8)
    h, w = rgb8.shape[:2]
    return np.pad(rgb8, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def _summary(rows: list[SessionFrame], **info) -> dict:
    rig, foveation, policy = info.pop("rig"), info.pop("foveation"), info.pop("policy")
    n = len(rows)
    states = [r.tracking_state for r in rows]
    latencies = [r.latency_s for r in rows if r.tracking_state == "ok" and math.isfinite(r.latency_s)]
    return {
        "frames": n,
        "frames_requested": info.pop("n_frames"),
        **info,
        "eye_size": [rig.eye_width, rig.eye_height],
        "fovea_deg": foveation.fovea_deg,
        "periphery_deg": foveation.periphery_deg,
        "spp": foveation.spp,
        "policy": dataclasses.asdict(policy),
        "tracking_states": {s: states.count(s) for s in dict.fromkeys(states)},
        "ok_latency_s_mean": float(np.mean(latencies)) if latencies else None,
        "ok_latency_s_max": float(np.max(latencies)) if latencies else None,
        "rays_total": sum(r.rays for r in rows),
        "rays_per_frame_mean": sum(r.rays for r in rows) / n if n else None,
        "render_s_mean": float(np.mean([r.render_s for r in rows])) if n else None,
        "compile_s_total": sum(r.compile_s for r in rows),
        "dropped_samples_total": sum(r.dropped for r in rows),
        "rejected_samples": rows[-1].rejected_samples if n else 0,
    }


def _jsonable(value):
    """Non-finite floats become null (JSON has no inf/NaN); tuples lists."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    return value


def _write_log(out: Path, rows: list[SessionFrame], summary: dict) -> None:
    from ..files import atomic_path

    fields = [f.name for f in dataclasses.fields(SessionFrame)]
    with atomic_path(out / "session.csv") as tmp, open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields)
        w.writeheader()
        for r in rows:
            w.writerow(
                {k: (json.dumps(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(r).items()}
            )
    with atomic_path(out / "session.json") as tmp, open(tmp, "w") as fh:
        json.dump(
            _jsonable({"summary": summary, "frames": [dataclasses.asdict(r) for r in rows]}),
            fh,
            indent=1,
            allow_nan=False,
        )
