"""Files that are either complete or absent, and writes that Ctrl-C cannot cut in half.

`atomic_path(path)` yields a temporary name next to `path` (same folder, same suffix, so format
detection by suffix still works); when the block ends normally the temporary file is renamed
onto `path` (`os.replace`, atomic on POSIX and Windows), otherwise it is removed. A reader, or a
user looking at the folder after an interrupt or a crash, never sees a half-written `path`.

`deferred_interrupt()` holds a Ctrl-C (SIGINT) that arrives inside the block until the block
ends, then raises KeyboardInterrupt; outside the main thread it does nothing (Python delivers
signals to the main thread only). SIGTERM (`kill`'s default signal) is taken as a Ctrl-C by
both (`INTERRUPT_SIGNALS`), so a process asked to stop still finishes its files.

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


# The signals taken as a Ctrl-C: SIGINT itself, and SIGTERM (what `kill` and service managers
# send to ask a process to stop).
INTERRUPT_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def _handling(handler):
    """`handler` for each of `INTERRUPT_SIGNALS` not ignored, while the block runs (nothing
    outside the main interpreter's main thread); the previous handlers restored after."""
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for signum in INTERRUPT_SIGNALS:
            if signal.getsignal(signum) is signal.SIG_IGN:  # a background job: left alone
                continue
            try:
                previous[signum] = signal.signal(signum, handler)
            except ValueError:  # not the main interpreter's main thread
                break
    try:
        yield
    finally:
        for signum, before in previous.items():
            signal.signal(signum, before)


@contextlib.contextmanager
def interrupt_flag():
    """Yield an Event that Ctrl-C (or SIGTERM) sets while the block runs (and KeyboardInterrupt
    raised)."""
    flag = threading.Event()

    def on_interrupt(signum, frame):
        flag.set()
        raise KeyboardInterrupt

    with _handling(on_interrupt):
        yield flag


@contextlib.contextmanager
def deferred_interrupt():
    """Run the block to its end even when Ctrl-C (or SIGTERM) arrives; raise KeyboardInterrupt
    after it."""
    pending = []

    def hold(signum, frame):
        pending.append(signum)

    with _handling(hold):
        yield
    if pending:
        raise KeyboardInterrupt
