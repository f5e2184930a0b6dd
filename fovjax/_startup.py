"""What the `fovjax` program does as it starts, imported first by the package's `__init__`,
before JAX (whose start-up takes a second or two): large buffers on huge pages, and Ctrl-C."""

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


# glibc's malloc advises the kernel to back its large blocks with transparent huge pages. A frame
# program's buffers are allocated and freed by XLA on every call, so every call faults its pages
# in afresh (hundreds of MiB a full frame, `benchmarks/mitsuba_frame.py`'s "fresh MiB"); with
# 2 MiB pages instead of 4 KiB that costs a fraction of the kernel time
# (`benchmarks/huge_pages.py` compares both, alternating processes). The setting is read
# when a process starts, so the program starts itself again with it; a script that imports
# fovjax sets it itself (docs/how-to-choose.md, "Speed switches").
HUGE_PAGES_TUNABLE = "glibc.malloc.hugetlb=1"


def huge_pages_environment(environ, platform: str = sys.platform, libc: str | None = None) -> str | None:
    """The `GLIBC_TUNABLES` value that adds `HUGE_PAGES_TUNABLE` to `environ`'s, or None where
    nothing is to change: not Linux with glibc, `FOVJAX_HUGE_PAGES=0`, or the tunable (any
    value of it) already set."""
    if libc is None:
        try:
            libc = os.confstr("CS_GNU_LIBC_VERSION") or ""
        except (ValueError, OSError):
            libc = ""
    if not platform.startswith("linux") or not libc.startswith("glibc"):
        return None
    if environ.get("FOVJAX_HUGE_PAGES", "1") == "0":
        return None
    current = environ.get("GLIBC_TUNABLES", "")
    if "glibc.malloc.hugetlb" in current:
        return None
    return f"{current}:{HUGE_PAGES_TUNABLE}" if current else HUGE_PAGES_TUNABLE


def huge_pages_in_use() -> bool:
    """Whether this process started with `HUGE_PAGES_TUNABLE`."""
    return HUGE_PAGES_TUNABLE in os.environ.get("GLIBC_TUNABLES", "").split(":")


def relaunch_with_huge_pages() -> None:
    """Start this process again (the same interpreter, options and arguments, `os.execv`: the
    same process id and open files) with `HUGE_PAGES_TUNABLE`, where `huge_pages_environment`
    says so; where it cannot, go on as it is. Call it before JAX starts."""
    tunables = huge_pages_environment(os.environ)
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
    except OSError:  # this process goes on with the pages it has
        if before is None:
            del os.environ["GLIBC_TUNABLES"]
        else:
            os.environ["GLIBC_TUNABLES"] = before


def _interrupted_while_starting(signum, frame):
    sys.stderr.write("fovjax: interrupted while starting; nothing was written\n")
    sys.stderr.flush()
    os._exit(130)


if _running_as_the_program():
    relaunch_with_huge_pages()

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
