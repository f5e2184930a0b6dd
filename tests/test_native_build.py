"""How the native handlers are built (`fovjax.native._library`): GCC's parallel back end first
and a plain build where it fails, the library's name per choice, the background build and what
the size check estimates while it runs, and what `fovjax render` says and writes first.

The compilers here are shell scripts that write an empty "library" (nothing is compiled, so
each case takes a moment); the real build from a fresh directory is in test_trace_native.py."""

from __future__ import annotations

import stat
import sys
import threading
import types
from pathlib import Path

import pytest

import fovjax
import fovjax.trace
from fovjax.native import _library
from fovjax.render import RenderConfig

GCC_VERSION = "g++ (Debian 12.2.0-14) 12.2.0\nCopyright (C) 2022 Free Software Foundation, Inc.\n"
CLANG_VERSION = "Debian clang version 16.0.6 (15)\nTarget: x86_64-pc-linux-gnu\n"

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the handlers build on Linux")


def _compiler(tmp_path: Path, version: str, *, lto_fails: bool = False) -> tuple[str, Path]:
    """A compiler script printing `version`, logging each build's arguments, failing a build
    with `-flto=auto` where `lto_fails`, and otherwise writing an empty file at `-o`."""
    log = tmp_path / "builds.log"
    fail = 'case " $* " in *" -flto=auto "*) echo "lto1: fatal error: no LTO support" >&2; exit 1;; esac\n'
    script = tmp_path / "fake-c++"
    script.write_text(
        "#!/bin/sh\n"
        f'if [ "$1" = "--version" ]; then printf %s "{version}"; exit 0; fi\n'
        f'echo "$*" >> "{log}"\n'
        + (fail if lto_fails else "")
        + 'while [ $# -gt 0 ]; do if [ "$1" = "-o" ]; then : > "$2"; fi; shift; done\n'
    )
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    return str(script), log


def _builds(log: Path) -> list[list[str]]:
    return [line.split() for line in log.read_text().splitlines()] if log.exists() else []


@pytest.fixture
def native_dir(tmp_path, monkeypatch):
    folder = tmp_path / "native"
    monkeypatch.setenv("FOVJAX_NATIVE_DIR", str(folder))
    monkeypatch.delenv("FOVJAX_NATIVE_SANITIZE", raising=False)
    return folder


def test_gcc_builds_with_its_parallel_back_end(tmp_path, native_dir):
    compiler, log = _compiler(tmp_path, GCC_VERSION)
    path, seconds = _library.build(compiler)
    assert path == _library.library_path(compiler, _library.FLAGS + _library.PARALLEL_FLAGS)
    assert path.exists() and seconds > 0
    (args,) = _builds(log)
    assert "-flto=auto" in args and "-O3" in args
    # Built: the next call loads it, compiling nothing.
    assert _library.build(compiler) == (path, 0.0) and len(_builds(log)) == 1


def test_a_gcc_without_link_time_optimisation_builds_plainly(tmp_path, native_dir):
    compiler, log = _compiler(tmp_path, GCC_VERSION, lto_fails=True)
    path, _ = _library.build(compiler)
    assert path == _library.library_path(compiler, _library.FLAGS)
    first, second = _builds(log)
    assert "-flto=auto" in first and "-flto=auto" not in second
    assert [p.name for p in native_dir.iterdir()] == [path.name]  # no temporary file left
    # The plain library is found next time without trying the parallel build again.
    assert _library.build(compiler) == (path, 0.0) and len(_builds(log)) == 2


def test_other_compilers_build_plainly_and_the_names_differ_per_choice(tmp_path, native_dir):
    compiler, log = _compiler(tmp_path, CLANG_VERSION)
    path, _ = _library.build(compiler)
    assert path == _library.library_path(compiler, _library.FLAGS)
    (args,) = _builds(log)
    assert not any(a.startswith("-flto") for a in args)
    assert _library.library_path(compiler, _library.FLAGS + _library.PARALLEL_FLAGS) != path


def test_a_build_that_fails_both_ways_says_why(tmp_path, native_dir):
    script = tmp_path / "broken-c++"
    script.write_text(
        f'#!/bin/sh\nif [ "$1" = "--version" ]; then printf %s "{GCC_VERSION}"; exit 0; fi\n'
        'echo "library.cc:1:1: error: this compiler is broken" >&2; exit 1\n'
    )
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    with pytest.raises(
        RuntimeError, match="broken-c\\+\\+ failed to compile library.cc: .*error: this compiler is broken"
    ):
        _library.build(str(script))
    assert not native_dir.exists() or not list(native_dir.iterdir())


