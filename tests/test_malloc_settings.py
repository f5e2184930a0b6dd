"""Importing fovjax keeps malloc's freed memory for the next frame (fovjax/_startup.py): glibc's
`mallopt` before JAX starts, in every process, with no re-exec. What it decides from the
environment, what it says, and what a process that imports fovjax gets: kept memory, checked
by the page faults of a freed block used again; malloc untouched where the C library is not
glibc; the call made late, and said, after a JAX computation."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fovjax import _startup
from fovjax._startup import (
    KEPT,
    KEPT_MEMORY_MALLOPT,
    KEPT_MEMORY_TUNABLES,
    LATE,
    NOT_GLIBC,
    OFF,
    REFUSED,
    USERS,
    describe_malloc,
    keep_memory,
)

REPO = Path(__file__).resolve().parents[1]
ON_GLIBC = _startup.glibc_version() is not None


class Mallopt:
    """A stand-in for glibc's mallopt that records its calls and answers `answer`."""

    def __init__(self, answer: int = 1):
        self.calls: list[tuple[int, int]] = []
        self.answer = answer

    def __call__(self, param: int, value: int) -> int:
        self.calls.append((param, value))
        return self.answer


@pytest.fixture
def glibc(monkeypatch):
    """This process as Linux with glibc, whatever runs the test."""
    monkeypatch.setattr(os, "confstr", lambda name: "glibc 2.36", raising=False)
    monkeypatch.setattr(_startup, "_xla_started", lambda: False)


@pytest.mark.parametrize(
    ("environ", "expected", "called"),
    [
        ({}, KEPT, True),
        ({"FOVJAX_KEEP_MEMORY": "1"}, KEPT, True),
        ({"FOVJAX_KEEP_MEMORY": ""}, KEPT, True),  # empty: the default
        ({"FOVJAX_KEEP_MEMORY": "0"}, OFF, False),
        # a user's own tunables that name none of the settings leave them to fovjax
        ({"GLIBC_TUNABLES": "glibc.malloc.tcache_count=0"}, KEPT, True),
        ({"GLIBC_TUNABLES": f"glibc.malloc.hugetlb=1:{KEPT_MEMORY_TUNABLES[0]}"}, USERS, False),
        # a user's own choice of one of the settings wins, whatever its value
        ({"GLIBC_TUNABLES": "glibc.malloc.arena_max=2"}, USERS, False),
        ({"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=0"}, USERS, False),
    ],
)
def test_what_it_sets_from_the_environment(glibc, environ, expected, called):
    mallopt = Mallopt()
    assert keep_memory(environ, platform="linux", mallopt=mallopt) == expected
    assert mallopt.calls == (list(KEPT_MEMORY_MALLOPT) if called else [])


def test_the_settings_are_one_arena_no_mapped_blocks_no_trimming():
    """glibc's malloc.h numbers: M_ARENA_MAX -8, M_MMAP_MAX -4, M_TRIM_THRESHOLD -1 (-1: the
    largest size_t), the same settings as the tunables a user may set instead."""
    assert dict(KEPT_MEMORY_MALLOPT) == {-8: 1, -4: 0, -1: -1}
    assert [t.split("=")[0] for t in KEPT_MEMORY_TUNABLES] == [
        "glibc.malloc.arena_max",
        "glibc.malloc.mmap_max",
        "glibc.malloc.trim_threshold",
    ]


def test_a_switch_it_cannot_use_is_named_and_malloc_left_alone(glibc, capsys):
    mallopt = Mallopt()
    assert keep_memory({"FOVJAX_KEEP_MEMORY": "no"}, platform="linux", mallopt=mallopt) == OFF
    assert mallopt.calls == []
    err = capsys.readouterr().err
    assert "FOVJAX_KEEP_MEMORY='no'" in err and "0 (off) or 1 (on)" in err and "malloc left" in err


def test_after_xla_started_it_still_sets_them_and_says_late(glibc, monkeypatch):
    monkeypatch.setattr(_startup, "_xla_started", lambda: True)
    mallopt = Mallopt()
    assert keep_memory({}, platform="linux", mallopt=mallopt) == LATE
    assert mallopt.calls == list(KEPT_MEMORY_MALLOPT)


def test_a_refused_setting_is_said(glibc):
    assert keep_memory({}, platform="linux", mallopt=Mallopt(answer=0)) == REFUSED


