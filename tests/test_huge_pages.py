"""The `fovjax` program starts itself with glibc's huge-page advice for large blocks
(fovjax/_startup.py): the environment it adds, what it leaves alone, and the running program's
own environment, read from /proc."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fovjax._startup import HUGE_PAGES_TUNABLE, huge_pages_environment

REPO = Path(__file__).resolve().parents[1]
GLIBC = "glibc 2.36"


@pytest.mark.parametrize(
    ("environ", "platform", "libc", "expected"),
    [
        ({}, "linux", GLIBC, HUGE_PAGES_TUNABLE),
        # a user's own tunables are kept, the advice appended
        (
            {"GLIBC_TUNABLES": "glibc.malloc.arena_max=2"},
            "linux",
            GLIBC,
            f"glibc.malloc.arena_max=2:{HUGE_PAGES_TUNABLE}",
        ),
        # a user's own choice of the same tunable wins, whatever its value
        ({"GLIBC_TUNABLES": "glibc.malloc.hugetlb=0"}, "linux", GLIBC, None),
        ({"FOVJAX_HUGE_PAGES": "0"}, "linux", GLIBC, None),
        ({}, "darwin", "", None),
        ({}, "linux", "", None),  # musl and others: no glibc tunables
    ],
)
def test_the_environment_it_adds(environ, platform, libc, expected):
    assert huge_pages_environment(environ, platform=platform, libc=libc) == expected


def _program_environment(tmp_path, **extra) -> dict[str, str]:
    """The environment of a running `python -m fovjax render`, read once JAX is loading (after
    any restart: the process id stays), then the program is stopped."""
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""), **extra)
    env.pop("GLIBC_TUNABLES", None)
    cmd = [sys.executable, "-m", "fovjax", "render", "--scene", "cornell", "--width", "8", "--height", "8"]
    cmd += ["--mono", "-o", str(tmp_path / "img.png")]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    try:
        deadline = time.monotonic() + 60
        while proc.poll() is None and time.monotonic() < deadline:
            try:
                if "jaxlib" in Path(f"/proc/{proc.pid}/maps").read_text():
                    raw = Path(f"/proc/{proc.pid}/environ").read_bytes()
                    return dict(e.split("=", 1) for e in raw.decode().split("\0") if "=" in e)
            except OSError:
                pass
            time.sleep(0.01)
        raise AssertionError(f"the program did not start: {proc.communicate()[1]!r}")
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or not os.confstr("CS_GNU_LIBC_VERSION").startswith("glibc"),
    reason="glibc's tunables and /proc (Linux with glibc)",
)
def test_the_program_runs_with_the_advice_unless_told_not_to(tmp_path):
    tunables = _program_environment(tmp_path).get("GLIBC_TUNABLES", "")
    assert HUGE_PAGES_TUNABLE in tunables.split(":")
    assert "GLIBC_TUNABLES" not in _program_environment(tmp_path, FOVJAX_HUGE_PAGES="0")