def test_the_background_build_is_what_status_loads(tmp_path, native_dir, monkeypatch):
    """`start_build` compiles in a thread; `building()` holds until `status()` takes its result."""
    compiler, log = _compiler(tmp_path, GCC_VERSION)
    monkeypatch.setattr(_library, "_state", {})
    monkeypatch.setattr(_library, "_background", {})
    monkeypatch.setattr(_library, "_prerequisites", lambda: (compiler, "libembree4.so"))
    release = threading.Event()
    build = _library.build

    def slow_build(*args, **kwargs):
        release.wait(30)
        return build(*args, **kwargs)

    monkeypatch.setattr(_library, "build", slow_build)
    path = _library.start_build()
    assert path == _library.library_path(compiler, _library.FLAGS + _library.PARALLEL_FLAGS)
    assert _library.building() and not path.exists()
    assert _library.start_build() is None  # one build at a time
    release.set()
    # The empty "library" does not load: status() says so, naming the file the thread built.
    found = _library.status()
    assert not found and str(path) in found.reason
    assert not _library.building() and len(_builds(log)) == 1
    assert _library.start_build() is None  # the status is known: nothing more to build


def test_nothing_starts_where_the_library_is_built_or_cannot_be(tmp_path, native_dir, monkeypatch):
    compiler, log = _compiler(tmp_path, GCC_VERSION)
    monkeypatch.setattr(_library, "_state", {})
    monkeypatch.setattr(_library, "_background", {})
    monkeypatch.setattr(_library, "_prerequisites", lambda: (compiler, "libembree4.so"))
    _library.build(compiler)
    assert _library.start_build() is None and not _library.building()
    unavailable = _library.NativeStatus(False, "turned off by FOVJAX_NATIVE=0")
    monkeypatch.setattr(_library, "_prerequisites", lambda: unavailable)
    assert _library.start_build() is None and not _library.building()


def test_the_size_check_estimates_for_the_integrator_the_building_handlers_will_run(monkeypatch):
    """While the handlers build in the background, a frame's estimate is that of the integrator
    they will run, without waiting for them (the frame checks again once they are loaded)."""
    from fovjax.native import _dispatch
    from fovjax.render import _memory

    monkeypatch.setattr(_library, "_background", {"thread": threading.Thread()})
    monkeypatch.setattr(_dispatch, "status", lambda: pytest.fail("the estimate waited for the build"))
    # A configuration the cached plans have not seen (integrator_plan is cached per config).
    config = RenderConfig(max_depth=7, min_contribution=0.0123)
    assert _memory._integrator(config, "cpu") == "native"
    assert _memory._integrator(RenderConfig(backend="jax", max_depth=7), "cpu") == "jax"
    assert _memory._integrator(RenderConfig(max_depth=300), "cpu") == "jax"
    assert _memory._integrator(RenderConfig(integrator="jax", max_depth=7), "cpu") == "jax"
    assert _memory._integrator(config, "gpu") == "jax"


def test_render_writes_the_foveated_image_before_the_full_frame_renders(monkeypatch, tmp_path, capsys):
    from fovjax.cli import main

    out = tmp_path / "x.png"
    calls = []

    class Stop(BaseException):  # not an error the command reports: it stops the command
        pass

    def save(path, **kwargs):
        Path(path).write_bytes(b"image")

    def fake_render_stereo(*args, **kwargs):
        calls.append(kwargs)
        if "foveation" in kwargs:
            return types.SimpleNamespace(save=save)
        assert out.exists(), "the full frame rendered before the foveated image was written"
        raise Stop

    monkeypatch.setattr(fovjax, "render_stereo", fake_render_stereo)
    monkeypatch.setattr(fovjax.trace, "start_embree_build", lambda: None)  # no build in this test
    argv = ["--scene", "cornell", "--width", "8", "--height", "8", "--no-size-check", "-o", str(out)]
    with pytest.raises(Stop):
        main(["render", *argv])
    assert len(calls) == 2
    err = capsys.readouterr().err
    assert err.index(f"[4/6] writing {out}") < err.index("[5/6] full frame")


def test_the_first_run_note_says_what_is_built_and_compiled_and_where_it_is_kept(capsys):
    from fovjax.cli._render import HANDLERS_TYPICAL, PROGRAMS_TYPICAL, _first_run_note

    cache = Path("/cache/fovjax")
    _first_run_note(cache / "native" / "fovjax_native-0123.so", cache / "xla")
    both = capsys.readouterr().err
    assert f"building the native handlers (C++, {HANDLERS_TYPICAL}" in both
    assert f"compiling the frame programs ({PROGRAMS_TYPICAL})" in both
    assert f"kept in {cache} (native/, xla/) for later runs" in both
    _first_run_note(None, cache / "xla")
    programs = capsys.readouterr().err
    assert "building" not in programs and f"kept in {cache / 'xla'} for later runs" in programs
    _first_run_note(None, None)  # nothing built, nothing compiled the first time: nothing said
    assert capsys.readouterr().err == ""
