"""People's answers to the user study, recorded as they are given (`fovjax view --study`).

One folder holds a study: per participant and test a results file
`<participant>_<test>.jsonl` (the results-file format, `RESULT_FIELDS`, one JSON object per
answer, plus what the player measured: `STUDY_LOG_FIELDS`), the session settings
`<participant>_<test>.session.json` (the trial order, its seed, the timings: a resumed session
must run the same sequence), and the participant form `<participant>.participant.json`
(`PARTICIPANT_FORM`: the thesis's form -- age, gender, eye colour, eye problems -- as ranges and
choices, plus vision correction and consent; no name is asked or stored: the participant is an
ID such as "p07").

Nothing is lost: each answer is one line written in one call, flushed and fsync'ed before the
page is told it was recorded; a line cut off by a crash (no newline at its end) is dropped when
the session resumes, and that trial asked again. A session resumes at its first unanswered trial.

Timing is measured, not assumed: the page reports the `requestAnimationFrame` timestamp at which
each segment of a trial (`presentation`) was first drawn and at which the answer buttons
appeared; a segment's shown duration is the next onset minus its own. `timing_problems` flags a
segment whose shown duration differs from the protocol's (times `time_scale`) by more than one
frame of the page's display (its median frame interval, measured during the trial).
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
import os
import re
import warnings
from collections.abc import Sequence
from pathlib import Path

from ._protocols import (
    APPENDIX_LEVELS,
    TESTS,
    Response,
    ResultsFileError,
    Trial,
    _check_levels,
    jsonl_rows,
    pair_trials,
    presentation,
    ramp_trials,
    read_responses,
    slider_presentation,
    slider_trial,
)

PARTICIPANT_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,31}")
# The participant form: field -> the answers offered (the page shows them as choices; free text
# is never asked, so nothing identifying can be typed in). "consent" must be "yes".
PARTICIPANT_FORM: dict[str, tuple[str, ...]] = {
    "age_range": ("18-24", "25-34", "35-44", "45-54", "55-64", "65+", "prefer not to say"),
    "gender": ("female", "male", "other", "prefer not to say"),
    "eye_colour": ("brown", "blue", "green", "hazel", "grey", "other", "prefer not to say"),
    "vision_correction": ("none", "glasses", "contact lenses", "other", "prefer not to say"),
    "eye_condition": (
        "none known",
        "colour vision deficiency",
        "amblyopia or strabismus",
        "other",
        "prefer not to say",
    ),
    "consent": ("yes",),
}
# Columns a recorded answer has besides RESULT_FIELDS.
STUDY_LOG_FIELDS = (
    "session",  # one id per `fovjax view --study` run: a resumed session has a new one
    "seed",
    "time_scale",
    "presented",  # per segment: kind, level, protocol_s, onset_ms, shown_s, frames
    "stimulus_end_ms",
    "answer_ms",
    "time_origin_ms",  # the page's performance.timeOrigin (ms since the epoch): its clock's zero
    "answered_utc",
    "frame_interval_ms",
    "frames_drawn",
    "late_frames",
    "timing_ok",
    "timing_worst_ms",
    "slider_actions",
    "clips",
)


# The resolution of the page's timestamps (performance.now() and requestAnimationFrame's in
# Chrome without cross-origin isolation: 100 µs), twice: a duration is the difference of two.
TIMESTAMP_RESOLUTION_MS = 0.2


class StudyLogError(ValueError):
    """A study folder that cannot be used as asked (the message says why and which file)."""


def check_participant(participant: str) -> str:
    """A participant ID: 1-32 letters, digits, '-' or '_', starting with a letter or digit (an
    ID such as "p07", never a name; it is part of file names)."""
    if not isinstance(participant, str) or PARTICIPANT_ID.fullmatch(participant) is None:
        raise StudyLogError(
            f"participant ID {participant!r}: use 1-32 letters, digits, '-' or '_' "
            "(an ID such as p07, not a name)"
        )
    return participant


def study_sequence_of(test: str, *, seed: int | None = None, levels=APPENDIX_LEVELS) -> list[Trial]:
    """The trials of one test in the order a participant sees them (`pair_trials`,
    `ramp_trials`, `slider_trial`; shuffled by `seed` where those are)."""
    if test == "pair":
        return pair_trials(levels, seed=seed)
    if test == "ramp":
        return ramp_trials(levels, seed=seed)
    if test == "slider":
        return [slider_trial(levels)]
    raise StudyLogError(f"unknown study test {test!r} (expected one of {', '.join(TESTS)})")


def _fsync_write(path: Path, text: str, mode: str) -> None:
    with path.open(mode, encoding="utf-8") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())


def _write_json(path: Path, payload: dict) -> None:
    """Complete or absent: written beside, fsync'ed, renamed over."""
    tmp = path.with_name(path.name + ".tmp")
    _fsync_write(tmp, json.dumps(payload, indent=1) + "\n", "w")
    os.replace(tmp, path)


