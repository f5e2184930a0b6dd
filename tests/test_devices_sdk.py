"""ViewPointSource and InterSenseSource against fake vendor libraries compiled from
tests/fakes/*.c for the test (skipped when there is no C compiler)."""

import ctypes
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fovjax.devices import (
    EYE_A,
    EYE_B,
    InterSenseSource,
    LibraryNotFoundError,
    ViewPointSource,
    viewpoint_to_side_by_side,
)
from fovjax.devices._intersense import ISD_STATION_DATA_TYPE, ISD_TRACKING_DATA_TYPE
from fovjax.devices._viewpoint import VPX_DAT_FRESH

FAKES = Path(__file__).parent / "fakes"
COMPILER = shutil.which("cc") or shutil.which("gcc")


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    if COMPILER is None or sys.platform == "win32":
        pytest.skip("no C compiler to build the fake vendor libraries")
    out = tmp_path_factory.mktemp("fakelibs")

    def compile_(name):
        lib = out / f"lib{name}.so"
        subprocess.run(
            [COMPILER, "-shared", "-fPIC", "-O1", "-o", str(lib), str(FAKES / f"{name}.c"), "-lpthread"],
            check=True,
            capture_output=True,
        )
        return lib

    return compile_


def wait_for(predicate, timeout=10.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.002)
    return False


# -- ViewPoint --------------------------------------------------------------------------------


def test_viewpoint_missing_library_is_a_clear_error(tmp_path, monkeypatch):
    with pytest.raises(LibraryNotFoundError, match=r"ViewPoint SDK library not found \(tried .*nope\.so"):
        ViewPointSource(tmp_path / "nope.so").open()
    monkeypatch.setenv("FOVJAX_VIEWPOINT_LIB", str(tmp_path / "also-missing.so"))
    with pytest.raises(LibraryNotFoundError, match="FOVJAX_VIEWPOINT_LIB"):
        ViewPointSource().open()
    assert issubclass(LibraryNotFoundError, FileNotFoundError)


def test_viewpoint_fresh_data_callback_quality_codes_and_eyes(build):
    path = build("fake_vpx")
    fake = ctypes.CDLL(str(path))
    fake.fake_set_eye.argtypes = [ctypes.c_int, ctypes.c_float, ctypes.c_float, ctypes.c_int, ctypes.c_double]
    source = ViewPointSource(path)
    with source:
        assert fake.fake_callback_registered() == 1
        fake.fake_set_eye(EYE_A, 0.625, 0.375, 0, 1.0)  # EYE_A: the right eye (thesis figure 45)
        fake.fake_set_eye(EYE_B, 0.25, 0.375, 2, 1.0)
        assert fake.fake_fire(VPX_DAT_FRESH, EYE_A) == 0
        sample = source.read(timeout=1.0)
        assert sample.right.xy == (0.625, 0.375) and sample.right.valid and sample.right.confidence == 1.0
        assert (
            sample.left.xy == (0.25, 0.375)
            and sample.left.valid
            and sample.left.confidence == pytest.approx(0.6)
        )
        assert sample.device_time == 1.0
        fake.fake_fire(VPX_DAT_FRESH, EYE_B)  # same data times: not a new sample
        fake.fake_fire(21, 0)  # a status-change message: ignored
        assert source.read(timeout=0.05) is None
        # Quality 3 (pupil outside criteria) fails the thesis's "<= 2" rule.
        fake.fake_set_eye(EYE_A, 0.5, 0.5, 3, 2.0)
        fake.fake_set_eye(EYE_B, 0.5, 0.5, 5, 2.0)
        fake.fake_fire(VPX_DAT_FRESH, EYE_A)
        bad = source.read(timeout=1.0)
        assert not bad.right.valid and not bad.left.valid and bad.left.confidence == 0.0
        # ViewPoint calls back from its own thread.
        fake.fake_set_eye(EYE_A, 0.75, 0.125, 1, 3.0)
        assert fake.fake_fire_from_thread(VPX_DAT_FRESH, EYE_A) == 0
        threaded = source.read(timeout=1.0)
        assert threaded.right.xy == (0.75, 0.125) and threaded.right.valid
        assert source.latest() is threaded and source.status.samples == 3
    assert fake.fake_callback_registered() == 0  # close() removed the callback
    assert fake.fake_fire(VPX_DAT_FRESH, EYE_A) == -1

    lenient = ViewPointSource(path, max_quality_code=3, eye_a="left")
    with lenient:
        fake.fake_set_eye(EYE_A, 0.5, 0.5, 3, 4.0)
        fake.fake_fire(VPX_DAT_FRESH, EYE_A)
        s = lenient.read(timeout=1.0)
        assert s.left.valid and not s.right.valid  # EYE_A is now the left eye, EYE_B still code 5


