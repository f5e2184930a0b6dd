"""The `fovjax` program starts itself with its malloc settings (fovjax/_startup.py: freed memory
kept; huge pages for large blocks where asked): the environment it adds, what it leaves alone,
and the running program's own environment, read from /proc."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fovjax._startup import (
    HUGE_PAGES_TUNABLE,
    KEPT_MEMORY_TUNABLES,
    malloc_environment,
)

REPO = Path(__file__).resolve().parents[1]
GLIBC = "glibc 2.36"


KEPT = ":".join(KEPT_MEMORY_TUNABLES)
BOTH = f"{HUGE_PAGES_TUNABLE}:{KEPT}"


@pytest.mark.parametrize(
    ("environ", "platform", "libc", "expected"),
    [
        ({}, "linux", GLIBC, KEPT),
        # a user's own tunables are kept, the settings appended
        (
            {"GLIBC_TUNABLES": "glibc.malloc.tcache_count=0"},
            "linux",
            GLIBC,
            f"glibc.malloc.tcache_count=0:{KEPT}",
        ),
        # a user's own choice of a tunable the settings use wins, whatever its value
        ({"GLIBC_TUNABLES": "glibc.malloc.arena_max=2"}, "linux", GLIBC, None),
        (
            {"GLIBC_TUNABLES": "glibc.malloc.mmap_max=9", "FOVJAX_HUGE_PAGES": "1"},
            "linux",
            GLIBC,
            f"glibc.malloc.mmap_max=9:{HUGE_PAGES_TUNABLE}",
        ),
        (
            {"GLIBC_TUNABLES": "glibc.malloc.hugetlb=0", "FOVJAX_HUGE_PAGES": "1"},
            "linux",
            GLIBC,
            f"glibc.malloc.hugetlb=0:{KEPT}",
        ),
        # each setting has its own switch: huge pages opt-in, kept memory opt-out
        ({"FOVJAX_HUGE_PAGES": "1"}, "linux", GLIBC, BOTH),
        ({"FOVJAX_HUGE_PAGES": "0"}, "linux", GLIBC, KEPT),
        ({"FOVJAX_KEEP_MEMORY": "0"}, "linux", GLIBC, None),
        ({"FOVJAX_HUGE_PAGES": "1", "FOVJAX_KEEP_MEMORY": "0"}, "linux", GLIBC, HUGE_PAGES_TUNABLE),
        ({}, "darwin", "", None),
        ({}, "linux", "", None),  # musl and others: no glibc tunables
    ],
)
def test_the_environment_it_adds(environ, platform, libc, expected):
    assert malloc_environment(environ, platform=platform, libc=libc) == expected


def test_a_switch_that_is_not_0_or_1_is_named_and_the_default_kept(capsys):
    environ = {"FOVJAX_KEEP_MEMORY": "no", "FOVJAX_HUGE_PAGES": "yes"}
    assert malloc_environment(environ, platform="linux", libc=GLIBC) == KEPT
    err = capsys.readouterr().err
    assert "FOVJAX_KEEP_MEMORY='no' is not 0 or 1; using 1" in err
    assert "FOVJAX_HUGE_PAGES='yes' is not 0 or 1; using 0" in err


def _environ(raw: bytes) -> dict[str, str]:
    """A process's environment from /proc/PID/environ. glibc (2.36) parses GLIBC_TUNABLES in
    place, writing a NUL over each ':' between tunables, so the tunables after the first read
    as entries of their own ("glibc.malloc...."): they are joined back."""
    env: dict[str, str] = {}
    last = None
    for entry in raw.decode().split("\0"):
        if last == "GLIBC_TUNABLES" and entry.startswith("glibc."):
            env[last] += ":" + entry
        elif "=" in entry:
            last, value = entry.split("=", 1)
            env[last] = value
    return env


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
                    return _environ(Path(f"/proc/{proc.pid}/environ").read_bytes())
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
def test_the_program_runs_with_the_settings_unless_told_not_to(tmp_path):
    tunables = _program_environment(tmp_path).get("GLIBC_TUNABLES", "").split(":")
    assert set(KEPT_MEMORY_TUNABLES) <= set(tunables)
    assert HUGE_PAGES_TUNABLE not in tunables
    switched = _program_environment(tmp_path, FOVJAX_HUGE_PAGES="1", FOVJAX_KEEP_MEMORY="0")
    assert switched.get("GLIBC_TUNABLES") == HUGE_PAGES_TUNABLE


def test_render_says_how_malloc_runs(monkeypatch):
    from fovjax.cli._render import _pages

    monkeypatch.setenv("GLIBC_TUNABLES", KEPT)
    assert _pages().startswith("freed memory kept for the next frame; no huge pages")
    monkeypatch.setenv("GLIBC_TUNABLES", BOTH)
    assert "transparent huge pages" in _pages()
    monkeypatch.delenv("GLIBC_TUNABLES")
    assert _pages() == "freed memory returned; no huge pages (GLIBC_TUNABLES=unset)"