def check_form(form) -> dict:
    """The participant form's answers, each one of `PARTICIPANT_FORM`'s choices, consent "yes";
    a StudyLogError names the first bad field."""
    if not isinstance(form, dict):
        raise StudyLogError(f"participant form: expected the form's fields, got {type(form).__name__}")
    unknown = sorted(set(form) - set(PARTICIPANT_FORM))
    if unknown:
        raise StudyLogError(f"participant form: unknown fields {unknown} (no name or free text is stored)")
    unanswered = [name for name in PARTICIPANT_FORM if name != "consent" and form.get(name) in (None, "")]
    if unanswered:
        fields = ", ".join(name.replace("_", " ") for name in unanswered)
        raise StudyLogError(
            f"Please choose an answer for: {fields} (“prefer not to say” is one of the choices)."
        )
    for name, choices in PARTICIPANT_FORM.items():
        value = form.get(name)
        if name == "consent" and value != "yes":
            raise StudyLogError(
                "Please tick the box to say you agree to take part (the study cannot start without it)."
            )
        if value not in choices:
            raise StudyLogError(f"participant form: {name} {value!r} is not one of {list(choices)}")
    return {name: form[name] for name in PARTICIPANT_FORM}


def _optional_number(value, name: str, where: str) -> float | None:
    return None if value is None else _number(value, name, where)


