"""Files that are either complete or absent, and writes that Ctrl-C cannot cut in half.

`atomic_path(path)` yields a temporary name next to `path` (same folder, same suffix, so format
detection by suffix still works); when the block ends normally the temporary file is renamed
onto `path` (`os.replace`, atomic on POSIX and Windows), otherwise it is removed. A reader, or a
user looking at the folder after an interrupt or a crash, never sees a half-written `path`.

`deferred_interrupt()` holds a Ctrl-C (SIGINT) that arrives inside the block until the block
ends, then raises KeyboardInterrupt; outside the main thread it does nothing (Python delivers
signals to the main thread only).

`interrupt_flag()` is for loops that stop cleanly on Ctrl-C: it yields a `threading.Event` that
a Ctrl-C sets (as well as raising KeyboardInterrupt as usual). A KeyboardInterrupt can be lost
-- raised inside a garbage-collection callback (JAX has one) Python only prints "Exception
ignored" and carries on -- so the loop checks the flag at each step too.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from pathlib import Path


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside `path`; rename it onto `path` when the block succeeds."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.part{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


@contextlib.contextmanager
def interrupt_flag():
    """Yield an Event that Ctrl-C sets while the block runs (and KeyboardInterrupt raised)."""
    flag = threading.Event()
    if (
        threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    ):
        yield flag
        return

    def on_sigint(signum, frame):
        flag.set()
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        yield flag
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def deferred_interrupt():
    """Run the block to its end even when Ctrl-C arrives; raise KeyboardInterrupt after it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending = []

    def hold(signum, frame):
        pending.append(signum)

    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:  # Ctrl-C is ignored anyway
        yield
        return
    try:
        previous = signal.signal(signal.SIGINT, hold)
    except ValueError:  # not the main interpreter's main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if pending:
        raise KeyboardInterrupt