def test_viewpoint_reads_the_smoothed_gaze_point_by_default_as_the_thesis(build):
    """The thesis's callback reads VPX_GetGazePointSmoothed2; the unfiltered point is a choice
    (smoothed=False, or the spec's @raw)."""
    from fovjax.devices import source_from_spec

    path = build("fake_vpx")
    fake = ctypes.CDLL(str(path))
    fake.fake_set_eye.argtypes = [ctypes.c_int, ctypes.c_float, ctypes.c_float, ctypes.c_int, ctypes.c_double]
    fake.fake_set_smoothed.argtypes = [ctypes.c_int, ctypes.c_float, ctypes.c_float]
    sources = {
        "default": ViewPointSource(path),
        "spec": source_from_spec(f"viewpoint:{path}"),
        "spec @smoothed": source_from_spec(f"viewpoint:{path}@smoothed"),
        "smoothed=False": ViewPointSource(path, smoothed=False),
        "spec @raw": source_from_spec(f"viewpoint:{path}@raw"),
    }
    for n, (name, source) in enumerate(sources.items()):
        with source:
            for eye in (EYE_A, EYE_B):
                fake.fake_set_eye(eye, 0.5, 0.5, 0, float(n + 1))
                fake.fake_set_smoothed(eye, 0.25, 0.75)
            fake.fake_fire(VPX_DAT_FRESH, EYE_A)
            sample = source.read(timeout=1.0)
        want = (0.5, 0.5) if "raw" in name or "False" in name else (0.25, 0.75)
        assert sample.right.xy == want and sample.left.xy == want, name
    with pytest.raises(ValueError, match="ViewPoint reading 'median' is not 'smoothed' or 'raw'"):
        source_from_spec("viewpoint@median")


def test_viewpoint_side_by_side_mapping_follows_figure_45():
    w, h = 2000, 1000
    assert viewpoint_to_side_by_side(0.0, 0.0, EYE_A, w, h) == (1000.0, 1000.0)
    assert viewpoint_to_side_by_side(1.0, 1.0, EYE_A, w, h) == (2000.0, 0.0)
    assert viewpoint_to_side_by_side(0.5, 0.25, EYE_B, w, h) == (500.0, 750.0)
    with pytest.raises(ValueError, match="EYE_A"):
        viewpoint_to_side_by_side(0.5, 0.5, 7, w, h)


# -- InterSense -------------------------------------------------------------------------------


def test_intersense_struct_layout_matches_the_c_compiler(build):
    fake = ctypes.CDLL(str(build("fake_isense")))
    assert ctypes.sizeof(ISD_STATION_DATA_TYPE) == fake.fake_station_size()
    assert ISD_STATION_DATA_TYPE.Euler.offset == fake.fake_offset_euler()
    assert ISD_STATION_DATA_TYPE.TimeStamp.offset == fake.fake_offset_timestamp()
    assert ISD_STATION_DATA_TYPE.AuxInputs.offset == fake.fake_offset_aux()
    assert ISD_STATION_DATA_TYPE.MagBodyFrame.offset == fake.fake_offset_mag()
    assert ctypes.sizeof(ISD_TRACKING_DATA_TYPE) == 8 * fake.fake_station_size()


def test_intersense_missing_library_is_a_clear_error(tmp_path):
    with pytest.raises(LibraryNotFoundError, match="InterSense SDK library not found"):
        InterSenseSource(tmp_path / "libisense.so").open()


def test_intersense_reset_heading_euler_new_data_and_replug(build):
    path = build("fake_isense")
    fake = ctypes.CDLL(str(path))
    fake.fake_set_pose.argtypes = [ctypes.c_int] + [ctypes.c_float] * 3 + [ctypes.c_ubyte, ctypes.c_float]
    fake.fake_plug(0)
    fake.fake_set_pose(2, 10.0, 0.0, 0.0, 1, 0.0)
    source = InterSenseSource(path, station=2, poll_interval=0.002, backoff_initial=0.005, backoff_max=0.01)
    with source:
        # Not plugged in: no exception, retries with back-off.
        assert not source.wait_connected(0.05) and source.status.errors >= 1
        fake.fake_plug(1)
        assert source.wait_connected(5.0)
        assert fake.fake_resets() == 1 and fake.fake_last_port() == 0
        fake.fake_set_pose(2, 40.0, -5.5, 2.25, 1, 12.5)
        # The pose at connection (device time 0) may still be queued: skip to this one.
        pose = source.read(timeout=2.0)
        while pose is not None and pose.device_time == 0.0:
            pose = source.read(timeout=2.0)
        assert (pose.yaw, pose.pitch, pose.roll) == (30.0, -5.5, 2.25)  # yaw relative to the reset heading
        assert pose.valid and pose.device_time == 12.5
        assert source.read(timeout=0.05) is None  # NewData false: no repeats
        fake.fake_set_pose(2, 40.0, 0.0, 0.0, 0, 13.0)  # TrackingStatus 0: lost
        lost = source.read(timeout=2.0)
        assert not lost.valid
        # Unplugged mid-stream: ISD_GetTrackingData fails, the source closes and reopens.
        fake.fake_plug(0)
        assert wait_for(lambda: source.status.disconnects >= 1)
        fake.fake_plug(1)
        assert wait_for(lambda: fake.fake_opens() >= 2)
        assert fake.fake_resets() >= 2
        fake.fake_set_pose(2, 50.0, 1.0, 0.0, 1, 14.0)
        again = source.read(timeout=2.0)
        assert again.yaw == pytest.approx(10.0) and again.pitch == 1.0  # heading re-zeroed at 40 on reopen
    assert not source.status.connected
