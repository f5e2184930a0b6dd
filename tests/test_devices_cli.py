"""The `fovjax record` command, the shipped synthetic recordings, and the fallback seen end to end
on the recording with a silent second."""

import json
import math
import socket
import time
from pathlib import Path

import _extras
import numpy as np
import pytest
from fakes.clock import FakeClock

from fovjax.cli import main
from fovjax.devices import (
    DeviceError,
    FallbackPolicy,
    GazeTracker,
    ReplaySource,
    TrackingState,
    load_recording,
    source_from_spec,
)

RECORDINGS = Path(__file__).resolve().parents[1] / "data" / "recordings"

SHIPPED = {
    "synthetic_scanpath_seed0.jsonl": [
        "--gaze", "synthetic:scanpath:0", "--seconds", "5", "--fast",
        "--description", "5 s synthetic scanpath, seed 0, 120 Hz, both eyes at the same point",
    ],
    "synthetic_scanpath_seed1_dropout.csv": [
        "--gaze", "synthetic:scanpath:1", "--seconds", "5", "--fast", "--dropout", "2.0:3.0",
        "--description", "5 s synthetic scanpath, seed 1, 120 Hz, tracker silent from 2.0 s to 3.0 s",
    ],
    "synthetic_pursuit.csv": [
        "--gaze", "synthetic:pursuit", "--seconds", "5", "--fast",
        "--description", "5 s synthetic smooth pursuit, circle radius 0.25 at 0.1 Hz, 120 Hz",
    ],
    "synthetic_head_sway.csv": [
        "--head", "synthetic:sway", "--seconds", "5", "--fast",
        "--description",
        "5 s synthetic head sway: yaw 20 deg sin(2 pi t / 8 s), " "pitch 5 deg at twice that, 180 Hz",
    ],
}  # fmt: skip


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_shipped_recordings_are_labelled_and_regenerate(name, tmp_path, capsys):
    shipped = RECORDINGS / name
    assert shipped.is_file(), f"{shipped}: the recording ships with the repository"
    recording = load_recording(shipped)
    assert recording.metadata["synthetic"] is True and "SYNTHETIC" in recording.metadata["note"]
    out = tmp_path / name
    assert main(["record", *SHIPPED[name], "-o", str(out)]) == 0
    assert f"wrote {len(recording)} " in capsys.readouterr().out
    # Same header, same samples (to 1e-12: the last digit of a libm sine may differ by platform).
    regenerated = load_recording(out)
    assert regenerated.metadata == recording.metadata and len(regenerated) == len(recording)
    a = np.array([list(r.as_row().values()) for r in recording.samples], dtype=float)
    b = np.array([list(r.as_row().values()) for r in regenerated.samples], dtype=float)
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-12, equal_nan=True)


def test_record_cli_stops_at_sample_count_and_rejects_bad_options(tmp_path):
    out = tmp_path / "n.jsonl"
    assert (
        main(["record", "--gaze", "synthetic:fixed:0.2,0.3", "--fast", "--samples", "7", "-o", str(out)]) == 0
    )
    rec = load_recording(out)
    assert len(rec) == 7 and rec.samples[0].left.xy == (0.2, 0.3)
    header = json.loads(out.read_text().splitlines()[0])
    assert header["kind"] == "gaze" and header["source"] == "synthetic:fixed:0.2,0.3"
    assert main(["record", "--gaze", "synthetic:scanpath", "--dropout", "soon", "-o", str(out)]) == 2
    with pytest.raises(SystemExit):
        main(["record", "-o", str(out)])  # neither --gaze nor --head


# --- devices fail loudly --------------------------------------------------------------------


