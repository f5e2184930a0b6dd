"""JAX's persistent compilation cache for fovjax's programs.

A frame program takes 10–40 s to compile on a 2-core CPU, almost all of it in XLA's backend
(lowering to StableHLO is 1–5 s of it), and that is paid again by every process: each
`fovjax render`, each session. JAX can keep compiled executables on disk, keyed by the program,
the compile options, the device and the JAX/XLA versions; a later process with the same
configuration loads the executable instead of compiling it. `run_compiled` still traces and
lowers the program (so trace counts and `compile_seconds` stay meaningful), only XLA's compile
is skipped.

The cache is process-wide JAX configuration, so the library never turns it on by itself: the
command line does (unless `FOVJAX_COMPILE_CACHE=0` or JAX already has a cache directory), and
library users call `enable_compile_cache()`.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import jax

from .. import _environment

# Only programs that took at least this long to compile are written (JAX's default too): the
# frame programs, not the many small helper jits.
MIN_COMPILE_SECONDS = 1.0
# A bound on the directory's size, enforced by JAX's LRU eviction; that needs `filelock`,
# which also serialises concurrent readers and writers (several processes, pytest-xdist).
MAX_BYTES = 2 << 30


def compile_cache_dir() -> Path:
    """Where `enable_compile_cache()` keeps executables by default: `$FOVJAX_CACHE_DIR/xla`, else
    `$XDG_CACHE_HOME/fovjax/xla` (`~/.cache/fovjax/xla`), beside the BVH and LOD caches."""
    return _environment.cache_dir("xla")


def enable_compile_cache(directory: str | os.PathLike | None = None) -> Path | None:
    """Turn on JAX's persistent compilation cache in `directory` (default `compile_cache_dir()`).

    Returns the directory in use, or None when the cache stays off: the directory cannot be
    created or written (a cache is an optimisation, so that is not an error; the reason is
    returned by `compile_cache_problem`). If JAX already has a cache directory (the user set
    `jax_compilation_cache_dir` or `JAX_COMPILATION_CACHE_DIR`), that one is kept and returned.
    """
    global _PROBLEM
    # jax.config's options are set at run time (pyright cannot see it).
    current = jax.config.jax_compilation_cache_dir  # pyright: ignore[reportAttributeAccessIssue]
    if current:
        return Path(current)
    path = Path(directory) if directory is not None else compile_cache_dir()
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as err:
        _PROBLEM = f"compile cache off: cannot write {path} ({err.strerror or err})"
        return None
    _PROBLEM = None
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    if importlib.util.find_spec("filelock") is not None:
        jax.config.update("jax_compilation_cache_max_size", MAX_BYTES)
    jax.config.update("jax_compilation_cache_dir", str(path))
    return path


_PROBLEM: str | None = None


def compile_cache_entries() -> int | None:
    """How many compiled programs JAX's persistent cache holds in the directory in use, None
    where the cache is off: 0 on a machine's first run, when every frame program compiles."""
    # jax.config's options are set at run time (pyright cannot see it).
    current = jax.config.jax_compilation_cache_dir  # pyright: ignore[reportAttributeAccessIssue]
    if not current:
        return None
    try:
        # One "<key>-cache" file per program (and its "<key>-atime" beside it, for eviction).
        return sum(1 for p in Path(current).iterdir() if p.name.endswith("-cache"))
    except OSError:  # not created yet: nothing written
        return 0


def compile_cache_problem() -> str | None:
    """Why the last `enable_compile_cache()` left the cache off (None if it did not)."""
    return _PROBLEM
