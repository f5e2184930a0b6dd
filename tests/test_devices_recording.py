import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from fakes.clock import FakeClock
from fakes.feed import FeedSource

from fovjax.devices import (
    MISSING_EYE,
    EyeGaze,
    GazeSample,
    HeadPose,
    Recorder,
    ReplaySource,
    Scanpath,
    SyntheticGazeSource,
    load_recording,
    record,
    source_from_spec,
)

ROOT = Path(__file__).resolve().parents[1]


def _same(a, b):
    """Field-by-field equality where NaN equals NaN."""
    ra, rb = a.as_row(), b.as_row()
    return ra.keys() == rb.keys() and all(
        (isinstance(x, float) and math.isnan(x) and math.isnan(y)) or x == y
        for x, y in zip(ra.values(), rb.values(), strict=True)
    )


def _mixed_samples():
    src = SyntheticGazeSource(
        Scanpath(5), rate=250, duration=0.4, noise_sd=0.003, seed=1, speed=None, start_time=10.0
    )
    with src:
        samples = list(src)
    # Make some eyes bad the way devices do: missing, NaN, low confidence.
    samples[3] = GazeSample(samples[3].timestamp, MISSING_EYE, samples[3].right, samples[3].device_time)
    samples[4] = GazeSample(samples[4].timestamp, EyeGaze(math.nan, 0.2, 0.0, False), samples[4].right)
    samples[5] = GazeSample(samples[5].timestamp, EyeGaze(0.1, 0.2, 0.05, True), samples[5].right, 1e-9)
    return samples


@pytest.mark.parametrize("suffix", [".jsonl", ".csv"])
def test_recording_round_trip_is_exact(tmp_path, suffix):
    samples = _mixed_samples()
    path = tmp_path / f"gaze{suffix}"
    with Recorder(path, "gaze", metadata={"synthetic": True}) as rec:
        rec.write_all(samples)
    loaded = load_recording(path)
    assert loaded.kind == "gaze" and loaded.metadata["synthetic"] is True
    assert len(loaded) == len(samples)
    assert all(_same(a, b) for a, b in zip(samples, loaded.samples, strict=True))

    poses = [HeadPose(1.0 + i / 100, 3.0 * i, -1.5, 0.25, device_time=i, valid=i != 2) for i in range(5)]
    head_path = tmp_path / f"head{suffix}"
    with Recorder(head_path, "head") as rec:
        rec.write_all(poses)
    assert all(_same(a, b) for a, b in zip(poses, load_recording(head_path).samples, strict=True))


