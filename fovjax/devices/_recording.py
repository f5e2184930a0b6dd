"""Recording tracking streams to files and replaying them.

File formats (one kind of sample per file, chosen by the suffix):

* **JSON lines** (``.jsonl``): the first line is a header object
  ``{"fovjax_recording": 1, "kind": "gaze" | "head", ...metadata}``; every further line is one
  sample with the fields of `GazeSample.as_row` (``t, device_time, lx, ly, lq, lv, rx, ry, rq,
  rv``) or `HeadPose.as_row` (``t, device_time, yaw, pitch, roll, valid``). NaN is written as
  ``null``.
* **CSV** (``.csv``): optional ``#`` comment lines (the recorder writes the same header object as
  ``# {...}``), then a header row with those field names, then one sample per row; NaN is empty,
  booleans are ``1``/``0``.

``t`` is the sample timestamp on the recording source's clock (``time.monotonic`` seconds unless
the header's ``clock`` says otherwise).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import signal
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from ._paced import PacedSource
from ._samples import GazeSample, HeadPose
from ._source import Clock, Source, ThreadedSource

FORMAT_VERSION = 1
FIELDS = {
    "gaze": ("t", "device_time", "lx", "ly", "lq", "lv", "rx", "ry", "rq", "rv"),
    "head": ("t", "device_time", "yaw", "pitch", "roll", "valid"),
}
_BOOL_FIELDS = {"lv", "rv", "valid"}
_SAMPLE_TYPES = {"gaze": GazeSample, "head": HeadPose}


def _format_of(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in (".jsonl", ".ndjson"):
        return "jsonl"
    if suffix == ".csv":
        return "csv"
    raise ValueError(f"{path}: unknown recording format {suffix!r} (use .jsonl or .csv)")


def _kind_of(sample) -> str:
    if isinstance(sample, GazeSample):
        return "gaze"
    if isinstance(sample, HeadPose):
        return "head"
    raise ValueError(f"not a tracking sample: {type(sample).__name__}")


class Recorder:
    """Write samples of one kind to a ``.jsonl`` or ``.csv`` file, one line each.

    Every `write` goes straight to the file and, with the default ``flush_every=1``, is flushed to
    the OS at once, so a crash or an interrupt loses nothing already written; `close` (also on
    leaving a ``with`` block, including by an exception) flushes and fsyncs.
    """

    def __init__(
        self, path: str | os.PathLike, kind: str, *, metadata: dict | None = None, flush_every: int = 1
    ):
        if kind not in FIELDS:
            raise ValueError(f"Recorder({path}): kind must be 'gaze' or 'head', got {kind!r}")
        if flush_every < 1:
            raise ValueError(f"Recorder({path}): flush_every must be >= 1, got {flush_every}")
        self.path = Path(path)
        self.kind = kind
        self.format = _format_of(self.path)
        self.flush_every = flush_every
        self.count = 0
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "w", newline="", encoding="utf-8")
        header = {"fovjax_recording": FORMAT_VERSION, "kind": kind, "clock": "time.monotonic"}
        header.update(metadata or {})
        if self.format == "jsonl":
            self._file.write(json.dumps(header, allow_nan=False) + "\n")
            self._csv = None
        else:
            self._file.write("# " + json.dumps(header, allow_nan=False) + "\n")
            self._csv = csv.writer(self._file, lineterminator="\n")
            self._csv.writerow(FIELDS[kind])
        self._file.flush()

    def write(self, sample: GazeSample | HeadPose) -> None:
        kind = _kind_of(sample)
        if kind != self.kind:
            raise ValueError(f"Recorder({self.path}): got a {kind} sample in a {self.kind} recording")
        row = sample.as_row()
        if self.format == "jsonl":
            clean = {
                k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in row.items()
            }
            self._file.write(json.dumps(clean, allow_nan=False) + "\n")
        elif self._csv is None:
            raise ValueError(f"Recorder({self.path}): closed")
        else:
            self._csv.writerow([_csv_cell(row[name]) for name in FIELDS[self.kind]])
        self.count += 1
        if self.count % self.flush_every == 0:
            self._file.flush()

    def write_all(self, samples: Iterable[GazeSample | HeadPose]) -> None:
        for sample in samples:
            self.write(sample)

    def close(self) -> None:
        if not self._file.closed:
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _csv_cell(value) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return str(value)


@dataclass
class RecordingSummary:
    path: Path
    samples: int
    interrupted: bool
    first_timestamp: float = math.nan
    last_timestamp: float = math.nan
    source_status: dict = field(default_factory=dict)


def record(
    source: Source,
    path: str | os.PathLike,
    *,
    seconds: float | None = None,
    max_samples: int | None = None,
    metadata: dict | None = None,
    reraise: bool = False,
    on_sample: Callable[[GazeSample | HeadPose], None] | None = None,
) -> RecordingSummary:
    """Write every sample of `source` to `path` until `seconds` of sample time have passed,
    `max_samples` were written, the source ends, or the user interrupts. A source fed by a
    device (a `ThreadedSource`) is also stopped after `seconds` of wall time since the start,
    even when nothing arrives.

    Interrupts lose nothing. Called from the main thread, SIGINT (Ctrl-C) is turned into a stop
    request for the duration of the call, so the sample being written is finished and no sample is
    taken from the source without being written; a KeyboardInterrupt raised some other way (e.g.
    by `on_sample`) is caught as well. Either way the samples the source already received but not
    yet handed out are drained and written, the file is flushed and fsynced, and the summary says
    ``interrupted=True`` (with `reraise`, KeyboardInterrupt is raised again afterwards).
    """
    source.open()
    wall_deadline = None
    if seconds is not None and isinstance(source, ThreadedSource):
        wall_deadline = time.monotonic() + seconds
    stop = threading.Event()
    previous_handler = None
    if threading.current_thread() is threading.main_thread():
        previous_handler = signal.signal(signal.SIGINT, lambda signum, frame: stop.set())
    interrupted = False
    first = last = math.nan
    try:
        with Recorder(path, source.kind, metadata=metadata) as recorder:
            try:
                while not stop.is_set():
                    if wall_deadline is not None and time.monotonic() >= wall_deadline:
                        break
                    sample = source.read(timeout=0.1)
                    if sample is None:
                        if source.exhausted:
                            break
                        continue
                    recorder.write(sample)
                    if math.isnan(first):
                        first = sample.timestamp
                    last = sample.timestamp
                    if on_sample is not None:
                        on_sample(sample)
                    if max_samples is not None and recorder.count >= max_samples:
                        break
                    if seconds is not None and sample.timestamp - first >= seconds:
                        break
            except KeyboardInterrupt:
                interrupted = True
            if stop.is_set():
                interrupted = True
            if interrupted:
                for sample in source.drain():
                    recorder.write(sample)
                    if math.isnan(first):
                        first = sample.timestamp
                    last = sample.timestamp
            count = recorder.count
    finally:
        if previous_handler is not None:
            signal.signal(signal.SIGINT, previous_handler)
    if interrupted and reraise:
        raise KeyboardInterrupt
    return RecordingSummary(Path(path), count, interrupted, first, last, dict(vars(source.status)))


@dataclass(frozen=True)
class Recording:
    kind: str
    samples: tuple
    metadata: dict

    def __len__(self) -> int:
        return len(self.samples)


def _parse_value(name: str, value, where: str) -> float | bool:
    if name in _BOOL_FIELDS:
        if isinstance(value, bool):
            return value
        if value in ("1", "true", "True", 1):
            return True
        if value in ("0", "false", "False", 0):
            return False
        raise ValueError(f"{where}: field {name}={value!r} is not a boolean")
    if value is None or value == "":
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: field {name}={value!r} is not a number") from None


def load_recording(path: str | os.PathLike) -> Recording:
    """Read a ``.jsonl`` or ``.csv`` recording. Errors name the file, line and field."""
    path = Path(path)
    fmt = _format_of(path)
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise ValueError(
            f"{path}:{line}: not a text recording (byte 0x{raw[exc.start]:02x} is not UTF-8)"
        ) from None
    metadata: dict = {}
    rows: list[tuple[int, dict]] = []
    if fmt == "jsonl":
        for lineno, line in enumerate(text.splitlines(), start=1):
            if not line.strip():
                continue
            try:
                obj = json.loads(line)
            except json.JSONDecodeError as exc:
                raise ValueError(f"{path}:{lineno}: not JSON ({exc.msg})") from None
            if not isinstance(obj, dict):
                raise ValueError(f"{path}:{lineno}: expected an object, got {type(obj).__name__}")
            if "fovjax_recording" in obj:
                metadata = obj
                continue
            rows.append((lineno, obj))
    else:
        lines = text.splitlines()
        body_start = 0
        for i, line in enumerate(lines):
            if line.startswith("#"):
                body = line[1:].strip()
                if body.startswith("{"):
                    try:
                        metadata = json.loads(body)
                    except json.JSONDecodeError as exc:
                        raise ValueError(f"{path}:{i + 1}: header comment is not JSON ({exc.msg})") from None
                body_start = i + 1
            else:
                break
        reader = csv.DictReader(io.StringIO("\n".join(lines[body_start:])))
        for offset, row in enumerate(reader):
            rows.append((body_start + 2 + offset, row))
    kind = metadata.get("kind")
    if kind is None:
        keys = set(rows[0][1]) if rows else set()
        kind = "gaze" if "lx" in keys else "head" if "yaw" in keys else None
    if kind not in FIELDS:
        raise ValueError(f"{path}: cannot tell whether this is a gaze or a head recording (kind={kind!r})")
    samples = []
    previous = -math.inf
    for lineno, row in rows:
        where = f"{path}:{lineno}"
        missing = [name for name in FIELDS[kind] if name not in row and name != "device_time"]
        if missing:
            raise ValueError(f"{where}: missing field(s) {', '.join(missing)}")
        parsed = {name: _parse_value(name, row.get(name), where) for name in FIELDS[kind] if name in row}
        if not math.isfinite(parsed["t"]):
            raise ValueError(f"{where}: field t={row['t']!r} is not a finite timestamp")
        if parsed["t"] < previous:
            raise ValueError(f"{where}: field t={parsed['t']} goes back in time (previous {previous})")
        previous = parsed["t"]
        samples.append(_SAMPLE_TYPES[kind].from_row(parsed))
    return Recording(kind, tuple(samples), metadata)


class ReplaySource(PacedSource):
    """Replay a recording (a path or a loaded `Recording`).

    ``speed=1.0`` replays in real time on `clock` (``time.monotonic``), ``speed=2.0`` twice as fast,
    ``speed=None`` as fast as it is read with the recorded timestamps untouched. With pacing each
    sample is re-stamped with the time it is released (``t0 + (t_i - t_first) / speed``). ``loop``
    repeats the recording forever, each pass starting one median sample interval after the last.
    """

    def __init__(
        self,
        recording: Recording | str | os.PathLike,
        *,
        speed: float | None = 1.0,
        loop: bool = False,
        clock: Clock = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ):
        self.path = None if isinstance(recording, Recording) else Path(recording)
        if not isinstance(recording, Recording):
            recording = load_recording(recording)
        if not recording.samples:
            raise ValueError(f"ReplaySource: the recording has no samples ({recording.metadata})")
        first = recording.samples[0].timestamp
        super().__init__(speed=speed, clock=clock, sleep=sleep, start_time=first)
        self.recording = recording
        self.kind = recording.kind
        self.loop = loop
        self._offsets = [s.timestamp - first for s in recording.samples]
        n = len(self._offsets)
        if n > 1:
            gaps = sorted(b - a for a, b in zip(self._offsets, self._offsets[1:], strict=False))
            step = gaps[len(gaps) // 2]
        else:
            step = 0.0
        self._period = self._offsets[-1] + (step if step > 0 else 1e-3)

    def describe(self) -> str:
        return "a recording" if self.path is None else f"recording {self.path}"

    def _count(self) -> int | None:
        return None if self.loop else len(self._offsets)

    def _offset(self, i: int) -> float:
        n = len(self._offsets)
        return self._offsets[i % n] + (i // n) * self._period

    def _sample(self, i: int, timestamp: float):
        return self.recording.samples[i % len(self._offsets)].with_timestamp(timestamp)
