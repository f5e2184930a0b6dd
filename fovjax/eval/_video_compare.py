"""Compare foveation methods on an animated sequence: the gaze of a recording replayed frame by
frame, every method × threshold pair rendered along it, each judged by FovVideoVDP in video
mode against the full render of the same frames.

    import fovjax, fovjax.eval as fe
    renderer = fovjax.FoveatedRenderer(scene, rig)
    sweep = fe.ThresholdSweep(thresholds=[(5, 10)], spp=[1], methods=list(fovjax.foveate.METHODS))
    cmp = fe.compare_methods_on_recording(renderer, "data/recordings/synthetic_scanpath_seed1_dropout.csv",
                                          sweep, frames=60, fps=30.0, start_s=1.5)
    cmp.records                                   # one row per method × threshold pair × SPP
    cmp.measure("weier2016", "thesis", (5, 10))   # new rays ratio and both JOD intervals
    cmp.write("out/compare_video")                # video_comparison.csv and video_comparison.png

What the sequence is:

- Frame k is shown at t_k = `start_s` + k / `fps` on a virtual clock, as `run_session` runs a
  recording: the recording is replayed (`fovjax.devices.source_from_spec("replay:PATH")`) on
  that clock, the samples that arrived by t_k go through one `GazeTracker` (its
  `FallbackPolicy`: hold, widen, lost, recover), the frame's gaze is the tracker's (clamped to
  the screen) and its thresholds are each configuration's widened by the tracker's widening
  towards the fovea that covers the screen (`widen_thresholds`). The tracking is computed once
  and is the same for every configuration.
- Tracking loss: where the tracker's state becomes "lost" (and on the first frame), a temporal
  method's history is reset, as `run_session` does.
- Head pose: fixed, the renderer's rig (as `run_session` with no head source): the sequence
  isolates gaze motion and tracking loss. (The video study's walk and look-around,
  `StudyAnimation`, is not used.)
- Keys: frame k uses `jax.random.fold_in(jax.random.key(sweep.keys[0]), k)` for the full render
  and for every configuration (a fresh sampling pattern per frame, as `run_session`'s default).
  The sweep's `gazes` are not used: the gaze is the recording's.
- Reference: one full render per frame (`FoveatedRenderer.render_full`) with the same key.
- Each configuration is rendered frame by frame through one `FoveatedRenderer` (one compiled
  program; the thresholds are traced), its history carried across frames.
- Cost: ms per frame is the median of the frames' run times (compile excluded); new primary
  rays per frame (`FrameStats.primary_rays`: the rays traced this frame; a temporal method's
  reused pixels cost none) and rays per frame (with shadow and reflection rays) are means over
  the frames (`new_rays_per_frame_ok`: over the frames where tracking is ok and no history was
  reset, a temporal method's steady state; the first frame, which has no history, and the
  widened frames of a tracking loss, which render the whole screen, are left out of it);
  reused pixels per frame is the mean of `FoveationStats.reused`.
- Quality: FovVideoVDP (`fovvdp`, video mode at `fps`, foveated, fixation = the frame's gaze per
  eye) of the whole sequence against the full sequence on the SX111 display model at the
  rendered resolution (`sx111_display`); `jod` is the worse eye's. Interval: the sequence is
  also judged as `blocks` consecutive blocks of frames (each in video mode); the 95%
  Student-t half-width of the mean of the blocks' worse-eye JODs, put around the whole
  sequence's JOD, is `jod_lo`/`jod_hi` (`jod_hi` at most 10). It is the spread over time of the
  sequence's quality (how much the JOD depends on which part of the recording is judged);
  FovVideoVDP itself is deterministic, so repeating it gives no interval. `blocks=0`: no
  interval (NaN). PSNR is the mean over frames with a Student-t interval over frames.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ._pareto import mean_interval, pareto_front, write_csv

DEFAULT_FRAMES = 60
DEFAULT_FPS = 30.0
DEFAULT_BLOCKS = 4
MIN_BLOCK_FRAMES = 2  # a block is a video: at least two frames
JOD_MAX = 10.0


def _where() -> str:
    return "compare_methods_on_recording"


def _is_int(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | np.integer)


def _is_number(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | float | np.integer | np.floating)


def _check(renderer, recording, sweep, frames, fps, start_s, blocks, tracker, perceptual):
    """Every argument, before anything is rendered: (recording path, loaded recording, sweep)."""
    from ..devices import GazeTracker, load_recording
    from ..foveate import FoveatedRenderer
    from ._compare import ThresholdSweep

    where = _where()
    if not isinstance(renderer, FoveatedRenderer):
        raise ValueError(f"{where}: renderer {renderer!r}: expected a fovjax.FoveatedRenderer")
    if isinstance(recording, str) and recording.startswith("replay:"):
        recording = recording[len("replay:") :]
    if not isinstance(recording, str | Path):
        raise ValueError(f"{where}: recording {recording!r}: expected the path of a gaze recording")
    path = Path(recording)
    if not path.is_file():
        raise ValueError(
            f"{where}: recording {str(path)!r}: expected an existing .csv or .jsonl gaze recording"
        )
    loaded = load_recording(path)  # ValueError naming the file, line and field
    if loaded.kind != "gaze":
        raise ValueError(f"{where}: recording {str(path)!r} holds {loaded.kind} samples: expected gaze")
    if not loaded.samples:
        raise ValueError(f"{where}: recording {str(path)!r} has no samples: expected a gaze recording")
    if sweep is None:
        from ..foveate import METHODS

        sweep = ThresholdSweep(thresholds=((5, 10),), spp=(1,), methods=tuple(METHODS))
    elif not isinstance(sweep, ThresholdSweep):
        raise ValueError(f"{where}: sweep {sweep!r}: expected a fovjax.eval.ThresholdSweep or None")
    if not _is_int(frames) or frames < MIN_BLOCK_FRAMES:
        raise ValueError(f"{where}: frames {frames!r}: expected a whole number >= {MIN_BLOCK_FRAMES}")
    if not _is_number(fps) or not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"{where}: fps {fps!r}: expected a finite number > 0 (frames per second)")
    if not _is_number(start_s) or not (math.isfinite(start_s) and start_s >= 0):
        raise ValueError(f"{where}: start_s {start_s!r}: expected a finite number of seconds >= 0")
    first, last = loaded.samples[0].timestamp, loaded.samples[-1].timestamp
    length = last - first
    end = float(start_s) + (int(frames) - 1) / float(fps)
    if end > length + 1e-9:
        raise ValueError(
            f"{where}: frames {frames} at {fps:g} fps from start_s {start_s:g} end at {end:.3f} s: expected "
            f"frame times within the recording's {length:.3f} s"
        )
    if not _is_int(blocks) or not (blocks == 0 or 2 <= blocks <= frames // MIN_BLOCK_FRAMES):
        raise ValueError(
            f"{where}: blocks {blocks!r}: expected 0 (no interval) or a whole number from 2 to "
            f"{frames // MIN_BLOCK_FRAMES} (blocks of at least {MIN_BLOCK_FRAMES} of the {frames} frames)"
        )
    if tracker is not None and not isinstance(tracker, GazeTracker):
        raise ValueError(f"{where}: tracker {tracker!r}: expected a fovjax.devices.GazeTracker or None")
    if not isinstance(perceptual, bool):
        raise ValueError(f"{where}: perceptual {perceptual!r}: expected True or False")
    if perceptual:
        from ._metrics import _require

        _require("pyfvvdp", "fvvdp", f"{where}'s FovVideoVDP")
    return path, sweep


def _track(path: Path, times: np.ndarray, tracker) -> list[dict]:
    """The gaze per frame as `run_session` computes it on its virtual clock: the recording
    replayed on the clock, the samples that arrived by each frame's time through `tracker`."""
    from ..devices import GazeTracker, source_from_spec

    tracker = tracker or GazeTracker()
    tracker.reset()
    now = {"t": 0.0}
    source = source_from_spec(f"replay:{path}", "gaze", clock=lambda: now["t"])
    rows, previous = [], None
    source.open()
    try:
        for k, t in enumerate(times):
            now["t"] = float(t)
            tf = tracker.step(float(t), source.drain(), display_time=float(t))
            state = str(tf.state)
            # run_session's rule: a temporal method's history is dropped where tracking
            # becomes lost (the frame starts from none); every configuration starts from none.
            reset = k == 0 or (state == "lost" and previous != "lost")
            previous = state
            gaze = np.clip(np.array([tf.left, tf.right], np.float32), 0.0, 1.0)
            rows.append(
                {
                    "frame": k,
                    "time_s": float(t),
                    "state": state,
                    "widening": float(tf.widening),
                    "reset": bool(reset),
                    "gaze": gaze,
                }
            )
    finally:
        source.close()
    return rows


