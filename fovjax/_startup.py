"""Ctrl-C while the `fovjax` program starts. Imported first by the package's `__init__`, before
JAX, whose start-up takes a second or two."""

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


def _interrupted_while_starting(signum, frame):
    sys.stderr.write("fovjax: interrupted while starting; nothing was written\n")
    sys.stderr.flush()
    os._exit(130)


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
