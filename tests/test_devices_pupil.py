"""PupilSource against a local fake of Pupil Remote (REP) and the IPC backbone (PUB)."""

import math
import threading
import time

import _extras
import pytest

zmq = _extras.require("zmq", module_level=True)
msgpack = _extras.require("msgpack", module_level=True)

from fovjax.devices import PupilSource, gaze_from_pupil_datum  # noqa: E402


class FakePupil:
    """Pupil Remote answering SUB_PORT, plus a publisher speaking Pupil's [topic, msgpack] frames."""

    def __init__(self):
        self.ctx = zmq.Context()
        self.rep = self.ctx.socket(zmq.REP)
        self.remote_port = self.rep.bind_to_random_port("tcp://127.0.0.1")
        self.pub = self.ctx.socket(zmq.PUB)
        self.sub_port = self.pub.bind_to_random_port("tcp://127.0.0.1")
        self.requests = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self):
        while not self._stop.is_set():
            if self.rep.poll(20):
                request = self.rep.recv_string()
                self.requests.append(request)
                self.rep.send_string(str(self.sub_port) if request == "SUB_PORT" else "unknown")

    def publish(self, datum, topic=None, raw=None):
        topic = topic or datum["topic"]
        payload = raw if raw is not None else msgpack.packb(datum, use_bin_type=True)
        self.pub.send_multipart([topic.encode(), payload])

    def close(self):
        self._stop.set()
        self._thread.join()
        self.rep.close(0)
        self.pub.close(0)
        self.ctx.term()


def gaze(topic, x, y, confidence, timestamp):
    return {
        "topic": topic,
        "norm_pos": [x, y],
        "confidence": confidence,
        "timestamp": timestamp,
        "base_data": [],
    }


def wait_for(predicate, timeout=10.0, poke=None):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        if poke is not None:
            poke()
        time.sleep(0.01)
    return False


def test_pupil_gaze_stream_is_mapped_to_top_left_origin():
    peer = FakePupil()
    source = PupilSource("127.0.0.1", peer.remote_port, request_timeout=2.0, poll_interval=0.02)
    try:
        with source:
            assert source.wait_connected(5.0) and source.sub_port == peer.sub_port
            assert peer.requests[0] == "SUB_PORT"
            # ZeroMQ drops what is published before the subscription lands: sync first.
            assert wait_for(
                lambda: source.status.samples > 0,
                poke=lambda: peer.publish(gaze("gaze.3d.01.", 0.5, 0.5, 1.0, -1.0)),
            )
            time.sleep(0.05)
            while source.read(timeout=0.05) is not None:
                pass
            peer.publish({"topic": "pupil.0.2d", "norm_pos": [0.1, 0.1], "confidence": 1.0, "timestamp": 1.0})
            peer.publish(gaze("gaze.3d.01.", 0.2, 0.7, 0.9, 10.0))
            peer.publish(gaze("gaze.2d.0.", 0.6, 0.4, 0.8, 11.0))
            peer.publish(None, topic="gaze.3d.01.", raw=msgpack.packb([1, 2, 3]))  # not a map
            peer.publish({"topic": "gaze.3d.1.", "norm_pos": [0.3, 0.3], "timestamp": 12.0})  # no confidence
            peer.publish(gaze("gaze.3d.1.", 0.9, 0.0, 0.7, 13.0))
            got = []
            # (late sync messages, stamped -1, are skipped)
            assert wait_for(
                lambda: (
                    got.extend(s for s in [source.read(timeout=0.05)] if s and s.device_time >= 0)
                    or len(got) >= 3
                )
            )
            assert [s.device_time for s in got] == [10.0, 11.0, 13.0]
            assert got[0].left.xy == pytest.approx((0.2, 0.3)) and got[0].right.xy == pytest.approx(
                (0.2, 0.3)
            )
            assert got[0].left.confidence == pytest.approx(0.9) and got[0].left.valid
            assert got[1].right.xy == pytest.approx((0.6, 0.6))
            assert got[2].left.xy == pytest.approx((0.9, 1.0))
            assert wait_for(lambda: source.status.extra["bad_messages"] == 2)
            assert source.latest().device_time == 13.0
    finally:
        peer.close()


def test_monocular_own_mode_and_datum_errors():
    right_only = gaze_from_pupil_datum(gaze("gaze.3d.0.", 0.25, 0.25, 0.95, 3.0), 1.0, monocular="own")
    assert right_only.right.xy == (0.25, 0.75) and not right_only.left.valid
    left_only = gaze_from_pupil_datum(gaze("gaze.2d.1.", 0.25, 0.25, 0.95, 3.0), 1.0, monocular="own")
    assert left_only.left.valid and not left_only.right.valid
    nan = gaze_from_pupil_datum(gaze("gaze.3d.01.", math.nan, 0.2, 0.9, 1.0), 1.0)
    assert not nan.left.valid and not nan.right.valid
    with pytest.raises(ValueError, match="no field 'confidence'"):
        gaze_from_pupil_datum({"topic": "gaze.3d.01.", "norm_pos": [0, 0]}, 0.0)
    with pytest.raises(ValueError, match="not numeric"):
        gaze_from_pupil_datum({"norm_pos": "xy", "confidence": 1}, 0.0)


def test_silent_pupil_remote_never_raises():
    ctx = zmq.Context()
    sock = ctx.socket(zmq.REP)
    port = sock.bind_to_random_port("tcp://127.0.0.1")  # bound but never answers
    try:
        source = PupilSource("127.0.0.1", port, request_timeout=0.05, backoff_initial=0.01, backoff_max=0.02)
        with source:
            assert not source.wait_connected(0.3)
            assert source.status.errors >= 1 and "did not answer SUB_PORT" in source.status.last_error
            assert source.latest() is None and source.read(timeout=0.01) is None
    finally:
        sock.close(0)
        ctx.term()