def test_recorder_refuses_the_wrong_kind(tmp_path):
    with (
        Recorder(tmp_path / "g.jsonl", "gaze") as rec,
        pytest.raises(ValueError, match="head sample in a gaze"),
    ):
        rec.write(HeadPose(0.0, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="unknown recording format"):
        Recorder(tmp_path / "g.txt", "gaze")


def test_load_errors_name_file_line_and_field(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("t,device_time,yaw,pitch,roll,valid\n0.0,,1,2,3,1\n0.1,,1,oops,3,1\n")
    with pytest.raises(ValueError, match=r"bad.csv:3: field pitch='oops' is not a number"):
        load_recording(path)
    path = tmp_path / "back.jsonl"
    path.write_text(
        '{"t": 1, "yaw": 0, "pitch": 0, "roll": 0, "valid": true}\n'
        '{"t": 0.5, "yaw": 0, "pitch": 0, "roll": 0, "valid": true}\n'
    )
    with pytest.raises(ValueError, match=r"back.jsonl:2: field t=0.5 goes back in time"):
        load_recording(path)


def test_replay_as_fast_as_possible_is_deterministic(tmp_path):
    path = tmp_path / "r.jsonl"
    with Recorder(path, "gaze") as rec:
        rec.write_all(_mixed_samples())

    def run():
        with ReplaySource(path, speed=None) as src:
            return [s.as_row() for s in src]

    first, second = run(), run()
    assert len(first) == 101
    assert [r["t"] for r in first] == [r["t"] for r in second]
    assert str(first) == str(second)  # identical including NaNs
    assert first[0]["t"] == 10.0  # unpaced replays keep the recorded timestamps


def test_replay_in_real_time_and_at_double_speed_on_an_injected_clock(tmp_path):
    path = tmp_path / "r.csv"
    originals = _mixed_samples()
    with Recorder(path, "gaze") as rec:
        rec.write_all(originals)
    for speed in (1.0, 2.0):
        clock = FakeClock(500.0)
        with ReplaySource(path, speed=speed, clock=clock, sleep=clock.sleep) as src:
            assert src.latest().timestamp == 500.0
            clock.advance(0.0201 / speed)
            assert src.latest().device_time == originals[5].device_time  # 20 ms in at 250 Hz
            replayed = list(src)
        assert len(replayed) == len(originals)
        for a, b in zip(originals, replayed, strict=True):
            assert b.timestamp == pytest.approx(500.0 + (a.timestamp - 10.0) / speed)
            assert a.left == b.left or (math.isnan(a.left.x) and math.isnan(b.left.x))
        assert clock.t == pytest.approx(500.0 + 0.4 / speed)


def test_replay_loops(tmp_path):
    path = tmp_path / "r.jsonl"
    with Recorder(path, "gaze") as rec:
        rec.write_all(_mixed_samples()[:10])
    with ReplaySource(path, speed=None, loop=True) as src:
        got = [src.read() for _ in range(25)]
    times = [s.timestamp for s in got]
    assert all(b > a for a, b in zip(times, times[1:], strict=False))
    assert got[10].left == got[0].left


def test_recorder_loses_nothing_when_interrupted_mid_stream(tmp_path):
    source = FeedSource()
    source.open()
    sent = [GazeSample(float(i), EyeGaze(0.5, 0.5), EyeGaze(0.5, 0.5), float(i)) for i in range(300)]
    for s in sent:
        source.device.put(s)
    assert _wait_for(lambda: source.status.samples == 300)

    def interrupt_at_ten(sample):
        if sample.device_time == 10.0:
            raise KeyboardInterrupt

    summary = record(source, tmp_path / "cut.jsonl", on_sample=interrupt_at_ten)
    source.close()
    assert summary.interrupted and summary.samples == 300
    loaded = load_recording(tmp_path / "cut.jsonl")
    assert [s.device_time for s in loaded.samples] == [float(i) for i in range(300)]
    with pytest.raises(KeyboardInterrupt):
        fresh = FeedSource()
        fresh.device.put(sent[0])
        record(fresh, tmp_path / "again.csv", on_sample=interrupt_at_ten_or_first, reraise=True)
    fresh.close()
    assert len(load_recording(tmp_path / "again.csv")) == 1


def interrupt_at_ten_or_first(sample):
    raise KeyboardInterrupt


def _wait_for(predicate, timeout=10.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.005)
    return False


def test_record_cli_subprocess_survives_sigint_without_losing_samples(tmp_path):
    out = tmp_path / "sigint.jsonl"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [
        sys.executable,
        "-m",
        "fovjax.cli._record",
        "record",
        "--gaze",
        "synthetic:scanpath:9",
        "--rate",
        "200",
    ]
    proc = subprocess.Popen(
        [*cmd, "--seconds", "120", "-o", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        assert _wait_for(lambda: out.exists() and out.read_text().count("\n") > 60, timeout=60.0), (
            "recorder never started"
        )
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, stderr  # the shell's status for Ctrl-C
    assert "(interrupted)" in stdout
    assert f"fovjax record: interrupted; wrote {out} (complete)" in stderr and "Traceback" not in stderr
    written = int(stdout.split("wrote ")[1].split()[0])
    loaded = load_recording(out)
    assert len(loaded) == written > 60
    # The synthetic source numbers its samples i / rate: consecutive, none missing.
    assert [round(s.device_time * 200) for s in loaded.samples] == list(range(written))
    assert loaded.metadata["synthetic"] is True


def test_replay_spec_checks_the_kind(tmp_path):
    path = tmp_path / "h.jsonl"
    with Recorder(path, "head") as rec:
        rec.write(HeadPose(0.0, 1.0, 2.0, 3.0))
    assert source_from_spec(f"replay:{path}@fast", "head").speed is None
    with pytest.raises(ValueError, match="is a head recording, not gaze"):
        source_from_spec(f"replay:{path}", "gaze")
