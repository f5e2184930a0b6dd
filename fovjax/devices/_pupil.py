"""Pupil Core network API source (optional extra ``pupil``: pyzmq + msgpack).

Protocol followed (Pupil Labs' "Network API" documentation): Pupil Remote is a ZeroMQ REP socket
(default port 50020). A REQ socket sends the string ``SUB_PORT`` and receives the IPC backbone's
SUB port as a string; a SUB socket connected to ``tcp://host:SUB_PORT`` and subscribed to the topic
prefix ``gaze.`` then receives multipart messages ``[topic, msgpack payload, *raw frames]``. A gaze
datum has ``topic`` (``gaze.3d.01.`` binocular, ``gaze.3d.0.`` / ``gaze.3d.1.`` monocular from eye
0 = right / eye 1 = left; ``gaze.2d.*`` likewise), ``norm_pos`` [x, y] in normalised coordinates of
the world (here: display) image with its origin at the **bottom-left**, ``confidence`` in [0, 1]
and ``timestamp`` in Pupil time.

Mapping to `GazeSample`: ``(x, y) -> (x, 1 - y)`` (top-left origin), ``confidence`` as is,
``timestamp`` kept as ``device_time``; the sample's ``timestamp`` is `clock()` on receipt. A
binocular datum gives both eyes the same point. A monocular datum is, in Pupil's model, still a
point in the one shared world/display image, so by default (``monocular="both"``) it also sets
both eyes; with ``monocular="own"`` it sets only its own eye and marks the other not tracked.
The datum is assumed to be calibrated to the display (as Pupil's HMD integration does); nothing
else is remapped.
"""

from __future__ import annotations

import math
import socket
import time

from ._samples import MISSING_EYE, EyeGaze, GazeSample
from ._source import Clock, DeviceError, ThreadedSource


def _require_pupil_extra():
    try:
        import msgpack
        import zmq
    except ImportError as exc:
        raise DeviceError(
            f"PupilSource needs the optional extra 'pupil' (pyzmq and msgpack): "
            f"pip install 'fovjax[pupil]' ({exc})"
        ) from exc
    return zmq, msgpack


def gaze_from_pupil_datum(datum: dict, receive_time: float, monocular: str = "both") -> GazeSample:
    """Map one decoded Pupil gaze datum to a `GazeSample` (see the module docstring).

    Raises ValueError naming the field when the datum lacks ``norm_pos`` or ``confidence`` or they
    have the wrong shape.
    """
    try:
        nx, ny = (float(v) for v in datum["norm_pos"])
        confidence = float(datum["confidence"])
    except KeyError as exc:
        raise ValueError(
            f"Pupil gaze datum has no field {exc.args[0]!r} (topic {datum.get('topic')!r})"
        ) from None
    except (TypeError, ValueError):
        raise ValueError(
            f"Pupil gaze datum field norm_pos={datum.get('norm_pos')!r} / "
            f"confidence={datum.get('confidence')!r} is not numeric [x, y] / number"
        ) from None
    tracked = math.isfinite(nx) and math.isfinite(ny) and math.isfinite(confidence)
    eye = EyeGaze(nx, 1.0 - ny, confidence if tracked else 0.0, tracked)
    topic = str(datum.get("topic", ""))
    parts = topic.rstrip(".").split(".")
    eye_ids = parts[-1] if len(parts) >= 3 else "01"
    device_time = float(datum.get("timestamp", math.nan))
    if monocular == "own" and eye_ids in ("0", "1"):
        # Pupil eye 0 is the right eye, eye 1 the left.
        if eye_ids == "0":
            return GazeSample(receive_time, MISSING_EYE, eye, device_time)
        return GazeSample(receive_time, eye, MISSING_EYE, device_time)
    return GazeSample(receive_time, eye, eye, device_time)


