"""SerialSource against a fake peer on a pseudo-terminal pair: partial lines, bad checksums,
garbage, and the peer vanishing and coming back mid-stream."""

import os
import sys
import time

import pytest

from fovjax.devices import (
    EyeGaze,
    FallbackPolicy,
    GazeSample,
    GazeTracker,
    HeadPose,
    SerialSource,
    TrackingState,
    format_gaze,
    format_head,
)

pytestmark = pytest.mark.skipif(
    not hasattr(os, "openpty") or sys.platform == "win32", reason="needs os.openpty"
)


class FakePeer:
    """The far end of a pty, reachable for the source through a symlink that can be re-pointed."""

    def __init__(self, link):
        import tty

        self.master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no CR/LF translation before the source opens the port
        self.name = os.ttyname(slave)
        os.close(slave)
        tmp = f"{link}.new"
        os.symlink(self.name, tmp)
        os.replace(tmp, link)

    def send(self, data: bytes) -> None:
        os.write(self.master, data)

    def hang_up(self) -> None:
        os.close(self.master)


def gaze_line(i: int) -> bytes:
    return format_gaze(GazeSample(0.0, EyeGaze(0.5, 0.25, 0.9), EyeGaze(0.5, 0.25, 0.8), float(i)))


def wait_for(predicate, timeout=10.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.005)
    return False


def test_serial_stream_with_garbage_partial_lines_and_a_reconnect(tmp_path):
    link = str(tmp_path / "ttyFAKE")
    peer = FakePeer(link)
    source = SerialSource(link, read_timeout=0.02, backoff_initial=0.01, backoff_max=0.05)
    with source:
        assert source.wait_connected(5.0)
        # A line split over two writes (so over two reads), garbage, a corrupted checksum, a
        # head-pose line on the gaze port, and binary noise.
        first = gaze_line(0)
        peer.send(first[:9])
        time.sleep(0.05)
        peer.send(first[9:])
        bad = bytearray(gaze_line(99))
        bad[8] = ord("7") if bad[8] != ord("7") else ord("8")
        peer.send(b"\x00\x13\xff\xfeNOISE\n" + gaze_line(1) + bytes(bad) + format_head(HeadPose(0, 1, 2, 3)))
        peer.send(b"@@@" + gaze_line(2) + bytes(range(256)) + b"\n" + gaze_line(3))
        assert wait_for(lambda: source.status.samples == 4)
        got = [source.read(timeout=1.0) for _ in range(4)]
        assert [s.device_time for s in got] == [0.0, 1.0, 2.0, 3.0]
        assert got[0].left == EyeGaze(0.5, 0.25, 0.9, True)
        assert source.rejected["checksum"] == 1 and source.rejected["garbage"] >= 2
        assert source.status.extra["other_kind"] == 1

        # Mid-line, the peer vanishes: the reader must notice, not crash, and keep retrying.
        peer.send(gaze_line(4)[:12])
        time.sleep(0.05)
        peer.hang_up()
        assert wait_for(lambda: source.status.disconnects >= 1)
        assert source.latest().device_time == 3.0  # nothing new, nothing made up
        frame = GazeTracker(FallbackPolicy(recover_after=1)).step(
            source.latest().timestamp + 0.3, [source.latest()]
        )
        assert frame.state is TrackingState.DEGRADED and frame.left == (0.5, 0.25)

        # The peer comes back on a new pty behind the same path; the half line is forgotten.
        peer = FakePeer(link)
        assert wait_for(lambda: source.status.connects >= 2)
        peer.send(gaze_line(4)[12:] + gaze_line(5) + gaze_line(6))
        assert wait_for(lambda: source.status.samples == 6)
        after = [source.read(timeout=1.0) for _ in range(2)]
        assert [s.device_time for s in after] == [5.0, 6.0]
        assert source.read(timeout=0.05) is None
        assert source.status.errors >= 1 and source.status.last_error
    peer.hang_up()
    assert not source.status.connected


def test_head_stream_and_a_port_that_is_not_there_yet(tmp_path):
    link = str(tmp_path / "ttyHEAD")
    source = SerialSource(link, kind="head", read_timeout=0.02, backoff_initial=0.01, backoff_max=0.05)
    with source:
        # No device yet: opening does not raise, the source just is not connected.
        assert not source.wait_connected(0.1)
        assert source.status.errors >= 1 and source.latest() is None
        peer = FakePeer(link)
        assert source.wait_connected(5.0)
        peer.send(format_head(HeadPose(0.0, 12.5, -3.0, 1.0, device_time=7.0)) + gaze_line(1))
        pose = source.read(timeout=5.0)
        assert (pose.yaw, pose.pitch, pose.roll, pose.device_time) == (12.5, -3.0, 1.0, 7.0)
        assert isinstance(pose, HeadPose) and pose.timestamp <= source.clock()
    peer.hang_up()


def test_serial_arguments_are_checked():
    with pytest.raises(ValueError, match="kind must be"):
        SerialSource("/dev/null", kind="eyes")
    with pytest.raises(ValueError, match="baudrate"):
        SerialSource("/dev/null", baudrate=0)