@pytest.mark.parametrize("platform", ["win32", "darwin", "linux"])
def test_without_glibc_nothing_is_set_or_said(monkeypatch, capsys, platform):
    """Windows has no `os.confstr`; macOS has no glibc; Linux with musl answers no glibc."""
    monkeypatch.delattr(os, "confstr", raising=False)
    mallopt = Mallopt()
    assert keep_memory({}, platform=platform, mallopt=mallopt) == NOT_GLIBC
    monkeypatch.setattr(os, "confstr", lambda name: "", raising=False)  # musl
    assert keep_memory({}, platform=platform, mallopt=mallopt) == NOT_GLIBC

    def unknown(name):
        raise ValueError(f"unrecognized configuration name {name!r}")

    monkeypatch.setattr(os, "confstr", unknown, raising=False)
    assert keep_memory({}, platform=platform, mallopt=mallopt) == NOT_GLIBC
    assert mallopt.calls == []
    assert capsys.readouterr() == ("", "")
    assert describe_malloc(NOT_GLIBC, {}) is None


def test_what_fovjax_render_says_about_memory():
    assert describe_malloc(KEPT, {}) == "freed memory kept for the next frame"
    assert "main thread only" in describe_malloc(LATE, {})
    assert "import fovjax before the first JAX computation" in describe_malloc(LATE, {})
    assert describe_malloc(OFF, {"FOVJAX_KEEP_MEMORY": "0"}) == "freed memory returned (FOVJAX_KEEP_MEMORY=0)"
    assert "refused" in describe_malloc(REFUSED, {})
    kept = {"GLIBC_TUNABLES": ":".join(KEPT_MEMORY_TUNABLES)}
    assert describe_malloc(USERS, kept) == "freed memory kept for the next frame (your GLIBC_TUNABLES)"
    assert describe_malloc(USERS, {"GLIBC_TUNABLES": "glibc.malloc.arena_max=4"}) == (
        "as your GLIBC_TUNABLES sets it"
    )
    # huge pages: a tunable only (no mallopt parameter), said where the user set it
    huge = describe_malloc(KEPT, {"GLIBC_TUNABLES": "glibc.malloc.hugetlb=1"})
    assert huge == "freed memory kept for the next frame; large blocks on huge pages (glibc.malloc.hugetlb=1)"
    assert "huge" not in describe_malloc(KEPT, {"GLIBC_TUNABLES": "glibc.malloc.hugetlb=0"})
    assert "GLIBC_TUNABLES" not in describe_malloc(KEPT, {})


# A process that imports fovjax as the `fovjax` program would (its argv), with `os.execv`
# forbidden, then frees a 64 MiB block and counts the page faults of using that much again:
# none to speak of where freed memory is kept; where malloc returns it (its defaults map such a
# block and unmap it when freed) every page faults afresh, or every huge page where the kernel
# backs it with them.
CHILD = r"""
import ctypes, json, os, sys
if sys.platform.startswith("linux"):
    import resource
PRE = sys.argv[1]
if PRE == "late":
    import jax
    jax.block_until_ready(jax.numpy.zeros(8) + 1)
elif PRE == "no confstr":
    del os.confstr

def no_execv(*args):
    raise SystemExit("os.execv called at import")

os.execv = no_execv
sys.orig_argv = [sys.executable, "-m", "fovjax"]
import fovjax
from fovjax import _startup

result = {"malloc": _startup.MALLOC}
if sys.platform.startswith("linux"):
    libc = ctypes.CDLL(None)
    libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    size = 64 << 20

    def use_and_free():
        block = libc.malloc(size)
        ctypes.memset(block, 1, size)
        libc.free(block)

    use_and_free()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    use_and_free()
    result["faults"] = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
    result["pages"] = size // os.sysconf("SC_PAGE_SIZE")
print(json.dumps(result))
"""


def _child(pre: str) -> tuple[dict, str]:
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    for name in ("GLIBC_TUNABLES", "FOVJAX_KEEP_MEMORY"):
        env.pop(name, None)
    done = subprocess.run(
        [sys.executable, "-c", CHILD, pre], env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1]), done.stderr


@pytest.fixture(scope="module")
def without_confstr():
    """A process that imports fovjax with no `os.confstr`, as on Windows: its result, stderr."""
    return _child("no confstr")


def test_without_confstr_the_package_imports_and_says_nothing(without_confstr):
    result, err = without_confstr
    assert result["malloc"] == NOT_GLIBC
    assert "fovjax" not in err


@pytest.mark.skipif(not ON_GLIBC, reason="glibc's malloc (Linux with glibc)")
def test_a_process_that_imports_fovjax_keeps_freed_memory_without_a_reexec(without_confstr):
    kept, _ = _child("plain")
    assert kept["malloc"] == KEPT
    assert kept["faults"] < kept["pages"] // 8
    untouched, _ = without_confstr  # malloc's defaults
    assert untouched["faults"] > kept["faults"]


@pytest.mark.skipif(not ON_GLIBC, reason="glibc's malloc (Linux with glibc)")
def test_importing_fovjax_after_a_jax_computation_is_late():
    late, _ = _child("late")
    assert late["malloc"] == LATE
    assert late["faults"] < late["pages"] // 8  # the main thread's blocks are still kept
