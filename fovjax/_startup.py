"""What the `fovjax` program does as it starts, imported first by the package's `__init__`,
before JAX (whose start-up takes a second or two): malloc's settings, and Ctrl-C."""

from __future__ import annotations

import os
import signal
import sys
import threading


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


# glibc's malloc, as the `fovjax` program runs it. XLA allocates a frame program's buffers on
# every call and frees them after; with malloc's defaults each call gets its large blocks as fresh
# pages from the kernel, zeroed and faulted in afresh (hundreds of MiB a full frame,
# `benchmarks/mitsuba_frame.py`'s "fresh MiB"). The program keeps freed memory instead: one
# arena, no mmap'd blocks, no trimming, so a frame's freed buffers serve the next frame (a
# caching allocator, as Dr.Jit's and PyTorch's are). The peak stays the frames' peak.
# `benchmarks/huge_pages.py` measures it against the defaults and against huge pages (2 MiB pages
# for large blocks: fewer faults, but each still zeroed), alone and together, in alternating
# processes: kept memory is the setting that pays; huge pages on top of it did not, and raised
# the peak, so they are opt-in (FOVJAX_HUGE_PAGES=1). The settings are read when a process
# starts, so the program starts itself again with them; a script that imports fovjax sets them
# itself (docs/how-to-choose.md, "Speed switches").
HUGE_PAGES_TUNABLE = "glibc.malloc.hugetlb=1"
KEPT_MEMORY_TUNABLES = (
    "glibc.malloc.arena_max=1",
    "glibc.malloc.mmap_max=0",
    "glibc.malloc.trim_threshold=4294967295",
)


def _names(tunables: str) -> set[str]:
    return {t.split("=", 1)[0] for t in tunables.split(":") if t}


def _switch(environ, name: str, default: bool) -> bool:
    """The on/off switch `name` ("1" or "0"; unset: `default`). Any other value says so on
    stderr, naming it, and keeps the default (the program has not started yet: no traceback)."""
    value = environ.get(name)
    if value in (None, ""):
        return default
    if value not in ("0", "1"):
        sys.stderr.write(f"fovjax: {name}={value!r} is not 0 or 1; using {int(default)}\n")
        return default
    return value == "1"


def malloc_environment(environ, platform: str = sys.platform, libc: str | None = None) -> str | None:
    """The `GLIBC_TUNABLES` value that adds the program's malloc settings to `environ`'s, or None
    where nothing is to change. Not on Linux with glibc: None. Kept memory
    (`KEPT_MEMORY_TUNABLES`) unless `FOVJAX_KEEP_MEMORY=0` or the user set any of those
    tunables; huge pages (`HUGE_PAGES_TUNABLE`) where `FOVJAX_HUGE_PAGES=1` and the user did not
    set `glibc.malloc.hugetlb` (a user's own malloc settings win, whatever their values)."""
    if libc is None:
        try:
            libc = os.confstr("CS_GNU_LIBC_VERSION") or ""
        except (ValueError, OSError):
            libc = ""
    if not platform.startswith("linux") or not libc.startswith("glibc"):
        return None
    current = environ.get("GLIBC_TUNABLES", "")
    have = _names(current)
    add = []
    if _switch(environ, "FOVJAX_HUGE_PAGES", False) and not have & _names(HUGE_PAGES_TUNABLE):
        add.append(HUGE_PAGES_TUNABLE)
    if _switch(environ, "FOVJAX_KEEP_MEMORY", True) and not have & _names(":".join(KEPT_MEMORY_TUNABLES)):
        add.extend(KEPT_MEMORY_TUNABLES)
    if not add:
        return None
    return ":".join([current, *add] if current else add)


def relaunch_with_malloc_settings() -> None:
    """Start this process again (the same interpreter, options and arguments, `os.execv`: the
    same process id and open files) with the program's malloc settings, where
    `malloc_environment` says so; where it cannot, go on as it is. Call it before JAX starts."""
    tunables = malloc_environment(os.environ)
    if tunables is None:
        return
    argv = list(getattr(sys, "orig_argv", ()))
    if not argv or not sys.executable:
        return
    before = os.environ.get("GLIBC_TUNABLES")
    os.environ["GLIBC_TUNABLES"] = tunables
    try:
        sys.stdout.flush()
        sys.stderr.flush()
        os.execv(sys.executable, [sys.executable, *argv[1:]])
    except OSError:  # this process goes on with the malloc it has
        if before is None:
            del os.environ["GLIBC_TUNABLES"]
        else:
            os.environ["GLIBC_TUNABLES"] = before


def _interrupted_while_starting(signum, frame):
    sys.stderr.write("fovjax: interrupted while starting; nothing was written\n")
    sys.stderr.flush()
    os._exit(130)


if _running_as_the_program():
    relaunch_with_malloc_settings()

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
