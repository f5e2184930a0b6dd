"""Every environment variable fovjax reads, in one table (`VARIABLES`: name, default, meaning),
the readers that check a value against it (`switch`, `choice`, `path`, `text`), and where the
caches on disk live (`cache_dir`).

A value a reader cannot use raises `EnvironmentVariableError` (a `ValueError`) naming the
variable, the value and what it expects. An unset or empty variable means its default. The
table also names the variables of the benchmarks and the test suite (`scope`), which read them
themselves: the suite's are read before the package is imported. This module imports nothing
of fovjax and nothing heavy: `fovjax._startup` reads it before JAX starts.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

SWITCH, CHOICE, PATH, TEXT = "switch", "choice", "path", "text"
PACKAGE, BENCHMARKS, TESTS = "package", "benchmarks", "tests"


@dataclass(frozen=True)
class Variable:
    """One environment variable: `name`; `kind` (`SWITCH`: 0 or 1; `CHOICE`: one of `choices`;
    `PATH`: a file or folder; `TEXT`); `default`, what an unset variable means, as the docs'
    table writes it; `meaning`, one line; `scope`, who reads it (`PACKAGE`, `BENCHMARKS`,
    `TESTS`)."""

    name: str
    kind: str
    default: str
    meaning: str
    scope: str = PACKAGE
    choices: tuple[str, ...] = ()


VARIABLES: dict[str, Variable] = {
    v.name: v
    for v in (
        Variable(
            "FOVJAX_CACHE_DIR",
            PATH,
            "`$XDG_CACHE_HOME/fovjax`, else `~/.cache/fovjax`",
            "the folder of fovjax's caches on disk: `bvh/`, `lod/`, `xla/` (compiled programs), `native/`",
        ),
        Variable(
            "FOVJAX_NATIVE_DIR",
            PATH,
            "`$FOVJAX_CACHE_DIR/native`",
            "where the native FFI handler library (Embree queries, the native integrator) is built "
            "and loaded",
        ),
        Variable(
            "FOVJAX_NATIVE",
            SWITCH,
            "1",
            "0 turns the native FFI handler off: the JAX traversal and integrator run instead",
        ),
        Variable(
            "FOVJAX_NATIVE_FLAGS",
            TEXT,
            "unset: none",
            "compiler flags added after the project's when the native handlers are built (a later "
            "`-O` wins: `-O0` for a quick build while changing them; `-march=native`); each set of "
            "flags builds its own library",
        ),
        Variable(
            "FOVJAX_NATIVE_SANITIZE",
            SWITCH,
            "0",
            "1 builds the native handlers with AddressSanitizer and UndefinedBehaviorSanitizer (the "
            "process must start with their runtime preloaded: `.ci/sanitize`)",
        ),
        Variable(
            "FOVJAX_KEEP_MEMORY",
            SWITCH,
            "1",
            "importing fovjax keeps malloc's freed memory for the next frame (Linux with glibc); "
            "0 leaves malloc alone",
        ),
        Variable(
            "FOVJAX_SIZE_CHECK",
            SWITCH,
            "1",
            "frames are refused before any work when their estimated memory exceeds what the "
            "machine has free (`fovjax.render.frame_memory`); 0 turns the check off",
        ),
        Variable(
            "FOVJAX_COMPILE_CACHE",
            SWITCH,
            "1",
            "the `fovjax` command keeps compiled programs on disk (`$FOVJAX_CACHE_DIR/xla`); "
            "0 turns that off",
        ),
        Variable(
            "FOVJAX_XLA_EMITTERS",
            CHOICE,
            "auto",
            "XLA:CPU's emitters for frame programs: auto (chosen per program), loop or fusion for every one",
            choices=("auto", "loop", "fusion"),
        ),
        Variable(
            "FOVJAX_AUTO_OTHER_PLATFORMS",
            SWITCH,
            "0",
            'backend "auto" traces the JAX traversal for platforms other than CPU and CUDA only where JAX '
            "sees such a device; 1 always (to export a program for them)",
        ),
        Variable(
            "FOVJAX_ISENSE_LIB",
            PATH,
            "the system's search for `isense`",
            "the InterSense SDK library the head tracker loads (`InterSenseSource(library_path=)` wins)",
        ),
        Variable(
            "FOVJAX_VIEWPOINT_LIB",
            PATH,
            "the system's search for `VPX_InterApp`",
            "the ViewPoint SDK library the eye tracker loads (`ViewPointSource(library_path=)` wins)",
        ),
        Variable(
            "FOVJAX_BENCH_RECORD",
            SWITCH,
            "1",
            "0 runs a benchmark without writing its record",
            scope=BENCHMARKS,
        ),
        Variable(
            "FOVJAX_BENCH_COMMIT",
            TEXT,
            "git's `HEAD`",
            "the commit a benchmark record names where git cannot say (a copy without `.git`)",
            scope=BENCHMARKS,
        ),
        Variable(
            "FOVJAX_KEEP_HLO",
            SWITCH,
            "0",
            "1 keeps the XLA dumps `benchmarks/profile_frame.py` reads",
            scope=BENCHMARKS,
        ),
        Variable(
            "FOVJAX_TYPECHECK",
            SWITCH,
            "1",
            "the tests check the package's jaxtyping annotations as they run; 0 turns that off",
            scope=TESTS,
        ),
        Variable(
            "FOVJAX_REQUIRE_EXTRAS",
            SWITCH,
            "0",
            "1 fails, rather than skips, a test whose optional extra is missing",
            scope=TESTS,
        ),
        Variable(
            "FOVJAX_TEST_FAST_COMPILE",
            SWITCH,
            "1",
            "the tests compile for a short compile; 0 compiles as users' programs do",
            scope=TESTS,
        ),
        Variable(
            "FOVJAX_TEST_SHARED_COMPILES",
            SWITCH,
            "1",
            "one run's workers share what they compile; 0 turns that off",
            scope=TESTS,
        ),
        Variable(
            "FOVJAX_TEST_COMPILE_DIR",
            PATH,
            "a fresh folder per run",
            "the folder a run's workers share compiled programs in (set by the run's first process)",
            scope=TESTS,
        ),
        Variable(
            "FOVJAX_TEST_COMPILE_LOG",
            PATH,
            "unset: no log",
            "a folder each worker logs its compile times to (`tests/compile_report.py` sums them)",
            scope=TESTS,
        ),
        Variable(
            "FOVJAX_IWER_DIR",
            PATH,
            "`~/.cache/fovjax/iwer-<version>`",
            "where the WebXR emulator (the npm package `iwer`) for `tests/test_view_xr.py` is installed",
            scope=TESTS,
        ),
        Variable(
            "FOVJAX_FVVDP_MEDIA",
            PATH,
            "unset: that check skips",
            "a folder holding FovVideoVDP's example image, for the check against its published value",
            scope=TESTS,
        ),
    )
}


class EnvironmentVariableError(ValueError):
    """An environment variable fovjax reads holds a value it cannot use."""


def _value(name: str, kind: str, environ: Mapping[str, str] | None) -> str | None:
    """`name`'s value, stripped; None where it is unset or empty. `name` must be in the table
    with `kind` (a reader for a variable the table does not list is a mistake in fovjax)."""
    variable = VARIABLES.get(name)
    if variable is None or variable.kind != kind:
        raise KeyError(f"{name} is not a {kind} in fovjax._environment.VARIABLES")
    value = (os.environ if environ is None else environ).get(name)
    if value is None or not value.strip():
        return None
    return value.strip()


def _error(name: str, value: str, expected: str) -> EnvironmentVariableError:
    return EnvironmentVariableError(f"environment variable {name}={value!r}: expected {expected}")


def switch(name: str, environ: Mapping[str, str] | None = None) -> bool:
    """The on/off switch `name`: "1" on, "0" off, unset or empty its default.

    Raises:
        EnvironmentVariableError: any other value.
    """
    value = _value(name, SWITCH, environ)
    if value is None:
        return VARIABLES[name].default == "1"
    if value not in ("0", "1"):
        raise _error(name, value, "0 (off) or 1 (on)")
    return value == "1"


def choice(name: str, environ: Mapping[str, str] | None = None) -> str:
    """The choice `name`: one of its `choices`, unset or empty its default.

    Raises:
        EnvironmentVariableError: a value that is not one of the choices.
    """
    value = _value(name, CHOICE, environ)
    variable = VARIABLES[name]
    if value is None:
        return variable.default
    if value not in variable.choices:
        raise _error(name, value, "one of " + ", ".join(variable.choices))
    return value


def path(name: str, environ: Mapping[str, str] | None = None) -> Path | None:
    """The file or folder `name` names (a leading `~` expanded), None where it is unset or empty.
    Whether it exists is for its reader to check, which can say what it wanted it for."""
    value = _value(name, PATH, environ)
    return None if value is None else Path(value).expanduser()


def text(name: str, environ: Mapping[str, str] | None = None) -> str | None:
    """The text `name` holds, None where it is unset or empty."""
    return _value(name, TEXT, environ)


def cache_dir(*parts: str, environ: Mapping[str, str] | None = None) -> Path:
    """The folder of one of fovjax's caches on disk: `$FOVJAX_CACHE_DIR/<parts>`, else
    `$XDG_CACHE_HOME/fovjax/<parts>` (an absolute `XDG_CACHE_HOME` only, as the XDG
    specification says), else `~/.cache/fovjax/<parts>`. `cache_dir("bvh")`, `cache_dir("xla")`.
    Not created here: each cache makes its folder when it first writes, and says when it cannot.
    """
    root = path("FOVJAX_CACHE_DIR", environ)
    if root is None:
        xdg = (os.environ if environ is None else environ).get("XDG_CACHE_HOME", "")
        base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".cache"
        root = base / "fovjax"
    return root.joinpath(*parts)
