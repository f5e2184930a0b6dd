"""What every process that imports fovjax does first, before JAX starts (imported first by the
package's `__init__`): glibc malloc's settings (`keep_memory`), and, for the `fovjax` program,
Ctrl-C while it starts."""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
from collections.abc import Callable, Mapping

from . import _environment

# glibc's malloc as fovjax runs it. XLA allocates a frame program's buffers on every call and
# frees them after; with malloc's defaults each call gets its large blocks as fresh pages from
# the kernel, zeroed and faulted in afresh (hundreds of MiB a full frame,
# `benchmarks/mitsuba_frame.py`'s "fresh MiB"). Kept memory: one arena, no mmap'd blocks, no
# trimming, so a frame's freed buffers serve the next (a caching allocator, as Dr.Jit's and
# PyTorch's are); the peak stays the frames' peak. `mallopt` sets it in the running process, so
# it must run before XLA starts its threads: a thread that has allocated keeps its own arena
# (`M_ARENA_MAX` only bounds new ones), and an arena other than the main one maps its large
# blocks afresh whatever `M_MMAP_MAX` says. Importing JAX starts none; its first computation
# does. `benchmarks/kept_memory.py` measures it against the same settings as glibc tunables read
# at process start and against the defaults, in alternating processes.
M_TRIM_THRESHOLD, M_MMAP_MAX, M_ARENA_MAX = -1, -4, -8  # glibc's malloc.h
KEPT_MEMORY_MALLOPT = (
    (M_ARENA_MAX, 1),
    (M_MMAP_MAX, 0),
    (M_TRIM_THRESHOLD, -1),  # the largest size_t: never trim
)
# The same settings as glibc tunables: a user's GLIBC_TUNABLES naming any of them wins.
KEPT_MEMORY_TUNABLES = (
    "glibc.malloc.arena_max=1",
    "glibc.malloc.mmap_max=0",
    "glibc.malloc.trim_threshold=4294967295",
)
# Large blocks on transparent huge pages: glibc has no mallopt parameter for it, only this
# tunable, read at process start; so it is the user's own choice (docs/how-to-choose.md).
HUGE_PAGES_TUNABLE = "glibc.malloc.hugetlb=1"

# What `keep_memory` found and did.
KEPT = "kept"  # set before XLA started
LATE = "late"  # set after XLA started: its threads keep the arenas they have
OFF = "off"  # FOVJAX_KEEP_MEMORY=0 (or a value it cannot use): malloc left alone
USERS = "user's GLIBC_TUNABLES"  # the user's tunables name a setting: malloc left alone
REFUSED = "refused"  # mallopt is missing or refused a setting
NOT_GLIBC = "not glibc"  # not Linux with glibc: nothing to set, nothing said


def glibc_version(platform: str = sys.platform) -> str | None:
    """This process's C library where it is glibc on Linux ("glibc 2.36"), else None. Never
    raises: `os.confstr` is missing on Windows and may not know the name elsewhere."""
    confstr = getattr(os, "confstr", None)
    if not platform.startswith("linux") or confstr is None:
        return None
    try:
        version = confstr("CS_GNU_LIBC_VERSION") or ""
    except (ValueError, OSError):
        return None
    return version if version.startswith("glibc") else None


def _tunable_names(tunables: str) -> set[str]:
    return {t.split("=", 1)[0] for t in tunables.split(":") if t}


def _xla_started() -> bool:
    """Whether JAX has started a backend (and XLA its threads) in this process."""
    bridge = sys.modules.get("jax._src.xla_bridge")
    started = getattr(bridge, "backends_are_initialized", None)
    return bool(started is not None and started())


def _libc_mallopt() -> Callable[[int, int], int] | None:
    mallopt = getattr(ctypes.CDLL(None), "mallopt", None)
    if mallopt is not None:
        mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return mallopt