def _configurations(base, sweep):
    """(label, fields, foveation) for every method × threshold pair × SPP × acuity model."""
    import itertools

    from ..foveate import Foveation, method_label, with_regions

    models = [None] if sweep.models is None else list(sweep.models)
    methods = [Foveation(method=m).method for m in sweep.methods]  # names checked by Foveation
    without_rule = [m.name for m in methods if "rule" not in m.thesis_options]
    if without_rule and sweep.rule != "either":
        raise ValueError(
            f"{_where()}: sweep.rule {sweep.rule!r}: expected 'either' with the methods {without_rule} "
            "(a sampling rule is the thesis's method's)"
        )
    out = []
    for s, (fovea, periphery), model, method in itertools.product(
        sweep.spp, sweep.thresholds, models, methods
    ):
        kwargs = {} if model is None else {"acuity": model}
        fov = Foveation(
            fovea_deg=float(fovea),
            periphery_deg=float(periphery),
            spp=int(s),
            rule=sweep.rule,
            method=method,
            **kwargs,
        )
        fov = with_regions(fov, sweep.regions, base.rig.eye_height)
        model_name = "thesis" if model is None else getattr(model, "name", type(model).__name__)
        name = method_label(method)  # its parameters where they are not the defaults
        label = f"{name} {fovea:g}/{periphery:g} spp{s}" + ("" if model is None else f" {model_name}")
        fields = {
            "method": name,
            "fovea_deg": float(fovea),
            "periphery_deg": float(periphery),
            "spp": int(s),
            "model": model_name,
            "regions": sweep.regions,
        }
        out.append((label, fields, fov))
    return out


