"""Serial-port source speaking the fovjax line protocol (see `fovjax.devices._protocol`)."""

from __future__ import annotations

import time

from ._protocol import LineParser
from ._samples import GazeSample, HeadPose
from ._source import Clock, DeviceError, ThreadedSource


class SerialSource(ThreadedSource):
    """Gaze (``kind="gaze"``) or head-pose (``kind="head"``) samples from a serial port.

    `port` is a device path (``/dev/ttyUSB0``, ``COM3``, a pty) or any pyserial URL
    (``socket://host:port``, ``loop://``). One background thread opens the port, reads whatever
    bytes are there (waiting at most `read_timeout` s per read), and parses complete lines. Lines of
    the other kind are counted in ``status.extra["other_kind"]`` and skipped, so one wire may carry
    both streams for two readers of a splitter, but one port can be opened only once.

    On any I/O error (unplugged adapter, closed pty, vanished device) the port is closed and
    reopened with exponential back-off from `backoff_initial` to `backoff_max` seconds; a partial
    line from before the break is discarded. Timestamps are `clock()` at the read that completed
    the line (``time.monotonic`` by default); the sender's ``t`` is kept as ``device_time``.
    """

    def __init__(
        self,
        port: str,
        *,
        kind: str = "gaze",
        baudrate: int = 115200,
        read_timeout: float = 0.05,
        write_timeout: float = 0.5,
        clock: Clock = time.monotonic,
        backoff_initial: float = 0.05,
        backoff_max: float = 2.0,
        serial_options: dict | None = None,
        connect_timeout: float | None = None,
    ):
        super().__init__(
            clock=clock,
            backoff_initial=backoff_initial,
            backoff_max=backoff_max,
            connect_timeout=connect_timeout,
        )
        if kind not in ("gaze", "head"):
            raise ValueError(f"SerialSource: kind must be 'gaze' or 'head', got {kind!r}")
        if baudrate <= 0:
            raise ValueError(f"SerialSource: baudrate must be positive, got {baudrate}")
        if not read_timeout > 0:
            raise ValueError(f"SerialSource: read_timeout must be > 0 s, got {read_timeout}")
        self.kind = kind
        self.port = port
        self.baudrate = baudrate
        self.read_timeout = read_timeout
        self.write_timeout = write_timeout
        self.serial_options = dict(serial_options or {})
        self.parser = LineParser(clock)
        self._serial = None
        self._want = GazeSample if kind == "gaze" else HeadPose
        self.status.extra["other_kind"] = 0

    def describe(self) -> str:
        return f"serial port {self.port}"

    def _connect(self) -> None:
        import serial  # pyserial, a core dependency

        self._serial = serial.serial_for_url(
            self.port,
            baudrate=self.baudrate,
            timeout=self.read_timeout,
            write_timeout=self.write_timeout,
            **self.serial_options,
        )
        self.parser.reset()

    def _read_some(self) -> list:
        ser = self._serial
        if ser is None:
            raise DeviceError(f"{self.describe()}: the port is not open (open the source first)")
        # Block for the first byte (up to read_timeout), then take whatever else is waiting.
        chunk = ser.read(1)
        waiting = ser.in_waiting
        if waiting:
            chunk += ser.read(waiting)
        if not chunk:
            return []
        out = []
        for message in self.parser.feed(chunk):
            if isinstance(message, self._want):
                out.append(message)
            else:
                self.status.extra["other_kind"] += 1
        return out

    def _disconnect(self) -> None:
        ser, self._serial = self._serial, None
        if ser is not None:
            ser.close()

    @property
    def rejected(self) -> dict[str, int]:
        """Rejected lines by reason: garbage, checksum, format, overlong."""
        return dict(self.parser.rejected)
