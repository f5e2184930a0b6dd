"""What a newcomer sees first: `fovjax` alone, `--version`, `--help`, warnings as one line, no
Warp start-up noise on a machine without an NVIDIA device, and a speed line that says what it
compares."""

from __future__ import annotations

import os
import types
from pathlib import Path

import pytest

import fovjax
import fovjax.trace
from fovjax.cli import main


def test_fovjax_alone_prints_help_and_renders_nothing(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main([]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: fovjax") and "first steps:" in out and "render" in out
    assert not list(tmp_path.iterdir())  # no render into ./out


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out == f"fovjax {fovjax.__version__}\n"


def test_help_opens_with_what_fovjax_is(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    description = out.split("\n\n")[1]
    assert description.startswith("fovjax: foveated ray tracing for eye-tracked stereo head-mounted displays")
    assert "`_render`" not in out and "subcommand has its own module" not in out


class _Stop(BaseException):
    """Raised where the command would build its BVH."""


def test_a_library_warning_is_one_line_naming_the_file_and_line(tmp_path, monkeypatch, capsys):
    obj = tmp_path / "grey.obj"
    obj.write_text("mtllib missing.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl red\nf 1 2 3\n")

    def stop(*args, **kwargs):
        raise _Stop

    monkeypatch.setattr(fovjax.trace, "build_bvh", stop)
    with pytest.raises(_Stop):
        main(
            [
                "render",
                "--scene",
                str(obj),
                "--mono",
                "--width",
                "8",
                "--height",
                "8",
                "-o",
                str(tmp_path / "x.png"),
            ]
        )
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("fovjax render: warning")]
    assert lines == [
        f"fovjax render: warning: {obj}:1: material library 'missing.mtl' not found (looked for "
        f"{tmp_path / 'missing.mtl'}); materials ['red'] render in the default grey"
    ]
    assert "UserWarning" not in err


def _fake_warp(lines: list[bytes]):
    """A module whose `init` writes `lines` to the process's stderr (fd 2), as Warp's native
    library does."""

    def init():
        for line in lines:
            os.write(2, line)

    return types.SimpleNamespace(init=init)


NO_DRIVER = (
    b"Warp CUDA warning: Could not find or load the NVIDIA CUDA driver. GPU execution will not be "
    b"available.\n"
)


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="fd 2 is captured the POSIX way")
def test_warps_no_driver_line_is_left_out_without_an_nvidia_device(monkeypatch, capfd):
    from fovjax.trace import _warp

    monkeypatch.setattr(_warp, "_nvidia_device_present", lambda: False)
    _warp._init_quietly(_fake_warp([NO_DRIVER, b"Warp: something else went wrong\n"]))
    err = capfd.readouterr().err
    assert err == "Warp: something else went wrong\n"  # the rest is passed on
    # Where an NVIDIA device is present, a driver that does not load is news: said.
    monkeypatch.setattr(_warp, "_nvidia_device_present", lambda: True)
    _warp._init_quietly(_fake_warp([NO_DRIVER]))
    assert capfd.readouterr().err == NO_DRIVER.decode()


def _stats(rays, seconds):
    return types.SimpleNamespace(rays=rays, render_seconds=seconds)


def test_the_speed_line_says_what_it_compares_and_slower_below_one():
    from fovjax.cli._render import _speed_text

    faster = _speed_text(_stats(1_000, 0.1), _stats(10_000, 0.42))
    assert "time of one frame each, compiling not counted, 0.10 s vs 0.42 s" in faster
    assert "the foveated frame 4.2x faster" in faster
    slower = _speed_text(_stats(1_000, 0.3), _stats(10_000, 0.1))
    assert "the foveated frame 3.0x slower" in slower and "faster" not in slower