class PupilSource(ThreadedSource):
    """Gaze from Pupil Capture / Pupil Service over its network API.

    `host`/`port` address Pupil Remote (REQ/REP, default 50020). `request_timeout` bounds the wait
    for the ``SUB_PORT`` reply; `poll_interval` the wait for one gaze message. A silent or vanished
    Pupil never raises here: the reader reconnects with back-off and the gaze simply goes stale.
    """

    kind = "gaze"

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 50020,
        *,
        topic: str = "gaze.",
        monocular: str = "both",
        request_timeout: float = 2.0,
        poll_interval: float = 0.05,
        silence_timeout: float | None = None,
        clock: Clock = time.monotonic,
        backoff_initial: float = 0.1,
        backoff_max: float = 2.0,
        connect_timeout: float | None = None,
    ):
        super().__init__(
            clock=clock,
            backoff_initial=backoff_initial,
            backoff_max=backoff_max,
            connect_timeout=connect_timeout,
        )
        if monocular not in ("both", "own"):
            raise ValueError(f"PupilSource: monocular must be 'both' or 'own', got {monocular!r}")
        self.host = host
        self.port = int(port)
        self.topic = topic
        self.monocular = monocular
        self.request_timeout = request_timeout
        self.poll_interval = poll_interval
        # With a silence timeout, a connection quiet for that long is torn down and rebuilt (the
        # SUB port can change when Pupil Capture restarts).
        self.silence_timeout = silence_timeout
        self._zmq, self._msgpack = _require_pupil_extra()
        self._ctx = None
        self._sub = None
        self._last_message = 0.0
        self.sub_port: int | None = None
        self.status.extra["bad_messages"] = 0

    def describe(self) -> str:
        return f"Pupil Remote at {self.host}:{self.port}"

    def _connect(self) -> None:
        zmq = self._zmq
        try:
            socket.getaddrinfo(self.host, self.port, type=socket.SOCK_STREAM)
        except OSError as exc:
            raise DeviceError(f"cannot resolve the host name {self.host!r} ({exc})") from None
        if self._ctx is None:
            self._ctx = zmq.Context()
        req = self._ctx.socket(zmq.REQ)
        req.setsockopt(zmq.LINGER, 0)
        try:
            req.connect(f"tcp://{self.host}:{self.port}")
            req.send_string("SUB_PORT")
            if not req.poll(int(self.request_timeout * 1000)):
                raise DeviceError(
                    f"Pupil Remote at {self.host}:{self.port} did not answer SUB_PORT within "
                    f"{self.request_timeout} s"
                )
            reply = req.recv_string()
        finally:
            req.close()
        try:
            self.sub_port = int(reply)
        except ValueError:
            raise DeviceError(f"Pupil Remote answered SUB_PORT with {reply!r}, not a port number") from None
        sub = self._ctx.socket(zmq.SUB)
        sub.setsockopt(zmq.LINGER, 0)
        sub.connect(f"tcp://{self.host}:{self.sub_port}")
        sub.setsockopt_string(zmq.SUBSCRIBE, self.topic)
        self._sub = sub
        self._last_message = time.monotonic()

    def _read_some(self) -> list[GazeSample]:
        zmq = self._zmq
        sub = self._sub
        if sub is None:
            raise DeviceError(f"{self.describe()}: not subscribed (open the source first)")
        if not sub.poll(int(self.poll_interval * 1000)):
            if (
                self.silence_timeout is not None
                and time.monotonic() - self._last_message > self.silence_timeout
            ):
                raise DeviceError(f"no Pupil message for {self.silence_timeout} s")
            return []
        out = []
        while True:
            try:
                frames = sub.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                break
            self._last_message = time.monotonic()
            now = self.clock()
            try:
                if len(frames) < 2:
                    raise ValueError(f"expected [topic, payload] frames, got {len(frames)} frame(s)")
                datum = self._msgpack.unpackb(frames[1], raw=False)
                if not isinstance(datum, dict):
                    raise ValueError(f"payload is a {type(datum).__name__}, not a map")
                datum.setdefault("topic", frames[0].decode("utf-8", "replace"))
                out.append(gaze_from_pupil_datum(datum, now, self.monocular))
            except Exception as exc:  # one bad message must not stop the stream
                self.status.extra["bad_messages"] += 1
                self._note_error(exc)
        return out

    def _disconnect(self) -> None:
        sub, self._sub = self._sub, None
        if sub is not None:
            sub.close()

    def _close(self) -> None:
        super()._close()
        if self._ctx is not None:
            self._ctx.term()
            self._ctx = None