def keep_memory(
    environ: Mapping[str, str] | None = None,
    *,
    platform: str = sys.platform,
    mallopt: Callable[[int, int], int] | None = None,
) -> str:
    """Set kept memory (`KEPT_MEMORY_MALLOPT`) with glibc's `mallopt` unless
    FOVJAX_KEEP_MEMORY=0 or the user's GLIBC_TUNABLES name one of its settings; return what was
    found and done (`KEPT`, `LATE`, `OFF`, `USERS`, `REFUSED`, `NOT_GLIBC`). Not on Linux with
    glibc: nothing, silently. A FOVJAX_KEEP_MEMORY it cannot use is said on stderr and malloc
    left alone (this runs at import: no exception). `mallopt`: the function to call (default
    the C library's)."""
    environ = os.environ if environ is None else environ
    if glibc_version(platform) is None:
        return NOT_GLIBC
    try:
        if not _environment.switch("FOVJAX_KEEP_MEMORY", environ):
            return OFF
    except _environment.EnvironmentVariableError as err:
        sys.stderr.write(f"fovjax: {err}; malloc left as it is\n")
        return OFF
    if _tunable_names(environ.get("GLIBC_TUNABLES", "")) & _tunable_names(":".join(KEPT_MEMORY_TUNABLES)):
        return USERS
    late = _xla_started()  # before mallopt: a late call is still made, for the main thread
    mallopt = mallopt or _libc_mallopt()
    if mallopt is None:
        return REFUSED
    if not all([mallopt(param, value) == 1 for param, value in KEPT_MEMORY_MALLOPT]):
        return REFUSED
    return LATE if late else KEPT


def describe_malloc(state: str | None = None, environ: Mapping[str, str] | None = None) -> str | None:
    """How this process's malloc runs, in words (`fovjax render`'s `memory:` line), from
    `keep_memory`'s `state` (default: what it did at import); None where it is not glibc's."""
    state = MALLOC if state is None else state
    environ = os.environ if environ is None else environ
    tunables = environ.get("GLIBC_TUNABLES", "")
    names = set(tunables.split(":"))
    said = {
        KEPT: "freed memory kept for the next frame",
        LATE: (
            "freed memory kept for the main thread only: XLA's threads started before fovjax was "
            "imported (import fovjax before the first JAX computation)"
        ),
        OFF: f"freed memory returned (FOVJAX_KEEP_MEMORY={environ.get('FOVJAX_KEEP_MEMORY', '')})",
        USERS: (
            "freed memory kept for the next frame (your GLIBC_TUNABLES)"
            if {"glibc.malloc.arena_max=1", "glibc.malloc.mmap_max=0"} <= names
            else "as your GLIBC_TUNABLES sets it"
        ),
        REFUSED: "freed memory returned (glibc's mallopt refused the settings)",
    }.get(state)
    if said is None:
        return None
    hugetlb = [t for t in names if t.startswith("glibc.malloc.hugetlb=") and t != "glibc.malloc.hugetlb=0"]
    if hugetlb:
        said += f"; large blocks on huge pages ({hugetlb[0]})"
    return said


def _running_as_the_program() -> bool:
    """True when this import starts the `fovjax` program (console script or `python -m fovjax`)."""
    argv = list(getattr(sys, "orig_argv", sys.argv))
    if any(os.path.basename(a) == "fovjax" for a in argv[:2]):
        return True
    for i, arg in enumerate(argv[1:], start=1):  # the interpreter's own options, up to -m
        if arg == "-m":
            return argv[i + 1 : i + 2] == ["fovjax"]
        if not arg.startswith("-"):
            return False
    return False


def _interrupted_while_starting(signum, frame):
    sys.stderr.write("fovjax: interrupted while starting; nothing was written\n")
    sys.stderr.flush()
    os._exit(130)


# Every process that imports fovjax, the `fovjax` program and a user's script alike.
MALLOC = keep_memory()

# Ctrl-C during the package's imports (JAX starting, a second or two) must end the program as it
# does later (`fovjax.cli.main` installs the handler for the rest of the run): raised there, a
# KeyboardInterrupt can land in one of JAX's garbage-collection callbacks, be printed and
# ignored, and the command would go on. Only the program does this; an importing library keeps
# its own handler, and so does a background job, which ignores SIGINT.
if (
    _running_as_the_program()
    and threading.current_thread() is threading.main_thread()
    and signal.getsignal(signal.SIGINT) is signal.default_int_handler
):
    signal.signal(signal.SIGINT, _interrupted_while_starting)
