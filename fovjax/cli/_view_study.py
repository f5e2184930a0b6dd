"""`fovjax view --study pair|ramp|slider --participant ID -o DIR`: the thesis's user study run
with a person in the browser (`fovjax.view.StudyServer`), answers recorded in DIR as they are
given (`fovjax.eval.StudyLog`).

Pre-rendered clips, not live rendering: the stimuli are the same animated sequence
(`fovjax.eval.study_sequence`: a slow walk with the head looking around, the gaze fixed at the
centre of each eye, where the page draws the fixation mark) rendered once, full and at every
level, into DIR/clips/ and reused by every participant and every resumed session. At the
thesis's SPP 4 on a CPU a live frame of 2 x 320 x 256 takes far longer than a display frame
(the command prints the rate it rendered at); played from memory, every participant sees the
same frames, each segment lasts its protocol duration to within a display frame whatever the
machine, and the page measures that. Gaze from a tracker needs live rendering and is not offered
here (`--gaze` must stay 'mouse').

`--time-scale S` multiplies every protocol duration by S (0 < S <= 1): for testing the player
quickly, never for a real session (it is recorded in every row, and `fovjax study` says so).
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import math
import threading
import time
from pathlib import Path

from fovjax import cli

STUDY_TESTS = ("pair", "ramp", "slider")
STUDY_SPP = 4  # thesis 5.2
DEFAULT_CLIP_FRAMES = 60
DEFAULT_CLIP_FPS = 30.0  # the thesis's renderer reached 26 fps full, 48 foveated at SPP 4
QUESTIONS = {
    "pair": "Which of the two sequences looked better?",
    "ramp": "Compared with the sequence just before it, did the quality increase, decrease or stay the same?",
    "slider": "Change the level until it looks the same as the reference, then choose it.",
}
ANSWER_LABELS = {
    "first": "First better",
    "second": "Second better",
    "same": "Same",
    "increase": "Increased",
    "decrease": "Decreased",
}


def add_arguments(p) -> None:
    p.add_argument(
        "--study",
        metavar="TEST",
        help="run one test of the thesis's user study with a participant: pair, ramp or slider "
        "(needs --participant and -o)",
    )
    p.add_argument(
        "--participant", metavar="ID", help="with --study: the participant's ID (e.g. p07; no names)"
    )
    p.add_argument(
        "-o",
        "--output",
        metavar="DIR",
        help="with --study: the study folder (answers, participant forms, clips); a session resumes there",
    )
    p.add_argument(
        "--frames",
        type=int,
        default=DEFAULT_CLIP_FRAMES,
        help=f"with --study: frames per clip (default {DEFAULT_CLIP_FRAMES}; played forwards then backwards)",
    )
    p.add_argument(
        "--clip-fps",
        type=float,
        default=DEFAULT_CLIP_FPS,
        help=f"with --study: the clips' frame rate (default {DEFAULT_CLIP_FPS:g})",
    )
    p.add_argument(
        "--clips",
        metavar="CLIP_DIR",
        help="with --study: play the clips in this folder (DIR/clips/<key>/ of another study folder, e.g. "
        "rendered on a faster machine) instead of rendering them; their settings are recorded",
    )
    p.add_argument(
        "--time-scale",
        type=float,
        default=1.0,
        help="with --study, FOR TESTING ONLY: multiply the protocol's durations (0.5 s black, 5 s steps) by "
        "this (0 < S <= 1; recorded in every answer)",
    )


def validate(args) -> None:
    """The --study arguments (after `fovjax view`'s own), before anything is rendered."""
    from fovjax.eval import StudyLogError, check_participant

    cli.choice(args.study, "--study", STUDY_TESTS)
    if args.participant is None:
        raise cli.UsageError("--study needs --participant ID (e.g. p07)")
    try:
        check_participant(args.participant)
    except StudyLogError as err:
        raise cli.UsageError(f"--participant {args.participant!r}: {str(err).partition(': ')[2]}") from None
    if args.output is None:
        raise cli.UsageError("--study needs -o DIR, the study folder the answers are written to")
    cli.output(args.output, "-o", directory=True)
    cli.number(args.frames, "--frames", ge=2, le=10_000, integer=True)
    cli.number(args.clip_fps, "--clip-fps", gt=0, le=240)
    cli.number(args.time_scale, "--time-scale", gt=0, le=1)
    if args.clips is not None:
        read_clips(args.clips)
    if args.gaze != "mouse":
        raise cli.UsageError(
            f"--gaze {args.gaze}: --study plays pre-rendered clips foveated at a fixed gaze (the thesis's "
            "fixation mark); a tracker's gaze needs live rendering"
        )
    if args.width < 8 or args.height < 8:
        raise cli.UsageError(
            f"--width/--height {args.width}x{args.height}: --study needs at least 8x8 per eye"
        )


# ---- clips ------------------------------------------------------------------------------------


def _clip_settings(args) -> dict:
    from fovjax.eval import APPENDIX_LEVELS

    return {
        "scene": args.scene,
        "triangles": args.triangles if args.scene == "atrium" else None,
        "eye_width": args.width,
        "eye_height": args.height,
        "frames": args.frames,
        "fps": args.clip_fps,
        "spp": args.spp,
        "regions": args.regions,
        "max_depth": args.max_depth,
        "levels": [list(lv) for lv in APPENDIX_LEVELS],
        "gaze": "fixed",
    }


CLIP_MANIFEST = "manifest.json"


def clip_names(levels) -> list[str]:
    """The clips a study needs, in order: the reference, then each level as "fovea/periphery"."""
    return ["reference", *(f"{f:g}/{p:g}" for f, p in levels)]


def write_clips(folder, settings: dict, clips, **stats) -> Path:
    """Store clips [(name, [JPEG bytes per frame])] in `folder` as `fovjax view --study` reads
    them: frame f of clip c in `<c>_<f:04d>.jpg`, and `manifest.json` (the settings -- "fps" the
    frame rate they play at --, each clip's name and frame count, `stats`) written last, so a
    folder without one is incomplete."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for c, (_, frames) in enumerate(clips):
        for f, jpeg in enumerate(frames):
            (folder / f"{c}_{f:04d}.jpg").write_bytes(jpeg)
    manifest = {
        "settings": settings,
        "clips": [{"name": name, "frames": len(frames)} for name, frames in clips],
        "rendered": time.strftime("%Y-%m-%d %H:%M:%S"),
        **stats,
    }
    tmp = folder / (CLIP_MANIFEST + ".tmp")
    tmp.write_text(json.dumps(manifest, indent=1) + "\n")
    tmp.replace(folder / CLIP_MANIFEST)
    return folder / CLIP_MANIFEST


def read_clips(folder, option: str = "--clips") -> tuple[list, dict]:
    """The clips and manifest `write_clips` stored in `folder`, checked: every clip the study
    needs (`clip_names`) with at least one frame, and every frame's file present; a UsageError
    names what is missing."""
    from fovjax.eval import APPENDIX_LEVELS

    folder = Path(folder)
    path = folder / CLIP_MANIFEST
    if not path.is_file():
        raise cli.UsageError(
            f"{option} {folder}: no {CLIP_MANIFEST} (not a clip folder, or an incomplete one)"
        )
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
        listed = [(str(c["name"]), int(c["frames"])) for c in manifest["clips"]]
        fps = float(manifest["settings"]["fps"])
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as err:
        raise cli.UsageError(f"{path}: not a clip manifest ({type(err).__name__}: {err})") from None
    names = [name for name, _ in listed]
    if names != clip_names(APPENDIX_LEVELS):
        raise cli.UsageError(f"{path}: clips {names}, expected {clip_names(APPENDIX_LEVELS)}")
    if not (math.isfinite(fps) and fps > 0) or any(n < 1 for _, n in listed):
        raise cli.UsageError(f"{path}: expected fps > 0 and at least one frame per clip")
    clips = []
    for c, (name, n) in enumerate(listed):
        frames = []
        for f in range(n):
            frame = folder / f"{c}_{f:04d}.jpg"
            if not frame.is_file():
                raise cli.UsageError(f"{path}: clip {name!r} frame {f}: {frame} is missing")
            frames.append(frame.read_bytes())
        clips.append((name, frames))
    return clips, manifest


def clips_for(args, load_scene) -> tuple[list, dict]:
    """The clips [(name, [JPEG per frame])] and their manifest: from --clips DIR when given;
    else from DIR/clips/<key>/ when an earlier session rendered them with the same settings;
    else rendered now and stored there (`write_clips`)."""
    from fovjax.eval import StudyAnimation, study_sequence
    from fovjax.render import RenderConfig
    from fovjax.view import encode_jpeg

    if args.clips is not None:
        clips, manifest = read_clips(args.clips)
        print(f"fovjax view: clips from {args.clips} (rendered {manifest['rendered']})", flush=True)
        return clips, manifest
    settings = _clip_settings(args)
    key = hashlib.sha1(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:12]
    folder = Path(args.output) / "clips" / key
    if (folder / CLIP_MANIFEST).is_file():
        clips, manifest = read_clips(folder, "-o")
        print(f"fovjax view: clips from {folder} (rendered {manifest['rendered']})", flush=True)
        return clips, manifest
    print(
        f"fovjax view: rendering the clips ({args.frames} frames x {1 + len(settings['levels'])} versions, "
        f"2x{args.width}x{args.height}, spp {args.spp}) into {folder}",
        flush=True,
    )
    t0 = time.perf_counter()
    animation = StudyAnimation(
        eye_width=args.width,
        eye_height=args.height,
        frames=args.frames,
        fps=args.clip_fps,
        spp=args.spp,
        gaze="fixed",
        regions=args.regions,
    )
    print(
        "fovjax view: building the scene and compiling the frame programs (the first frame takes a "
        "while); the page's address follows once the clips are ready",
        flush=True,
    )
    sequence = study_sequence(
        load_scene(args),
        animation,
        config=RenderConfig(max_depth=args.max_depth, backend=args.backend),
        progress=_clip_progress(args.frames),
    )
    wall = time.perf_counter() - t0
    images = [sequence.reference, *(sequence.foveated[level] for level in sequence.levels)]
    clips = [
        (name, [encode_jpeg(image) for image in frames])
        for name, frames in zip(clip_names(sequence.levels), images, strict=True)
    ]
    rendered = sequence.frames * len(clips)
    live_fps = rendered / sequence.render_seconds if sequence.render_seconds > 0 else None
    with cli.deferred_interrupt():  # the clip folder whole (its manifest last), or not at all
        write_clips(
            folder,
            settings,
            clips,
            render_seconds=sequence.render_seconds,
            compile_seconds=sequence.compile_seconds,
            live_fps=live_fps,
            primary_rays={
                ("reference" if k is None else f"{k[0]:g}/{k[1]:g}"): v
                for k, v in sequence.primary_rays.items()
            },
        )
        cli.wrote(folder)
    rate = "" if live_fps is None else f"{live_fps:.1f} frames/s rendering, against "
    print(
        f"fovjax view: rendered {rendered} frames in {wall:.1f} s "
        f"({sequence.compile_seconds:.1f} s compiling): "
        f"{rate}{args.clip_fps:g} frames/s played; pre-rendered clips",
        flush=True,
    )
    return read_clips(folder, "-o")


def _clip_progress(frames: int):
    """`study_sequence`'s progress: where the rendering is and about how long is left (from the
    frames after the first, which compiles), on one line rewritten in place on a terminal, else
    every tenth of the way."""
    import sys

    started = time.perf_counter()
    times: list[float] = []  # when each frame was done
    every = max(1, frames // 10)
    live = sys.stderr.isatty()

    def tick(text: str) -> None:
        now = time.perf_counter()
        times.append(now)
        done = len(times)
        left = "" if done < 2 else f", about {(now - times[0]) / (done - 1) * (frames - done):.0f} s left"
        line = f"fovjax view: rendering the clips: {text} ({now - started:.0f} s{left})"
        if live:
            end = "\n" if done == frames else ""
            print(f"\r{line}\033[K", end=end, file=sys.stderr, flush=True)
        elif done == 1 or done % every == 0 or done == frames:
            print(line, file=sys.stderr, flush=True)

    return tick


# ---- the study between the page and the record ------------------------------------------------


class StudyHost:
    """`fovjax.view.StudyServer`'s `study`: the trial sequence and record of a `StudyLog`, the
    clips by index (0 the reference, 1.. the levels)."""

    def __init__(self, log, clip_names, time_scale: float):
        self.log = log
        self.clip_of = {name: k for k, name in enumerate(clip_names)}
        self.time_scale = time_scale
        self.start_index = log.next_index  # where this run began: a resumed ramp repeats a step

    def _resumed(self, index: int) -> bool:
        return index == self.start_index and index > 0

    def _clip(self, segment) -> int | None:
        if segment.kind == "black":
            return None
        if segment.kind == "reference":
            return self.clip_of["reference"]
        return self.clip_of[f"{segment.level[0]:g}/{segment.level[1]:g}"]

    def state(self) -> dict:
        from fovjax.eval import PARTICIPANT_FORM, RAMP_GAP_S, RAMP_STEP_S

        log = self.log
        return {
            "participant": log.participant,
            "test": log.test,
            "trials": len(log.trials),
            "answered": len(log.answered),
            "next": log.next_index,
            "form_needed": log.form is None,
            "time_scale": self.time_scale,
            "resumed": bool(log.answered),
            "form": {name: list(choices) for name, choices in PARTICIPANT_FORM.items()},
            # The protocol's durations, for the instructions (as the page will show them).
            "timings": {"gap_s": RAMP_GAP_S * self.time_scale, "step_s": RAMP_STEP_S * self.time_scale},
        }

    def trial(self, index: int) -> dict:
        if index != self.log.next_index:
            raise ValueError(f"trial {index} is not the next unanswered trial ({self.log.next_index})")
        trial = self.log.trials[index]
        segments = self.log.presentation_of(index, resumed=self._resumed(index))
        payload = {
            "index": index,
            "test": trial.test,
            "condition": trial.condition,
            "question": QUESTIONS[trial.test],
            "segments": [
                {
                    "kind": s.kind,
                    "label": s.label,
                    "seconds": None if s.seconds is None else s.seconds * self.time_scale,
                    "clip": self._clip(s),
                }
                for s in segments
            ],
            "choices": [{"value": c, "label": ANSWER_LABELS.get(c, f"{c}°")} for c in trial.choices],
        }
        if trial.test == "slider":
            from fovjax.eval import SLIDER_REFERENCE_S

            payload["slider"] = {
                "levels": [list(lv) for lv in trial.levels],
                "clips": [self.clip_of[f"{f:g}/{p:g}"] for f, p in trial.levels],
                "start": trial.levels.index(trial.level),
                "gap_s": segments[0].seconds * self.time_scale,
                "reference_s": SLIDER_REFERENCE_S * self.time_scale,
                "reference_clip": self.clip_of["reference"],
            }
        return payload

    def save_form(self, form: dict) -> dict:
        stored = self.log.save_form(form)
        cli.wrote(self.log.form_path)
        return stored

    def record(self, payload: dict) -> dict:
        if self.log.form is None:
            raise ValueError("the participant form comes first")
        index, answer = payload.get("index"), payload.get("answer")
        if isinstance(index, bool) or not isinstance(index, int):
            raise ValueError(f"answer: index must be a trial number, got {index!r}")
        if index != self.log.next_index:
            raise ValueError(
                f"answer to trial {index}, but the next unanswered trial is {self.log.next_index}"
            )
        if answer not in self.log.trials[index].choices:
            raise ValueError(f"answer {answer!r} is not one of {self.log.trials[index].choices}")
        row = self.log.record(index, answer, payload.get("measured") or {}, resumed=self._resumed(index))
        cli.wrote(self.log.path)
        timing = "within a frame" if row["timing_ok"] else f"OFF by up to {row['timing_worst_ms']:.1f} ms"
        print(
            f"fovjax view: {self.log.participant} {self.log.test} trial {index + 1}/{len(self.log.trials)} "
            f"({row['condition']}): {answer!r} after {row['time_s']:.2f} s; shown durations {timing} "
            f"(frame {row['frame_interval_ms']:.1f} ms, {row['late_frames']} late)",
            flush=True,
        )
        return row


def run(args, load_scene) -> int:
    from fovjax.eval import StudyLog
    from fovjax.view import StudyServer

    settings = _clip_settings(args) if args.clips is None else read_clips(args.clips)[1]["settings"]
    # The record first: a resumed session with other settings is refused before any rendering.
    log = StudyLog.open(
        args.output,
        args.participant,
        args.study,
        seed=args.seed,
        time_scale=args.time_scale,
        stimulus={k: settings.get(k) for k in ("scene", "eye_width", "eye_height", "frames", "fps", "spp")},
    )
    if log.dropped_tail:
        print(
            f"fovjax view: note: {log.path}: its last line was cut off (a crash); that trial is asked again"
        )
    if log.next_index is None:
        print(f"fovjax view: {args.participant} has answered every {args.study} trial already ({log.path})")
        return 0
    clips, manifest = clips_for(args, load_scene)
    with cli.deferred_interrupt():  # the session file whole, and only now the clips are ready
        log.begin()
        cli.wrote(log.settings_path)
    host = StudyHost(log, [name for name, _ in clips], args.time_scale)
    clip_fps = float(manifest["settings"]["fps"])
    server = StudyServer(host, clips, clip_fps=clip_fps, host=args.host, port=args.port)
    interrupted = threading.Event()
    asyncio.run(_serve(server, args, log, interrupted))
    if interrupted.is_set():
        raise KeyboardInterrupt
    print(f"fovjax view: {args.participant} answered all {len(log.trials)} {args.study} trials: {log.path}")
    return 0


async def _serve(server, args, log, interrupted: threading.Event) -> None:
    from ._view import _first_interrupt

    loop = asyncio.get_running_loop()
    stop = asyncio.Event()

    def on_ctrl_c(signum, frame):
        interrupted.set()
        restore()
        loop.call_soon_threadsafe(stop.set)

    restore = _first_interrupt(on_ctrl_c)
    try:
        try:
            url = await server.start()
        except OSError as err:
            raise OSError(f"cannot listen on {server.host}:{server.port}: {err.strerror or err}") from None
        try:
            answered = len(log.answered)
            where = f"resuming at trial {answered + 1}" if answered else "from the first trial"
            print(
                f"fovjax view: {args.study} test for {args.participant}, {len(log.trials)} trials, {where}; "
                f"serving {url}  (Ctrl-C to stop; answers so far are kept)",
                flush=True,
            )
            if args.time_scale != 1:
                print(
                    f"fovjax view: note: --time-scale {args.time_scale:g}: for testing, "
                    "not the thesis's timings"
                )
            if args.open:
                import webbrowser

                webbrowser.open(url)
            waiters = {asyncio.ensure_future(stop.wait()), asyncio.ensure_future(server.done.wait())}
            _, pending = await asyncio.wait(waiters, return_when=asyncio.FIRST_COMPLETED)
            for task in pending:
                task.cancel()
        finally:
            await server.stop()
    finally:
        restore()