def _jod(test, ref, display, gazes, fps: float, blocks: int) -> dict:
    """The whole sequence's FovVideoVDP JOD (worse eye, each eye) and the interval from blocks."""
    from ._metrics import fovvdp

    whole = fovvdp(test, ref, display, gaze_xy=gazes, fps=fps)
    jod = float(whole)
    out = {
        "jod": jod,
        "jod_left": float(whole.details.get("jod_left", math.nan)),
        "jod_right": float(whole.details.get("jod_right", math.nan)),
        "jod_lo": math.nan,
        "jod_hi": math.nan,
        "jod_blocks": "",
        "jod_n": 0,
    }
    if blocks:
        edges = np.linspace(0, len(test), blocks + 1).round().astype(int)
        values = [
            float(fovvdp(test[a:b], ref[a:b], display, gaze_xy=gazes[a:b], fps=fps))
            for a, b in zip(edges[:-1], edges[1:], strict=True)
        ]
        mean, lo, _ = mean_interval(values)
        half = mean - lo
        out.update(
            jod_lo=jod - half,
            jod_hi=min(JOD_MAX, jod + half),
            jod_blocks=" ".join(f"{v:.4f}" for v in values),
            jod_n=len(values),
        )
    return out


def _psnr(test, ref) -> dict:
    from ._metrics import psnr

    values = [float(psnr(t, r).value) for t, r in zip(test, ref, strict=True)]
    finite = [v for v in values if math.isfinite(v)]
    if len(finite) >= 2:
        mean, lo, hi = mean_interval(finite)
    elif values and all(v == values[0] for v in values):
        mean = lo = hi = values[0]
    else:
        mean = float(np.mean(finite)) if finite else math.inf
        lo = hi = math.nan
    return {"psnr": mean, "psnr_lo": lo, "psnr_hi": hi}


