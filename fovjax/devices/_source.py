"""What every tracking source is: an iterator of timestamped samples with open/close, a context
manager, a non-blocking `latest()`, and a stated clock.

Two families share this interface:

* **Pull sources** (replay, synthetic) produce samples when asked; with pacing they release each
  sample at its due time on `clock`, without pacing they return samples as fast as they are read.
* **Threaded sources** (serial, Pupil, ViewPoint, InterSense) run one background reader thread that
  connects, reads, and on any error disconnects and reconnects with exponential back-off. Samples go
  into a FIFO buffer: `read()`/iteration return every buffered sample in order, `latest()` returns
  the newest without consuming anything, `drain()` empties the buffer without blocking (what a
  recorder does on an interrupt so nothing received is lost).
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Generic, TypeVar, cast, overload

from ._samples import GazeSample, HeadPose

S = TypeVar("S", GazeSample, HeadPose)

Clock = Callable[[], float]


class DeviceError(RuntimeError):
    """A tracking device or its library could not be used."""


# Seconds `source_from_spec` gives a live device to connect before `open()` fails.
DEFAULT_CONNECT_TIMEOUT = 3.0


class ConnectTimeoutError(DeviceError):
    """A live device did not connect within its connect timeout."""


class LibraryNotFoundError(DeviceError, FileNotFoundError):
    """A vendor SDK library (ViewPoint, InterSense) is not present where it was looked for."""


@dataclass
class SourceStatus:
    """Counters and connection state of a source, safe to read from any thread."""

    connected: bool = False
    samples: int = 0
    dropped: int = 0
    connects: int = 0
    disconnects: int = 0
    errors: int = 0
    last_error: str = ""
    extra: dict[str, int] = field(default_factory=dict)


class Source(Generic[S]):
    """Base class of all sources. Subclasses implement `_open`, `_close`, `read`, `latest`.

    `correction` (a gaze source's; None by default): a `GazeCorrection`, e.g. a calibration's
    (`calibrate`), applied to every sample read from the source from then on (`read`,
    iteration, `latest`, `drain`).
    """

    kind: str = "gaze"

    def __init__(self, *, clock: Clock = time.monotonic):
        self.clock = clock
        self.status = SourceStatus()
        # The spec this source was built from (`source_from_spec`), for messages; None otherwise.
        self.spec: str | None = None
        self._opened = False
        self._closed = False
        self._correction = None

    @property
    def correction(self):
        """The `GazeCorrection` applied to the samples read from now on, or None."""
        return self._correction

    @correction.setter
    def correction(self, correction) -> None:
        from ._correction import GazeCorrection

        if correction is not None and not isinstance(correction, GazeCorrection):
            raise TypeError(
                f"{type(self).__name__}.correction must be a fovjax.devices.GazeCorrection or None, "
                f"got {type(correction).__name__}"
            )
        if correction is not None and self.kind != "gaze":
            raise ValueError(
                f"{type(self).__name__}: a gaze correction applies to gaze sources, not {self.kind}"
            )
        self._correction = correction

    @overload
    def _corrected(self, sample: S) -> S: ...
    @overload
    def _corrected(self, sample: None) -> None: ...
    def _corrected(self, sample: S | None) -> S | None:
        """`sample` with the source's correction applied (None, a head pose, or no correction: as
        it is)."""
        correction = self._correction
        if correction is None or not isinstance(sample, GazeSample):
            return sample
        return cast(S, correction.apply(sample))

    # -- lifecycle -------------------------------------------------------------------------
    def _open(self) -> None:
        """Connect (a subclass's)."""
        raise NotImplementedError(f"{type(self).__name__} does not implement _open")

    def _close(self) -> None:
        """Disconnect (a subclass's)."""
        raise NotImplementedError(f"{type(self).__name__} does not implement _close")

    def open(self):
        if self._closed:
            raise DeviceError(f"{type(self).__name__}: cannot reopen a closed source; make a new one")
        if not self._opened:
            self._open()
            self._opened = True
        return self

    def close(self) -> None:
        if self._opened and not self._closed:
            self._closed = True
            self._close()
        self._closed = True

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def is_open(self) -> bool:
        return self._opened and not self._closed

    def describe(self) -> str:
        """The device (or file) this source reads, for messages: e.g. "serial port /dev/ttyUSB0"."""
        return type(self).__name__

    def _name(self) -> str:
        """Spec and device, for messages."""
        device = self.describe()
        return device if self.spec is None else f"{self.spec} ({device})"

    def _require_open(self) -> None:
        if not self._opened:
            self.open()

    # -- data ------------------------------------------------------------------------------
    def read(self, timeout: float | None = None) -> S | None:
        """Next sample in order, waiting at most `timeout` seconds (None: until one comes or the
        source ends). Returns None on timeout, when closed, or when a finite source is exhausted
        (then `exhausted` is True)."""
        raise NotImplementedError

    def latest(self) -> S | None:
        """Newest sample available now, without blocking and without consuming it."""
        raise NotImplementedError

    def drain(self) -> list[S]:
        """Every sample already received but not yet read, in order, without blocking."""
        return []

    @property
    def exhausted(self) -> bool:
        """True once a finite source has nothing more to give, or the source is closed."""
        return self._closed

    def __iter__(self) -> Iterator[S]:
        self._require_open()
        while True:
            sample = self.read(timeout=0.1)
            if sample is not None:
                yield sample
            elif self.exhausted:
                return


class ThreadedSource(Source[S]):
    """A source fed by one background thread with reconnect and exponential back-off.

    Subclasses implement `_connect()` (raise on failure), `_read_some()` (return a possibly empty
    list of samples, block at most about `poll_interval`; raise on a broken connection) and
    `_disconnect()` (must not raise).

    `connect_timeout` (seconds): `open()` waits that long for the first connection and, when
    none is made, stops the reader and raises a `DeviceError` naming the source and the last
    reason the connection failed. None (the default for source objects; `source_from_spec` uses
    `DEFAULT_CONNECT_TIMEOUT`): `open()` returns at once and the reader keeps trying forever.
    """

    def __init__(
        self,
        *,
        clock: Clock = time.monotonic,
        backoff_initial: float = 0.05,
        backoff_max: float = 2.0,
        backoff_factor: float = 2.0,
        buffer_size: int = 1 << 17,
        connect_timeout: float | None = None,
    ):
        super().__init__(clock=clock)
        if connect_timeout is not None and not connect_timeout > 0:
            raise ValueError(f"{type(self).__name__}: connect_timeout must be > 0 s, got {connect_timeout}")
        self.connect_timeout = connect_timeout
        if not (backoff_initial > 0 and backoff_max >= backoff_initial and backoff_factor >= 1):
            raise ValueError(
                f"{type(self).__name__}: back-off needs 0 < initial <= max and factor >= 1, got "
                f"initial={backoff_initial}, max={backoff_max}, factor={backoff_factor}"
            )
        self.backoff_initial = backoff_initial
        self.backoff_max = backoff_max
        self.backoff_factor = backoff_factor
        self._buffer: collections.deque[S] = collections.deque(maxlen=buffer_size)
        self._cond = threading.Condition()
        self._latest: S | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._connected_event = threading.Event()

    # subclass hooks ------------------------------------------------------------------------
    def _connect(self) -> None:
        raise NotImplementedError

    def _read_some(self) -> list[S]:
        raise NotImplementedError

    def _disconnect(self) -> None:
        raise NotImplementedError

    # lifecycle -----------------------------------------------------------------------------
    def _open(self) -> None:
        self._thread = threading.Thread(target=self._loop, name=f"fovjax-{type(self).__name__}", daemon=True)
        self._thread.start()
        timeout = self.connect_timeout
        if timeout is not None and not self._connected_event.wait(timeout):
            self._close()  # joins the reader: its last attempt's error is in the status now
            self._closed = True
            reason = self.status.last_error or "no answer"
            raise ConnectTimeoutError(
                f"{self._name()}: could not connect within {timeout:g} s "
                f"({self.status.errors} attempt(s) failed); last error: {reason}"
            )

    def _close(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)

    def wait_connected(self, timeout: float) -> bool:
        """Block until the reader thread has connected once (True) or `timeout` passes (False)."""
        return self._connected_event.wait(timeout)

    def _loop(self) -> None:
        delay = self.backoff_initial
        connected = False
        while not self._stop.is_set():
            if not connected:
                try:
                    self._connect()
                except Exception as exc:  # any failure to connect is retried, never raised
                    self._note_error(exc)
                    self._stop.wait(delay)
                    delay = min(delay * self.backoff_factor, self.backoff_max)
                    continue
                connected = True
                delay = self.backoff_initial
                self.status.connected = True
                self.status.connects += 1
                self._connected_event.set()
            try:
                samples = self._read_some()
            except Exception as exc:  # a broken link: drop it, then reconnect with back-off
                self._note_error(exc)
                self._safe_disconnect()
                connected = False
                self.status.connected = False
                self.status.disconnects += 1
                self._stop.wait(delay)
                delay = min(delay * self.backoff_factor, self.backoff_max)
                continue
            for sample in samples:
                self._push(sample)
        if connected:
            self._safe_disconnect()
            self.status.connected = False

    def _safe_disconnect(self) -> None:
        try:
            self._disconnect()
        except Exception as exc:
            self._note_error(exc)

    def _note_error(self, exc: BaseException) -> None:
        self.status.errors += 1
        self.status.last_error = f"{type(exc).__name__}: {exc}"

    def _push(self, sample: S) -> None:
        with self._cond:
            if len(self._buffer) == self._buffer.maxlen:
                self.status.dropped += 1
            self._buffer.append(sample)
            self._latest = sample
            self.status.samples += 1
            self._cond.notify_all()

    # data ----------------------------------------------------------------------------------
    def read(self, timeout: float | None = None) -> S | None:
        self._require_open()
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while not self._buffer:
                if self._stop.is_set():
                    return None
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                self._cond.wait(0.1 if remaining is None else min(remaining, 0.1))
            sample = self._buffer.popleft()
        return self._corrected(sample)

    def latest(self) -> S | None:
        with self._cond:
            sample = self._latest
        return self._corrected(sample)

    def drain(self) -> list[S]:
        with self._cond:
            out = list(self._buffer)
            self._buffer.clear()
        return [self._corrected(sample) for sample in out]

    @property
    def exhausted(self) -> bool:
        return self._stop.is_set()
