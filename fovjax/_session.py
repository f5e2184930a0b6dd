"""Render a sequence of foveated stereo frames driven by gaze and head-pose sources.

Two clocks:

- "virtual" (default): frame k is displayed at t = k / fps on a simulated clock shared with the
  sources (specs are built on it; recordings and synthetic gaze are paced on it), so a session
  that renders slower than real time still sees the gaze exactly as it was at each frame's
  time, and the same inputs give the same frames.
- "wall": frames are rendered as fast as they can be on `time.monotonic`, for live devices; each
  frame uses whatever samples arrived since the previous one.

Per frame: every sample that arrived goes through the `GazeTracker` (quality filter, hold, widen,
recover) and the `HeadTracker`; the tracker's widening turns into the frame's fovea and
periphery thresholds (widening 1 renders everything at full quality); then `render_foveated`.
Gaze the tracker accepts slightly off screen (within its `max_offscreen`) is clamped to the
screen edge.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import time
from pathlib import Path

import jax
import numpy as np

# Eccentricity that covers any display (the thresholds widen towards it; at 180° every pixel is
# foveal).
FULL_DEG = 180.0


class VirtualClock:
    """A clock that moves only when told to (seconds)."""

    def __init__(self, start: float = 0.0):
        self.now = float(start)

    def __call__(self) -> float:
        return self.now

    def advance(self, dt: float) -> None:
        self.now += float(dt)


@dataclasses.dataclass(frozen=True)
class SessionFrame:
    """One frame's statistics (also a row of `session.csv`)."""

    frame: int
    time_s: float
    tracking_state: str
    widening: float
    gaze_age_s: float
    gaze_left: tuple[float, float]
    gaze_right: tuple[float, float]
    head_state: str
    head_pose: tuple[float, float, float]
    fovea_deg: float
    periphery_deg: float
    primary_rays: int
    shadow_rays: int
    reflection_rays: int
    dropped: int
    render_s: float
    compile_s: float
    rejected_samples: int
    path: str


@dataclasses.dataclass(frozen=True)
class SessionResult:
    frames: list[SessionFrame]
    out: Path | None
    video: Path | None

    def states(self) -> list[str]:
        return [f.tracking_state for f in self.frames]


def _source(spec_or_source, kind, clock, duration):
    if spec_or_source is None:
        return None
    if isinstance(spec_or_source, str):
        from .devices import source_from_spec

        return source_from_spec(spec_or_source, kind, duration=duration, clock=clock)
    return spec_or_source