@dataclasses.dataclass(frozen=True)
class VideoComparison:
    """What `compare_methods_on_recording` measured.

    `records`: one per configuration (CSV-writable; see `RECORD_FIELDS`); `frames`: the tracking
    per frame (time, state, widening, whether histories were reset, gaze), the same for every
    configuration; `series`: per configuration label, the per-frame `new_rays`, `reused` and
    `ms`; `full`: the full render's ms and rays per frame; `recording`, `fps`, `start_s`."""

    records: list[dict]
    frames: list[dict]
    series: dict
    full: dict
    recording: str
    fps: float
    start_s: float

    @property
    def metric(self) -> str:
        """The quality column the chart and the Pareto front use: "jod", or "psnr" without it."""
        return "jod" if self.records and "jod" in self.records[0] else "psnr"

    def record(self, method: str, thresholds: Sequence[float], spp: int = 1) -> dict:
        """The record of `method` at (fovea, periphery) `thresholds` and `spp` (the thesis's
        acuity model); KeyError naming what is there when none matches."""
        fovea, periphery = (float(x) for x in thresholds)
        for r in self.records:
            if (r["method"], r["fovea_deg"], r["periphery_deg"], r["spp"]) == (method, fovea, periphery, spp):
                return r
        have = ", ".join(r["config"] for r in self.records)
        raise KeyError(f"no record of {method} at {fovea:g}/{periphery:g} spp{spp} (have: {have})")

    def measure(self, method: str, baseline: str, thresholds: Sequence[float], spp: int = 1) -> dict:
        """`method` against `baseline` at the same thresholds and SPP: the ratio of their new
        primary rays per frame (`new_rays_ratio`, over every frame; `new_rays_ratio_ok`, over the
        frames where tracking is ok and no history was reset), both JODs with their intervals,
        `at_most_half` (ratio <= 0.5) and `jod_no_lower` (the method's JOD interval reaches
        the baseline's: its upper end is at least the baseline's lower end, i.e. the method's
        JOD is not lower within the intervals; None without JOD intervals)."""
        a, b = self.record(method, thresholds, spp), self.record(baseline, thresholds, spp)
        ratio = a["new_rays_per_frame"] / b["new_rays_per_frame"] if b["new_rays_per_frame"] else math.nan
        ok = (
            a["new_rays_per_frame_ok"] / b["new_rays_per_frame_ok"]
            if b["new_rays_per_frame_ok"]
            else math.nan
        )
        out = {
            "method": method,
            "baseline": baseline,
            "fovea_deg": a["fovea_deg"],
            "periphery_deg": a["periphery_deg"],
            "spp": spp,
            "new_rays_ratio": ratio,
            "at_most_half": bool(ratio <= 0.5),
            "new_rays_ratio_ok": ok,
        }
        m = self.metric
        for who, r in ((method, a), (baseline, b)):
            out[f"{who}_{m}"] = r[m]
            out[f"{who}_{m}_lo"], out[f"{who}_{m}_hi"] = r[f"{m}_lo"], r[f"{m}_hi"]
        intervals = [a[f"{m}_hi"], b[f"{m}_lo"]]
        out["jod_no_lower"] = (
            bool(a[f"{m}_hi"] >= b[f"{m}_lo"]) if m == "jod" and all(map(math.isfinite, intervals)) else None
        )
        return out

    def write(self, out_dir) -> dict[str, Path]:
        """`video_comparison.csv` (the records) and `video_comparison.png` (new primary rays per
        frame and ms per frame against JOD, per method, the Pareto fronts marked)."""
        from ._charts import plot_methods_cost_quality

        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        m = self.metric
        what = "FovVideoVDP JOD" if m == "jod" else "PSNR dB"
        return {
            "csv": write_csv(self.records, out / "video_comparison.csv"),
            "chart": plot_methods_cost_quality(
                self.records,
                out / "video_comparison.png",
                costs=("new_rays_per_frame", "ms_per_frame"),
                quality=m,
                title=f"{len(self.frames)} frames at {self.fps:g} fps of {Path(self.recording).name} "
                f"from {self.start_s:g} s: {what} against the full render",
            ),
        }


