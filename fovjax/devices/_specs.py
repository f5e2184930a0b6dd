"""Open a source from a short text spec, as the command line writes it.

Gaze specs::

    synthetic:scanpath[:SEED]      fixations and main-sequence saccades (seed 0 by default)
                                   (synthetic gaze: 120 Hz and noise-free unless `rate` is given,
                                   an idealised tracker; the thesis's ran at 60/30 Hz, 0.25-1° accuracy)
    synthetic:fixed[:X,Y]          one fixed point (default the display centre)
    synthetic:pursuit              smooth pursuit around the display centre
    replay:FILE[@SPEED]            a .jsonl/.csv recording, real time or SPEED x ("fast": unpaced)
    serial:PORT[@BAUD]             the fovjax line protocol on a serial port / pyserial URL
    pupil:HOST:PORT                Pupil Remote (the 'pupil' extra)
    viewpoint[:LIBRARY][@raw]      ViewPoint SDK library; its smoothed gaze point (as the thesis),
                                   or with @raw the unfiltered one (@smoothed: the default, said)
Head specs: ``synthetic:sway``, ``replay:FILE``, ``serial:PORT[@BAUD]``, ``intersense[:LIBRARY]``.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

from ._source import DEFAULT_CONNECT_TIMEOUT, Clock, Source, ThreadedSource


def source_from_spec(
    spec: str,
    kind: str = "gaze",
    *,
    duration: float | None = None,
    clock: Clock = time.monotonic,
    rate: float | None = None,
    paced: bool = True,
    dropouts: tuple[tuple[float, float], ...] = (),
    connect_timeout: float | None = DEFAULT_CONNECT_TIMEOUT,
) -> Source:
    """Build (not open) the source a spec names; ValueError says which part of the spec is wrong.

    `duration` and `rate` apply to synthetic sources; ``paced=False`` makes synthetic and replay
    sources unpaced (as fast as read, timestamps on their own timeline); `dropouts` are silent
    intervals of a synthetic gaze source. `connect_timeout`: seconds a live device (serial,
    Pupil, InterSense) gets to connect when opened before `open()` raises a `DeviceError` naming
    the spec, the device and the reason (None: keep trying in the background forever)."""
    source = _build(spec, kind, duration, clock, rate, paced, dropouts, connect_timeout)
    source.spec = spec
    if isinstance(source, ThreadedSource):
        source.connect_timeout = connect_timeout
    return source


def _build(spec, kind, duration, clock, rate, paced, dropouts, connect_timeout) -> Source:
    if not isinstance(spec, str):
        raise ValueError(f"source spec must be text such as 'replay:FILE', got {spec!r}")
    if connect_timeout is not None and not connect_timeout > 0:
        raise ValueError(f"source spec {spec!r}: the connect timeout must be > 0 s, got {connect_timeout}")
    if dropouts and not spec.startswith("synthetic:"):
        raise ValueError(f"source spec {spec!r}: dropouts apply to synthetic gaze sources only")
    if kind not in ("gaze", "head"):
        raise ValueError(f"source_from_spec: kind must be 'gaze' or 'head', got {kind!r}")
    scheme, _, rest = spec.partition(":")
    if scheme.startswith("viewpoint@"):  # viewpoint@raw: the default library, a reading chosen
        scheme, rest = "viewpoint", scheme[len("viewpoint") :]
    if scheme == "synthetic":
        from ._synthetic import (
            DEFAULT_GAZE_RATE,
            FixedPoints,
            Scanpath,
            SmoothPursuit,
            SyntheticGazeSource,
            SyntheticHeadSource,
        )

        model_name, _, arg = rest.partition(":")
        if kind == "head":
            if model_name not in ("sway", ""):
                raise ValueError(f"source spec {spec!r}: synthetic head model must be 'sway'")
            if dropouts:
                raise ValueError(f"source spec {spec!r}: dropouts apply to synthetic gaze sources only")
            return SyntheticHeadSource(
                duration=duration, clock=clock, rate=rate or 180.0, speed=1.0 if paced else None
            )
        if model_name == "scanpath":
            try:
                seed = int(arg) if arg else 0
            except ValueError:
                raise ValueError(f"source spec {spec!r}: scanpath seed {arg!r} is not an integer") from None
            if seed < 0:
                raise ValueError(f"source spec {spec!r}: scanpath seed {arg!r} must be >= 0")
            model = Scanpath(seed)
        elif model_name == "fixed":
            try:
                point = tuple(float(v) for v in arg.split(",")) if arg else (0.5, 0.5)
            except ValueError:
                raise ValueError(f"source spec {spec!r}: fixed point {arg!r} is not X,Y") from None
            if len(point) != 2 or not all(math.isfinite(v) for v in point):
                raise ValueError(f"source spec {spec!r}: fixed point needs two finite numbers X,Y")
            model = FixedPoints([point])
        elif model_name == "pursuit":
            model = SmoothPursuit()
        else:
            raise ValueError(
                f"source spec {spec!r}: unknown synthetic gaze model {model_name!r} "
                "(scanpath, fixed, pursuit)"
            )
        return SyntheticGazeSource(
            model,
            duration=duration,
            clock=clock,
            rate=rate or DEFAULT_GAZE_RATE,
            speed=1.0 if paced else None,
            dropouts=dropouts,
        )
    if scheme == "replay":
        from ._recording import ReplaySource

        path, _, speed_text = rest.partition("@")
        if not path:
            raise ValueError(f"source spec {spec!r}: replay needs a file, replay:FILE")
        if not Path(path).is_file():
            raise ValueError(f"source spec {spec!r}: no such recording file {path}")
        if speed_text in ("", "1"):
            speed = 1.0
        elif speed_text == "fast":
            speed = None
        else:
            try:
                speed = float(speed_text)
            except ValueError:
                speed = math.nan
            if not (math.isfinite(speed) and speed > 0):
                raise ValueError(
                    f"source spec {spec!r}: replay speed {speed_text!r} is not a number > 0 or 'fast'"
                )
        source = ReplaySource(path, speed=speed if paced else None, clock=clock)
        if source.kind != kind:
            raise ValueError(f"source spec {spec!r}: {path} is a {source.kind} recording, not {kind}")
        return source
    if scheme == "serial":
        from ._serial import SerialSource

        port, _, baud = rest.partition("@")
        if not port:
            raise ValueError(f"source spec {spec!r}: serial needs a port, serial:PORT[@BAUD]")
        try:
            baudrate = int(baud) if baud else 115200
        except ValueError:
            baudrate = 0
        if baudrate <= 0:
            raise ValueError(f"source spec {spec!r}: baud rate {baud!r} is not a whole number > 0")
        return SerialSource(port, kind=kind, baudrate=baudrate, clock=clock)
    if scheme == "pupil":
        if kind != "gaze":
            raise ValueError(f"source spec {spec!r}: Pupil gives gaze, not {kind}")
        from ._pupil import PupilSource

        if ":" in rest:
            host, _, port = rest.rpartition(":")
        elif rest.isdigit():  # pupil:PORT on this machine
            host, port = "", rest
        else:
            host, port = rest, ""
        try:
            port_number = int(port) if port else 50020
        except ValueError:
            port_number = 0
        if not 0 < port_number < 65536:
            raise ValueError(
                f"source spec {spec!r}: Pupil port {port!r} is not a port number 1..65535 "
                "(pupil:HOST:PORT, pupil:HOST or pupil:PORT)"
            )
        labels = host.split(".")
        if host and ":" not in host and not all(p and p.replace("-", "").isalnum() for p in labels):
            raise ValueError(f"source spec {spec!r}: {host!r} is not a host name or IPv4 address")
        request_timeout = 2.0 if connect_timeout is None else min(2.0, connect_timeout)
        return PupilSource(host or "127.0.0.1", port_number, clock=clock, request_timeout=request_timeout)
    if scheme == "viewpoint":
        if kind != "gaze":
            raise ValueError(f"source spec {spec!r}: ViewPoint gives gaze, not {kind}")
        from ._viewpoint import ViewPointSource

        library, at, reading = rest.rpartition("@")
        if not at:
            library, reading = rest, "smoothed"
        if reading not in ("smoothed", "raw"):
            raise ValueError(
                f"source spec {spec!r}: ViewPoint reading {reading!r} is not 'smoothed' or 'raw' "
                "(viewpoint[:LIBRARY][@smoothed|@raw])"
            )
        return ViewPointSource(library or None, smoothed=reading == "smoothed", clock=clock)
    if scheme == "intersense":
        if kind != "head":
            raise ValueError(f"source spec {spec!r}: InterSense gives head pose, not {kind}")
        from ._intersense import InterSenseSource

        return InterSenseSource(rest or None, clock=clock)
    raise ValueError(
        f"source spec {spec!r}: unknown scheme {scheme!r} "
        "(synthetic, replay, serial, pupil, viewpoint, intersense)"
    )
