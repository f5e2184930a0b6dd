"""`fovjax build`: the native handlers built (or found built) and loaded, or the reason they
cannot run here with exit status 1. The build itself is tests/test_native_build.py's and
tests/test_trace_native.py's; here `fovjax.trace.embree_status` (the native handlers' status)
is replaced by each outcome."""

from __future__ import annotations

import pytest

import fovjax.trace
from fovjax.cli import main
from fovjax.native import NativeStatus

READY = "Embree 4.4.0 through XLA's FFI, 16-ray packets"


@pytest.mark.parametrize(("seconds", "how"), [(12.5, "built in 12.5 s"), (0.0, "already built")])
def test_ready_handlers_are_named_with_their_library(monkeypatch, capsys, seconds, how):
    found = NativeStatus(True, READY, library="/cache/native/fovjax_native-0123.so", compile_seconds=seconds)
    monkeypatch.setattr(fovjax.trace, "embree_status", lambda: found)
    assert main(["build"]) == 0
    out = capsys.readouterr().out
    assert f"native handlers: /cache/native/fovjax_native-0123.so ({how}; {READY})" in out


@pytest.mark.parametrize(
    "reason",
    [
        "turned off by FOVJAX_NATIVE=0",
        "no C++ compiler found (set CXX, or install g++)",
        "could not build the native handlers: g++ failed to compile library.cc: error",
    ],
)
def test_handlers_that_cannot_run_exit_1_with_the_reason(monkeypatch, capsys, reason):
    monkeypatch.setattr(fovjax.trace, "embree_status", lambda: NativeStatus(False, reason))
    assert main(["build"]) == 1
    captured = capsys.readouterr()
    assert f"fovjax build: the native handlers cannot run here: {reason}" in captured.err
    assert "JAX ray traversal" in captured.err and "Traceback" not in captured.err
    assert captured.out == ""