# Every record's columns (besides `jod_*` with `perceptual`).
RECORD_FIELDS = (
    "config",
    "method",
    "fovea_deg",
    "periphery_deg",
    "spp",
    "model",
    "regions",
    "frames",
    "fps",
    "start_s",
    "ms_per_frame",
    "full_ms_per_frame",
    "speedup",
    "new_rays_per_frame",
    "new_rays_fraction",
    "new_rays_per_frame_ok",
    "rays_per_frame",
    "full_primary_rays_per_frame",
    "full_rays_per_frame",
    "reused_pixels_per_frame",
    "resets",
    "lost_frames",
    "compile_s",
    "psnr",
    "psnr_lo",
    "psnr_hi",
    "pareto",
)


def compare_methods_on_recording(
    renderer,
    recording,
    sweep=None,
    *,
    frames: int = DEFAULT_FRAMES,
    fps: float = DEFAULT_FPS,
    start_s: float = 0.0,
    blocks: int = DEFAULT_BLOCKS,
    tracker=None,
    perceptual: bool = True,
    progress: bool = True,
) -> VideoComparison:
    """Compare foveation methods and thresholds along a gaze recording (see the module
    docstring for the sequence, the cost and the JOD's interval).

    Args:
        renderer: the `fovjax.FoveatedRenderer` (scene, rig, render config, BVH; its foveation is
            replaced by each configuration's). The head stays at its rig.
        recording: a gaze recording (`.csv` or `.jsonl`, `fovjax.devices.load_recording`), as a
            path or "replay:PATH".
        sweep: the `ThresholdSweep`: `methods`, `thresholds`, `spp`, `models`, `rule`, `regions`,
            and `keys[0]` the first frame's key (its `gazes` are not used). Default: every method
            of `fovjax.foveate.METHODS` at 5°/10°, SPP 1.
        frames: how many frames (at least 2).
        fps: frames per second: frame k is at `start_s` + k / `fps` s of the recording.
        start_s: the first frame's time in the recording (seconds from its first sample); the
            last frame must lie within the recording.
        blocks: consecutive blocks of frames the JOD's interval is measured over (0: none;
            else 2 to frames / 2).
        tracker: the `fovjax.devices.GazeTracker` (default `GazeTracker()`, `run_session`'s
            default; its `policy` is the fallback).
        perceptual: measure FovVideoVDP (the `[fvvdp]` extra); False: PSNR only (tests).
        progress: print a line per configuration.

    Returns:
        A `VideoComparison`: `records` (one per configuration), `frames` (the tracking),
        `series` (per-frame cost), `measure(method, baseline, thresholds)`, `write(dir)`.

    Raises:
        ValueError: a bad argument, naming its value and what was expected (all checked before
            anything is rendered).
        MissingExtraError: `perceptual` and pyfvvdp is not installed (`pip install 'fovjax[fvvdp]'`).
    """
    import jax

    from ..devices import widen_thresholds
    from ..foveate import Foveation

    path, sweep = _check(renderer, recording, sweep, frames, fps, start_s, blocks, tracker, perceptual)
    from ..foveate.internal import full_eccentricity
    from ._video_study import sx111_display

    frames, fps, start_s = int(frames), float(fps), float(start_s)
    rig = renderer.rig
    times = start_s + np.arange(frames, dtype=np.float64) / fps
    configs = _configurations(renderer, sweep)  # bad methods, rule or models fail here
    tracking = _track(path, times, tracker)
    gazes = np.stack([row["gaze"] for row in tracking])
    base_key = jax.random.key(int(sweep.keys[0]))
    keys = [jax.random.fold_in(base_key, k) for k in range(frames)]
    say = print if progress else (lambda *a, **k: None)

    full = {}
    references = {}
    for s in sorted({fields["spp"] for _, fields, _ in configs}):
        base = renderer.with_foveation(Foveation(spp=s), diagnostics=())
        images, ms, rays, primary = [], [], [], []
        for k in range(frames):
            frame = base.render_full(key=keys[k])
            images.append(np.asarray(frame.image, np.float32))
            ms.append(1000 * frame.stats.render_seconds)
            rays.append(frame.stats.rays)
            primary.append(frame.stats.primary_rays)
        references[s] = np.stack(images)
        full[s] = {
            "ms_per_frame": statistics.median(ms),
            "rays_per_frame": float(np.mean(rays)),
            "primary_rays_per_frame": float(np.mean(primary)),
        }
        say(f"full spp {s}: {frames} frames, {full[s]['ms_per_frame']:.0f} ms per frame")
    display = sx111_display(rig.eye_width, rig.eye_height)
    resets = sum(row["reset"] for row in tracking)
    lost = sum(row["state"] == "lost" for row in tracking)
    records, series = [], {}
    for label, fields, fov in configs:
        started = time.perf_counter()
        fovea, periphery = fov.fovea_deg, fov.periphery_deg
        omega_full = max(full_eccentricity(rig, fov), periphery)
        # Its max_periphery_deg None: one program serves every widening up to the whole screen.
        config_renderer = renderer.with_foveation(fov, diagnostics=())
        config_renderer.reset_history()

        images, ms, new_rays, rays, reused, compile_s = [], [], [], [], [], 0.0
        for k, row in enumerate(tracking):
            widening = row["widening"] if fov.method.widens_fovea else 0.0  # see `Weier2016`
            thresholds = widen_thresholds(fovea, periphery, widening, omega_full)
            frame = config_renderer.render(
                row["gaze"], key=keys[k], thresholds=thresholds, reset=row["reset"]
            )
            images.append(np.asarray(frame.image, np.float32))
            ms.append(1000 * frame.stats.render_seconds)
            compile_s += frame.stats.compile_seconds
            new_rays.append(int(frame.stats.primary_rays))
            rays.append(int(frame.stats.rays))
            reused.append(int(frame.foveation.reused))
        # Frames where tracking is ok and the history is not reset on them: the steady state.
        ok_rays = [
            n for n, row in zip(new_rays, tracking, strict=True) if row["state"] == "ok" and not row["reset"]
        ]
        test = np.stack(images)
        ref = references[fields["spp"]]
        f = full[fields["spp"]]
        record = {
            "config": label,
            **fields,
            "frames": frames,
            "fps": fps,
            "start_s": start_s,
            "ms_per_frame": statistics.median(ms),
            "full_ms_per_frame": f["ms_per_frame"],
            "speedup": f["ms_per_frame"] / statistics.median(ms),
            "new_rays_per_frame": float(np.mean(new_rays)),
            "new_rays_per_frame_ok": float(np.mean(ok_rays)) if ok_rays else math.nan,
            "new_rays_fraction": float(np.mean(new_rays)) / f["primary_rays_per_frame"],
            "rays_per_frame": float(np.mean(rays)),
            "full_primary_rays_per_frame": f["primary_rays_per_frame"],
            "full_rays_per_frame": f["rays_per_frame"],
            "reused_pixels_per_frame": float(np.mean(reused)),
            "resets": resets,
            "lost_frames": lost,
            "compile_s": compile_s,
            **_psnr(test, ref),
        }
        if perceptual:
            record.update(_jod(test, ref, display, gazes, fps, blocks))
        records.append(record)
        series[label] = {"new_rays": new_rays, "reused": reused, "ms": ms}
        jod = (
            f", JOD {record['jod']:.3f} [{record['jod_lo']:.3f}, {record['jod_hi']:.3f}]"
            if perceptual
            else ""
        )
        say(
            f"{label}: {record['ms_per_frame']:.0f} ms, "
            f"{record['new_rays_per_frame']:,.0f} new rays per frame{jod} "
            f"({time.perf_counter() - started:.0f} s)"
        )
    metric = "jod" if perceptual else "psnr"
    front = pareto_front(records, {"new_rays_per_frame": "min", metric: "max"}) if records else []
    for r, on_front in zip(records, front, strict=True):
        r["pareto"] = bool(on_front)
    frames_out = [{**row, "gaze": row["gaze"].tolist()} for row in tracking]
    return VideoComparison(records, frames_out, series, full, str(path), fps, start_s)