def _number(value, name: str, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise StudyLogError(f"{where}: {name} must be a finite number, got {value!r}")
    return float(value)


def _count(value, name: str, where: str) -> int | None:
    """A whole number >= 0 the page counted, or None when it did not say."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise StudyLogError(f"{where}: {name} must be a whole number >= 0, got {value!r}")
    return value


def shown_segments(
    segments, onsets_ms: Sequence, end_ms, *, time_scale: float = 1.0, frames: Sequence | None = None
) -> list[dict]:
    """Per segment of a trial's `presentation`: what it was, the protocol's duration (times
    `time_scale`; None for the slider's open-ended level), its first-drawn time on the page's
    clock, the duration it was shown (the next onset, or `end_ms` for the last, minus its own)
    and how many frames the page drew of it."""
    where = "shown segments"
    if len(onsets_ms) != len(segments):
        raise StudyLogError(f"{where}: {len(onsets_ms)} onsets for {len(segments)} segments")
    onsets = [_number(t, "onset_ms", where) for t in onsets_ms]
    end = _number(end_ms, "stimulus_end_ms", where)
    bounds = [*onsets, end]
    if any(b < a for a, b in zip(bounds, bounds[1:], strict=False)):
        raise StudyLogError(f"{where}: onsets {onsets} and end {end} are not in order")
    if frames is None:
        frames = [None] * len(segments)
    elif not isinstance(frames, list | tuple) or len(frames) != len(segments):
        raise StudyLogError(
            f"{where}: frames must be one count per segment ({len(segments)}), got {frames!r}"
        )
    else:
        frames = [_count(n, "frames", where) for n in frames]
    out = []
    for k, segment in enumerate(segments):
        protocol = None if segment.seconds is None else segment.seconds * time_scale
        out.append(
            {
                "kind": segment.kind,
                "level": None if segment.level is None else list(segment.level),
                "protocol_s": protocol,
                "onset_ms": onsets[k],
                "shown_s": (bounds[k + 1] - bounds[k]) / 1e3,
                "frames": frames[k],
            }
        )
    return out


def timing_problems(presented: Sequence[dict], frame_interval_ms: float) -> list[dict]:
    """The segments whose shown duration differs from the protocol's by more than one frame
    (`frame_interval_ms`, the page's median frame interval), each with its index and the
    difference in ms. Segments without a protocol duration (the slider's level) are not judged."""
    # A duration is two timestamps apart, each rounded by the browser: "exactly one frame off"
    # must not be flagged by that rounding (`TIMESTAMP_RESOLUTION_MS`).
    tolerance = float(frame_interval_ms) + TIMESTAMP_RESOLUTION_MS
    out = []
    for k, seg in enumerate(presented):
        if seg.get("protocol_s") is None:
            continue
        off_ms = (float(seg["shown_s"]) - float(seg["protocol_s"])) * 1e3
        if abs(off_ms) > tolerance:
            out.append({"segment": k, "kind": seg["kind"], "level": seg.get("level"), "off_ms": off_ms})
    return out


def worst_timing_ms(presented: Sequence[dict]) -> float | None:
    """The largest |shown - protocol| of a trial's segments in ms (None with nothing to judge)."""
    offs = [
        abs(float(s["shown_s"]) - float(s["protocol_s"])) * 1e3
        for s in presented
        if s.get("protocol_s") is not None
    ]
    return max(offs) if offs else None


@dataclasses.dataclass
class StudyLog:
    """One participant's session of one test, in `directory` (see the module docstring).
    `open` it (checking a resumed session's settings, reading the answers so far; nothing is
    written yet), `begin` it (the folder, the session file, a cut-off last answer dropped: done
    by the first `save_form` or `record` too), then `record` each answer as it is given."""

    directory: Path
    participant: str
    test: str
    settings: dict
    trials: list[Trial]
    answered: list[Response]
    session: str
    dropped_tail: bool = False  # a line cut off by a crash was dropped on opening
    _kept_bytes: int | None = None  # where the file is cut back to by `begin` (a dropped tail)
    _begun: bool = False

    @property
    def path(self) -> Path:
        return self.directory / f"{self.participant}_{self.test}.jsonl"

    @property
    def settings_path(self) -> Path:
        return self.directory / f"{self.participant}_{self.test}.session.json"

    @property
    def form_path(self) -> Path:
        return self.directory / f"{self.participant}.participant.json"

    @classmethod
    def open(
        cls,
        directory,
        participant: str,
        test: str,
        *,
        seed: int | None = None,
        time_scale: float = 1.0,
        levels=APPENDIX_LEVELS,
        stimulus: dict | None = None,
    ) -> StudyLog:
        """Open (or resume) `participant`'s session of `test` in `directory`. `stimulus`
        describes the clips (scene, size, spp, ...): a resumed session must show the same ones,
        with the same `seed` and `time_scale`, or it is a StudyLogError naming the difference.
        Nothing is written until `begin` (an interrupted start leaves the folder as it was)."""
        check_participant(participant)
        levels = _check_levels(levels, "StudyLog")
        if not (isinstance(time_scale, int | float) and math.isfinite(time_scale) and time_scale > 0):
            raise StudyLogError(f"time_scale must be a number > 0, got {time_scale!r}")
        trials = study_sequence_of(test, seed=seed, levels=levels)
        directory = Path(directory)
        settings = {
            "participant": participant,
            "test": test,
            "seed": seed,
            "time_scale": float(time_scale),
            "levels": [list(lv) for lv in levels],
            "trials": [t.condition for t in trials],
            "stimulus": stimulus or {},
        }
        log = cls(directory, participant, test, settings, trials, [], session="")
        log.session = datetime.datetime.now(datetime.UTC).strftime("%Y%m%dT%H%M%S.%fZ")
        if log.settings_path.exists():
            try:
                before = json.loads(log.settings_path.read_text(encoding="utf-8"))
            except (ValueError, UnicodeDecodeError) as err:
                raise StudyLogError(f"{log.settings_path}: not a session file ({err})") from None
            differ = [k for k in settings if before.get(k) != settings[k]]
            if differ:
                k = differ[0]
                raise StudyLogError(
                    f"{log.settings_path}: {participant}'s {test} session was started with {k} "
                    f"{before.get(k)!r}, not {settings[k]!r}; resume with the same settings or use "
                    "another folder"
                )
        if log.path.exists():
            raw = log.path.read_bytes()
            complete = None
            if raw and not raw.endswith(b"\n"):
                # The process died inside the write of the last answer: that line is incomplete
                # and its trial is asked again (`begin` cuts the file back to the lines before).
                keep = raw[: raw.rfind(b"\n") + 1]
                log._kept_bytes = len(keep)
                log.dropped_tail = True
                complete = sum(1 for line in keep.split(b"\n") if line.strip())
            try:
                with warnings.catch_warnings():  # the cut line: `dropped_tail` says so
                    warnings.simplefilter("ignore")
                    log.answered = read_responses(log.path, levels=levels)[:complete]
            except ResultsFileError as err:
                raise StudyLogError(str(err)) from None
            for line, (response, trial) in enumerate(zip(log.answered, trials, strict=False), 1):
                if response.participant != participant or response.trial.condition != trial.condition:
                    raise StudyLogError(
                        f"{log.path}:{line}: answer to {response.trial.condition!r} "
                        f"by {response.participant!r}, "
                        f"expected trial {trial.index} {trial.condition!r} by {participant!r}"
                    )
            if len(log.answered) > len(trials):
                raise StudyLogError(f"{log.path}: {len(log.answered)} answers for {len(trials)} trials")
        return log

    def begin(self) -> None:
        """Start writing (once; `save_form` and `record` call it): the folder, the session file
        of a new session, and a cut-off last answer cut away."""
        if self._begun:
            return
        self.directory.mkdir(parents=True, exist_ok=True)
        if not self.settings_path.exists():
            _write_json(self.settings_path, self.settings)
        if self._kept_bytes is not None:
            with self.path.open("r+b") as fh:
                fh.truncate(self._kept_bytes)
                fh.flush()
                os.fsync(fh.fileno())
            self._kept_bytes = None
        self._begun = True

    @property
    def next_index(self) -> int | None:
        """The first unanswered trial's index, None when the test is done."""
        n = len(self.answered)
        return n if n < len(self.trials) else None

    @property
    def form(self) -> dict | None:
        if not self.form_path.exists():
            return None
        try:
            return json.loads(self.form_path.read_text(encoding="utf-8"))
        except (ValueError, UnicodeDecodeError) as err:
            raise StudyLogError(f"{self.form_path}: not a participant form ({err})") from None

    def save_form(self, form) -> dict:
        """Check and store the participant form (`check_form`); returns what was stored."""
        answers = check_form(form)
        self.begin()
        _write_json(self.form_path, {"participant": self.participant, **answers})
        return answers

    def presentation_of(self, index: int, *, resumed: bool) -> tuple:
        trial = self.trials[index]
        previous = self.trials[index - 1] if index > 0 else None
        return presentation(trial, previous=previous, resumed=resumed)

    def record(self, index: int, answer: str, measured: dict, *, resumed: bool) -> dict:
        """Record the answer to trial `index` (it must be the next unanswered one): `measured`
        is what the page reports (`onsets_ms`, `stimulus_end_ms`, `answer_ms`, `time_origin_ms`,
        `frame_interval_ms`, `frames`, `frames_drawn`, `late_frames`, `slider_actions`). The
        row is appended, flushed and fsync'ed before this returns it."""
        if index != self.next_index:
            raise StudyLogError(
                f"answer to trial {index}, but the next unanswered trial is {self.next_index}"
            )
        trial = self.trials[index]
        where = f"answer to trial {index}"
        actions = measured.get("slider_actions")
        if trial.test == "slider":
            if not isinstance(actions, list) or not all(
                isinstance(a, dict) and isinstance(a.get("action"), str) for a in actions
            ):
                raise StudyLogError(
                    f"{where}: slider_actions must be a list of {{action, at_ms}}, got {actions!r}"
                )
            try:
                segments, shown_last = slider_presentation(trial, [a["action"] for a in actions])
            except ValueError as err:
                raise StudyLogError(f"{where}: {err}") from None
            if answer != f"{shown_last[0]:g}":
                raise StudyLogError(
                    f"{where}: the answer {answer!r} is not the level shown last ({shown_last[0]:g})"
                )
        else:
            if actions:
                raise StudyLogError(f"{where}: slider_actions in a {trial.test} trial")
            segments = self.presentation_of(index, resumed=resumed)
        end_ms = _number(measured.get("stimulus_end_ms"), "stimulus_end_ms", where)
        answer_ms = _number(measured.get("answer_ms"), "answer_ms", where)
        if answer_ms < end_ms:
            raise StudyLogError(
                f"{where}: answered at {answer_ms} ms, before the stimulus ended at {end_ms} ms"
            )
        frame_ms = _number(measured.get("frame_interval_ms"), "frame_interval_ms", where)
        if frame_ms <= 0:
            raise StudyLogError(f"{where}: frame_interval_ms must be > 0, got {frame_ms}")
        presented = shown_segments(
            segments,
            measured.get("onsets_ms") or [],
            end_ms,
            time_scale=self.settings["time_scale"],
            frames=measured.get("frames"),
        )
        # The response time: from the stimulus's end to the answer; for the slider, from the
        # starting level's first showing (after the reference) to the choice.
        since_ms = presented[3]["onset_ms"] if trial.test == "slider" else end_ms
        response = Response(self.participant, trial, answer, (answer_ms - since_ms) / 1e3)
        problems = timing_problems(presented, frame_ms)
        row = {
            **response.row(),
            "session": self.session,
            "seed": self.settings["seed"],
            "time_scale": self.settings["time_scale"],
            "presented": presented,
            "stimulus_end_ms": end_ms,
            "answer_ms": answer_ms,
            "time_origin_ms": _optional_number(measured.get("time_origin_ms"), "time_origin_ms", where),
            "answered_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="milliseconds"),
            "frame_interval_ms": frame_ms,
            "frames_drawn": _count(measured.get("frames_drawn"), "frames_drawn", where),
            "late_frames": _count(measured.get("late_frames"), "late_frames", where),
            "timing_ok": not problems,
            "timing_worst_ms": worst_timing_ms(presented),
            "slider_actions": actions,
            "clips": self.settings["stimulus"],
        }
        self.begin()
        _fsync_write(self.path, json.dumps(row, allow_nan=False) + "\n", "a")
        self.answered.append(response)
        return row


def study_files(directory) -> list[Path]:
    """The results files in a study folder: its `*.jsonl` and `*.csv` files, sorted (the
    session and participant files are `.json`; sub-folders such as the clips are not read)."""
    directory = Path(directory)
    if not directory.is_dir():
        raise StudyLogError(f"{directory}: not a folder")
    return sorted(p for p in directory.iterdir() if p.is_file() and p.suffix in (".jsonl", ".csv"))


def read_timing(path) -> list[dict]:
    """Per answer in a results file recorded by the player (rows with `presented`): who, which
    trial, the frame interval, and the segments `timing_problems` flags. Rows without timing
    (a CSV, the automatic observers) are left out. A malformed row is a ResultsFileError with
    FILE:LINE."""
    path = Path(path)
    if path.suffix != ".jsonl":
        return []
    out = []
    with warnings.catch_warnings():  # a cut-off last line: `read_responses` says so once
        warnings.simplefilter("ignore")
        rows = jsonl_rows(path)
    for line_no, row in rows:
        where = f"{path}:{line_no}"
        if "presented" not in row:
            continue
        try:
            presented = row["presented"]
            if not isinstance(presented, list) or not all(isinstance(s, dict) for s in presented):
                raise ValueError("presented must be a list of segments")
            frame_ms = _number(row.get("frame_interval_ms"), "frame_interval_ms", where)
            problems = timing_problems(presented, frame_ms)
            worst = worst_timing_ms(presented)
        except (KeyError, TypeError, ValueError) as err:
            raise ResultsFileError(f"{where}: bad timing fields ({err})") from None
        out.append(
            {
                "file": str(path),
                "line": line_no,
                "participant": row.get("participant"),
                "test": row.get("test"),
                "trial": row.get("trial"),
                "condition": row.get("condition"),
                "time_scale": row.get("time_scale"),
                "frame_interval_ms": frame_ms,
                "worst_ms": worst,
                "flagged": bool(problems),
                "problems": "; ".join(
                    f"segment {p['segment']} ({p['kind']}) off by {p['off_ms']:+.1f} ms" for p in problems
                ),
            }
        )
    return out