def _closed_port() -> int:
    """A loopback TCP port nothing listens on."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize(
    ("spec", "names"),
    [
        ("serial:/dev/ttyNOPE", ["serial:/dev/ttyNOPE", "serial port /dev/ttyNOPE", "No such file"]),
        ("pupil:127.0.0.1:{port}", ["Pupil Remote at 127.0.0.1:{port}", "did not answer"]),
        ("pupil:no-such-host.invalid", ["no-such-host.invalid", "cannot resolve the host name"]),
    ],
)
def test_unreachable_device_fails_within_its_connect_timeout(spec, names, monkeypatch):
    if spec.startswith("pupil"):
        _extras.require("zmq")
    if "invalid" in spec:  # the resolver's answer, without depending on this machine's DNS

        def no_such_host(host, *args, **kwargs):
            raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")

        monkeypatch.setattr(socket, "getaddrinfo", no_such_host)
    port = _closed_port()
    source = source_from_spec(spec.format(port=port), "gaze", connect_timeout=0.5)
    t0 = time.monotonic()
    with pytest.raises(DeviceError) as err:
        source.open()
    assert time.monotonic() - t0 < 5.0  # 0.5 s and the reader stopping; generous for a busy machine
    message = str(err.value)
    assert "could not connect within 0.5 s" in message
    for name in names:
        assert name.format(port=port) in message, message
    assert not source.is_open and source.exhausted


def test_record_from_a_silent_device_stops_on_wall_time_and_says_so(tmp_path, capsys):
    # pyserial's loop:// opens at once and never delivers a line.
    out = tmp_path / "silent.jsonl"
    t0 = time.monotonic()
    assert main(["record", "--gaze", "serial:loop://", "--seconds", "0.5", "-o", str(out)]) == 1
    assert time.monotonic() - t0 < 10.0
    captured = capsys.readouterr()
    assert "wrote 0 gaze samples" in captured.out
    assert "serial:loop:// (serial port loop://) delivered no samples" in captured.err
    assert len(load_recording(out)) == 0


def test_record_unreachable_device_names_it_and_the_wait_option(tmp_path, capsys):
    out = tmp_path / "none.jsonl"
    assert main(["record", "--gaze", "serial:/dev/ttyNOPE", "--wait", "0.3", "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("fovjax record: error: serial:/dev/ttyNOPE (serial port /dev/ttyNOPE)")
    assert "--wait SECONDS" in err and not out.exists()


def test_fallback_on_the_dropout_recording_widens_then_recovers():
    path = RECORDINGS / "synthetic_scanpath_seed1_dropout.csv"
    assert path.is_file(), f"{path}: the recording ships with the repository"
    clock = FakeClock(0.0)
    policy = FallbackPolicy()
    tracker = GazeTracker(policy, predictor=None)
    frames = []
    with ReplaySource(path, clock=clock, sleep=clock.sleep) as source:
        for k in range(int(5.0 * 90)):  # a 90 Hz display
            clock.t = k / 90.0
            frames.append(tracker.step(clock.t, [source.latest()], display_time=clock.t))
    t = np.array([f.time for f in frames])
    widening = np.array([f.widening for f in frames])
    states = [f.state for f in frames]
    before = (t > 0.2) & (t < 2.0)
    assert all(states[i] is TrackingState.OK for i in np.flatnonzero(before))
    assert np.all(widening[before] == 0)
    # The tracker went silent at 2.0 s (last sample at 119/120 s): hold, then widen step by step.
    last_good = 239 / 120
    gap = (t >= 2.0) & (t < 3.0)
    assert np.all(np.diff(widening[gap]) >= 0)
    assert set(np.round(widening[gap], 3)) == {0.0, 0.25, 0.5, 0.75, 1.0}
    later = t > 1.0  # (before its first samples the tracker starts out lost)
    first_widen = t[np.argmax(later & (widening > 0))]
    assert first_widen == pytest.approx(last_good + policy.hold_for, abs=1.5 / 90)
    first_full = t[np.argmax(later & (widening == 1.0))]
    assert first_full == pytest.approx(last_good + policy.time_to_lost(), abs=1.5 / 90)
    # Samples come back at 3.0 s; after recover_after of them the fovea is back to normal.
    back = t[np.argmax((t > 3.0) & (widening == 0))]
    assert 3.0 < back <= 3.0 + (policy.recover_after + 1) / 90 + 1e-9
    assert all(states[i] is TrackingState.OK for i in np.flatnonzero(t > 3.1))
    # The gaze never came from nowhere: while widened it stays at the last good sample.
    held = [f.left for f in frames if f.widening > 0 and f.time > 1.0]
    assert len(set(held)) == 1 and not any(math.isnan(v) for v in held[0])
