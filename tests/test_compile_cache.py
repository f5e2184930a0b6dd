"""The persistent compilation cache the command line turns on (`fovjax.render.enable_compile_cache`).

Each case runs in its own process with its own cache directory: the cache is process-wide JAX
configuration, and the rest of the suite runs without it (conftest)."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from _frames import users_xla_flags

REPO = Path(__file__).resolve().parents[1]
# Reflection depth 1: the JAX integrator's frame program then compiles in about half the time of
# depth 5's (still seconds, well over the cache's 1 s threshold); the Cornell box has no mirror, so
# the frame is the same.
RENDER = ["render", "--scene", "cornell", "--width", "8", "--height", "8", "--mono", "--spp", "1"]
RENDER += ["--max-depth", "1"]


def _fovjax(argv, cache_dir, **env):
    environment = dict(
        os.environ,
        PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""),
        FOVJAX_CACHE_DIR=str(cache_dir),
        FOVJAX_COMPILE_CACHE="1",
    )
    environment.update(env)
    return subprocess.run(
        [sys.executable, "-m", "fovjax", *argv], capture_output=True, text=True, env=environment, timeout=600
    )


def _entries(directory: Path) -> set[str]:
    return {p.name for p in directory.glob("*-cache")} if directory.exists() else set()


def test_a_second_run_loads_the_programs_the_first_compiled(tmp_path):
    """Two runs compiled as users' are (the suite compiles for a short compile,
    conftest): the second loads every program the first wrote. A third run, compiled the suite's way
    with a cache it cannot write, says so, goes on and renders the same frame to within one 8-bit
    step (tests/_frames.py: the same arithmetic, rounded apart)."""
    import imageio.v3 as iio

    cache = tmp_path / "cache"
    # The JAX integrator (no native handler): its frame program compiles for seconds, where the
    # native integrator's can come in under the cache's 1 s threshold.
    users = {"XLA_FLAGS": users_xla_flags(), "FOVJAX_NATIVE": "0"}
    first = _fovjax([*RENDER, "-o", str(tmp_path / "a.png")], cache, **users)
    assert first.returncode == 0, first.stderr
    written = _entries(cache / "xla")
    # The frame program takes well over the 1 s threshold to compile, so it was written.
    assert any(name.startswith("jit_counted") for name in written), written
    # The first run says what it compiles and where it keeps it; the second has nothing to say.
    note = "first run on this machine: compiling the frame programs (longer without the native handlers)"
    assert note in first.stderr and f"kept in {cache / 'xla'} for later runs" in first.stderr
    second = _fovjax([*RENDER, "-o", str(tmp_path / "b.png")], cache, **users)
    assert second.returncode == 0, second.stderr
    assert "first run" not in second.stderr
    # Every program of the second run came from the cache: nothing new was written.
    assert _entries(cache / "xla") == written
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()

    # A third run compiled the suite's way (with the native integrator, which agrees with the
    # JAX one to float rounding: tests/test_render_native.py), its cache directory under a
    # regular file (it cannot be created, whoever runs the test, root too): said once and
    # skipped, the same frame to within one 8-bit step.
    # The native handlers are the suite's (already built; the cache directory that would hold
    # them is the one that cannot be written).
    import fovjax.native

    built = fovjax.native.status()
    assert built and built.library, built.reason
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    library = {"FOVJAX_NATIVE_DIR": str(Path(built.library).parent)}
    suite = _fovjax([*RENDER, "-o", str(tmp_path / "c.png")], blocker / "cache", **library)
    assert suite.returncode == 0, suite.stderr
    assert "compile cache off: cannot write" in suite.stderr and str(blocker) in suite.stderr
    assert "Traceback" not in suite.stderr
    assert "integrator: native" in suite.stdout, suite.stdout
    users_frame = iio.imread(tmp_path / "a.png").astype(int)
    suite_frame = iio.imread(tmp_path / "c.png").astype(int)
    assert users_frame.shape == suite_frame.shape
    assert np.abs(users_frame - suite_frame).max() <= 1


def test_the_switch_turns_the_cache_off(monkeypatch):
    """`FOVJAX_COMPILE_CACHE=0`: the command line leaves JAX's cache as it was (off)."""
    import jax

    from fovjax.cli import _compile_cache

    before = jax.config.jax_compilation_cache_dir
    monkeypatch.setenv("FOVJAX_COMPILE_CACHE", "0")
    _compile_cache("fovjax render")
    assert jax.config.jax_compilation_cache_dir == before


def test_a_cache_directory_the_user_configured_is_kept(tmp_path):
    mine = tmp_path / "mine"
    code = (
        "import jax, fovjax\n"
        f"jax.config.update('jax_compilation_cache_dir', {str(mine)!r})\n"
        f"print(fovjax.enable_compile_cache({str(tmp_path / 'other')!r}))\n"
        "print(jax.config.jax_compilation_cache_dir)\n"
    )
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [str(mine), str(mine)]