def run_session(
    scene,
    rig=None,
    *,
    gaze,
    head=None,
    foveation=None,
    frames: int | None = None,
    seconds: float | None = None,
    fps: float = 30.0,
    out=None,
    key: jax.Array | None = None,
    fresh_key_per_frame: bool = True,
    clock: str = "virtual",
    policy=None,
    config=None,
    video: bool = False,
    progress: bool = True,
    bvh=None,
) -> SessionResult:
    """Render `frames` (or `seconds` × `fps`) foveated stereo frames of `scene` following the
    `gaze` source (a `fovjax.devices` source or a spec such as "synthetic:scanpath:0",
    "replay:FILE", "serial:PORT", "pupil:HOST:PORT") and optionally a `head` source. Writes
    `out/frame_00000.png`..., `out/session.csv` and `out/session.json` when `out` is given, and
    `out/session.mp4` with `video=True` (needs imageio-ffmpeg). Returns the per-frame stats."""
    from .devices import FallbackPolicy, GazeTracker, HeadTracker
    from .foveate import Foveation, render_foveated

    if frames is None and seconds is None:
        raise ValueError("run_session: give frames= or seconds=")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"run_session: fps must be positive, got {fps}")
    n_frames = int(frames if frames is not None else round(seconds * fps))
    if n_frames < 1:
        raise ValueError(f"run_session: need at least one frame, got {n_frames}")
    if clock not in ("virtual", "wall"):
        raise ValueError(f"run_session: clock must be 'virtual' or 'wall', got {clock!r}")
    foveation = foveation or Foveation()
    vclock = VirtualClock() if clock == "virtual" else None
    now = vclock if vclock is not None else time.monotonic
    duration = n_frames / fps + 1.0
    gaze_source = _source(gaze, "gaze", now, duration)
    head_source = _source(head, "head", now, duration)
    tracker = GazeTracker(policy=policy or FallbackPolicy())
    head_tracker = HeadTracker()
    key = jax.random.key(0) if key is None else key
    out = Path(out) if out is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)

    rows: list[SessionFrame] = []
    writer = None
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_frames, unit="frame", desc="session")
    try:
        gaze_source.open()
        if head_source is not None:
            head_source.open()
        if video and out is not None:
            import imageio.v2 as iio

            try:
                writer = iio.get_writer(out / "session.mp4", fps=fps, macro_block_size=1)
            except Exception as exc:  # no ffmpeg backend
                raise ImportError(
                    f"video=True needs imageio-ffmpeg (pip install 'fovjax[video]'): {exc}"
                ) from exc
        for k in range(n_frames):
            t = now()
            tf = tracker.step(t, gaze_source.drain(), display_time=t)
            hf = head_tracker.step(t, head_source.drain()) if head_source is not None else None
            pose = (hf.yaw, hf.pitch, hf.roll) if hf is not None else (0.0, 0.0, 0.0)
            fovea, periphery = tf.thresholds(foveation.fovea_deg, foveation.periphery_deg, FULL_DEG)
            frame_fov = dataclasses.replace(foveation, fovea_deg=fovea, periphery_deg=periphery)
            gaze_xy = np.clip(np.array([tf.left, tf.right], np.float32), 0.0, 1.0)
            frame_key = jax.random.fold_in(key, k) if fresh_key_per_frame else key
            frame = render_foveated(
                scene,
                rig,
                gaze=gaze_xy,
                foveation=frame_fov,
                head_pose=pose,
                key=frame_key,
                config=config,
                bvh=bvh,
            )
            path = ""
            if out is not None:
                path = str(frame.save(out / f"frame_{k:05d}.png"))
                if writer is not None:
                    from ._image import linear_to_srgb

                    writer.append_data(np.round(linear_to_srgb(frame.image) * 255).astype(np.uint8))
            rows.append(
                SessionFrame(
                    frame=k,
                    time_s=float(t),
                    tracking_state=str(tf.state),
                    widening=float(tf.widening),
                    gaze_age_s=float(tf.sample_age),
                    gaze_left=tuple(float(x) for x in gaze_xy[0]),
                    gaze_right=tuple(float(x) for x in gaze_xy[1]),
                    head_state=str(hf.state) if hf is not None else "none",
                    head_pose=tuple(float(x) for x in pose),
                    fovea_deg=float(fovea),
                    periphery_deg=float(periphery),
                    primary_rays=frame.stats.primary_rays,
                    shadow_rays=frame.stats.shadow_rays,
                    reflection_rays=frame.stats.reflection_rays,
                    dropped=frame.foveation.dropped,
                    render_s=frame.stats.render_seconds,
                    compile_s=frame.stats.compile_seconds,
                    rejected_samples=int(sum(tf.rejected.values())),
                    path=path,
                )
            )
            if bar is not None:
                bar.set_postfix_str(
                    f"{tf.state} {fovea:.0f}°/{periphery:.0f}° {frame.stats.rays / 1e6:.2f} Mrays"
                )
                bar.update(1)
            if vclock is not None:
                vclock.advance(1.0 / fps)
    finally:
        gaze_source.close()
        if head_source is not None:
            head_source.close()
        if writer is not None:
            writer.close()
        if bar is not None:
            bar.close()
    if out is not None:
        _write_log(out, rows)
    return SessionResult(frames=rows, out=out, video=(out / "session.mp4") if (video and out) else None)


def _write_log(out: Path, rows: list[SessionFrame]) -> None:
    fields = [f.name for f in dataclasses.fields(SessionFrame)]
    with open(out / "session.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields)
        w.writeheader()
        for r in rows:
            w.writerow(
                {k: (json.dumps(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(r).items()}
            )
    with open(out / "session.json", "w") as fh:
        json.dump([dataclasses.asdict(r) for r in rows], fh, indent=1)
