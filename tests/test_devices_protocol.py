import math

import pytest
from fakes.clock import FakeClock

from fovjax.devices import (
    EyeGaze,
    GazeSample,
    HeadPose,
    LineParser,
    ProtocolError,
    checksum,
    format_gaze,
    format_head,
    parse_line,
)


def test_checksum_matches_the_nmea_reference_sentence():
    # The textbook NMEA 0183 GGA example, whose checksum is printed as *47.
    payload = b"GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"
    assert checksum(payload) == 0x47


def test_gaze_line_round_trip_and_documented_example():
    line = b"$GAZE,12.5,0.51,0.49,0.98,0.49,0.49,0.97*2B"
    sample = parse_line(line, receive_time=7.0)
    assert sample.timestamp == 7.0 and sample.device_time == 12.5
    assert sample.left == EyeGaze(0.51, 0.49, 0.98, True)
    assert sample.right == EyeGaze(0.49, 0.49, 0.97, True)
    assert format_gaze(sample).rstrip(b"\r\n") == line
    head = parse_line(b"$HEAD,3.25,10,-5.25,0.5*09\r\n", receive_time=1.0)
    assert (head.yaw, head.pitch, head.roll, head.device_time, head.valid) == (10.0, -5.25, 0.5, 3.25, True)
    assert format_head(head).rstrip(b"\r\n") == b"$HEAD,3.25,10,-5.25,0.5*09"


def test_missing_eye_and_negative_confidence_mean_not_tracked():
    s = GazeSample(1.0, EyeGaze(math.nan, math.nan, 0.0, False), EyeGaze(0.2, 0.3, 0.9, True), 5.0)
    line = format_gaze(s)
    assert b"GAZE,5,,,," in line
    parsed = parse_line(line, 2.0)
    assert not parsed.left.valid and parsed.right.valid
    neg = parse_line(format_gaze(GazeSample(1.0, EyeGaze(0.5, 0.5, -1.0), EyeGaze(0.5, 0.5, 1.0))), 0.0)
    assert not neg.left.valid and neg.right.valid


@pytest.mark.parametrize(
    "line, fragment",
    [
        (b"GAZE,1,2,3,4,5,6,7*00", "start with"),
        (b"$GAZE,1,0.5,0.5,1,0.5,0.5,1", "no '*'"),
        (b"$GAZE,1,0.5,0.5,1,0.5,0.5,1*ZZ", "not hex"),
        (b"$GAZE,1,0.5,0.5,1,0.5,0.5,1*00", "checksum mismatch"),
        (b"$HEAD,1,2,3" + b"*" + f"{checksum(b'HEAD,1,2,3'):02X}".encode(), "needs 4 fields"),
        (b"$FOO,1*" + f"{checksum(b'FOO,1'):02X}".encode(), "unknown message type"),
        (b"$HEAD,1,x,3,4*" + f"{checksum(b'HEAD,1,x,3,4'):02X}".encode(), "yaw='x'"),
    ],
)
def test_bad_lines_raise_protocol_error_saying_why(line, fragment):
    with pytest.raises(ProtocolError, match=fragment.replace("(", r"\(").replace("*", r"\*")):
        parse_line(line, 0.0)


def test_protocol_error_is_a_value_error():
    assert issubclass(ProtocolError, ValueError)


def _lines(n):
    return [
        format_gaze(GazeSample(0.0, EyeGaze(0.1 * i % 1, 0.5, 0.9), EyeGaze(0.2, 0.3, 0.8), float(i)))
        for i in range(n)
    ]


def test_parser_reassembles_lines_fed_one_byte_at_a_time():
    parser = LineParser(FakeClock())
    data = b"".join(_lines(5))
    out = []
    for i in range(len(data)):
        out += parser.feed(data[i : i + 1])
    assert [s.device_time for s in out] == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert sum(parser.rejected.values()) == 0


def test_parser_survives_garbage_bad_checksums_and_overlong_lines():
    parser = LineParser(FakeClock())
    good = _lines(4)
    corrupted = bytearray(good[1])
    corrupted[10] ^= 0x01  # flip one bit in the payload
    stream = (
        b"\x00\xff\xfe garbage \x80\n"
        + good[0]
        + bytes(corrupted)
        + b"noise glued on"
        + good[2]
        + b"X" * 1000
        + b"\n"
        + good[3]
        + b"$GAZE,partial-without-end"
    )
    out = []
    for start in range(0, len(stream), 7):
        out += parser.feed(stream[start : start + 7])
    assert [s.device_time for s in out] == [0.0, 2.0, 3.0]
    assert parser.rejected["checksum"] == 1
    assert parser.rejected["garbage"] >= 2
    assert parser.rejected["overlong"] == 1
    # The unterminated tail is still pending, not parsed and not lost until its newline comes.
    assert parser.feed(b"\n") == []
    assert parser.rejected["format"] + parser.rejected["checksum"] >= 1


def test_head_pose_rotation_matrix_follows_the_intersense_signs():
    import numpy as np

    forward = np.array([1.0, 0.0, 0.0])
    up_look = HeadPose(0.0, 0.0, 30.0, 0.0).rotation_matrix() @ forward
    assert up_look[2] < 0  # z is down, so looking up has negative z
    right_turn = HeadPose(0.0, 30.0, 0.0, 0.0).rotation_matrix() @ forward
    assert right_turn[1] > 0
    right_ear_down = HeadPose(0.0, 0.0, 0.0, 30.0).rotation_matrix() @ np.array([0.0, 1.0, 0.0])
    assert right_ear_down[2] > 0
    r = HeadPose(0.0, 37.0, -12.0, 5.0).rotation_matrix()
    assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0)
