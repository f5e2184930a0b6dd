"""The `fovjax` command line. Each subcommand has its own module in this package (`_render`,
`_record`, `_session`, `_compare`, `_failures`, `_stability`, `_study`, `_fit`, `_fit_stability`,
`_view`, `_inspect`) and registers itself through a `register(subparsers)` function listed in
`_SUBCOMMAND_MODULES`. This package is the top layer: it may import every other package of
fovjax, and none of them imports it.

Errors: every command checks its arguments first, in one `validate(args)` step, with the checkers
below, which raise `UsageError`. `main` turns any error into one line on stderr naming the
command and a non-zero exit status (2: a bad argument or input file; 1: a device, a missing
extra, or anything else); `fovjax --debug COMMAND ...` shows the Python traceback instead.
Ctrl-C, or SIGTERM (`kill`), ends any command with status 130 after saying which files it
wrote (commands note them with `wrote`). Warnings are one line each, `fovjax COMMAND: warning:
...`. Commands that render check the frame's memory against the machine's first
(`frame_size`, `fovjax.render.check_frame_memory`; `--no-size-check` turns it off for the
command, as `FOVJAX_SIZE_CHECK=0` does everywhere). Commands that write a folder of numbered
files refuse one holding another run's (`output_folder`; `--overwrite` replaces them).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import math
import os
import signal
import sys
import warnings
from pathlib import Path

from .. import _environment
from ..files import INTERRUPT_SIGNALS as INTERRUPT_SIGNALS
from ..files import atomic_path as atomic_path
from ..files import deferred_interrupt as deferred_interrupt

# Modules that define `register(subparsers)`, in the order `fovjax --help` lists them.
_SUBCOMMAND_MODULES = [
    "fovjax.cli._render",
    "fovjax.cli._record",
    "fovjax.cli._session",
    "fovjax.cli._compare",
    "fovjax.cli._failures",
    "fovjax.cli._stability",
    "fovjax.cli._study",
    "fovjax.cli._fit",
    "fovjax.cli._fit_stability",
    "fovjax.cli._view",
    "fovjax.cli._inspect",
    "fovjax.cli._build",
]

# Exit status of an interrupted command (128 + SIGINT), as shells report Ctrl-C.
INTERRUPTED = 130


DESCRIPTION = (
    "fovjax: foveated ray tracing for eye-tracked stereo head-mounted displays (a JAX "
    "reimplementation of the 2020 thesis 'Real-Time Foveated Rendering in Virtual Reality for "
    "Ray-tracing'), and the visual-acuity models that drive it."
)
EPILOG = """first steps:
  fovjax render                      the thesis's stereo frame of the atrium, foveated and in full,
                                     into out/ (two 1280x1024 eyes; the first run compiles for a while)
  fovjax render --scene cornell --width 320 --height 256    a small frame, quickly
  fovjax COMMAND --help              a command's options

documentation: docs/getting-started.md in the repository (or the built site)"""


def _version() -> str:
    from fovjax import __version__

    return f"fovjax {__version__}"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fovjax",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=_version())
    parser.add_argument(
        "--debug", action="store_true", help="show the Python traceback of an error (for bug reports)"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _SUBCOMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run `fovjax` with `argv` (default: the process's arguments) and return the exit status.

    Called as the program (no `argv`), an interrupted command ends the process at once with
    `os._exit(130)` once its message is out: a normal exit would run Python's finalisation while
    XLA may still be compiling on its own threads, which ends in a segmentation fault."""
    program = argv is None
    argv = list(sys.argv[1:] if argv is None else argv)
    if program:
        _on_interrupt_exit("fovjax")
    parser = build_parser()
    # --debug is taken anywhere on the line (`fovjax render --debug ...` too).
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    args = parser.parse_args(argv)
    args.debug = debug
    if getattr(args, "func", None) is None:  # `fovjax` alone: what there is to run
        parser.print_help()
        return 0
    name = f"fovjax {args.command}"
    _WRITTEN.clear()
    if program:
        _on_interrupt_exit(name)
    try:
        _compile_cache(name)  # inside: a FOVJAX_COMPILE_CACHE it cannot use is a user's mistake
        with _one_line_warnings(name), _size_check(not getattr(args, "no_size_check", False)):
            return int(args.func(args) or 0)
    except KeyboardInterrupt:
        if program:
            _exit_interrupted(name)
        print(f"{name}: interrupted; {_written_text()}", file=sys.stderr, flush=True)
        return INTERRUPTED
    except Exception as err:
        if args.debug:
            raise
        status, text = _explain(err)
        print(f"{name}: error: {text}", file=sys.stderr, flush=True)
        return status


def _compile_cache(name: str) -> None:
    """Compiled frame programs persist across runs (JAX's compilation cache, see
    `fovjax.render.enable_compile_cache`): a second `fovjax render` loads its programs instead of
    compiling them. `FOVJAX_COMPILE_CACHE=0` turns it off; a cache that cannot be written is
    said once and skipped (it is an optimisation, never a reason to fail)."""
    from fovjax.render import compile_cache_problem, enable_compile_cache

    if not _environment.switch("FOVJAX_COMPILE_CACHE"):
        return
    if enable_compile_cache() is None:
        print(f"{name}: note: {compile_cache_problem()}", file=sys.stderr, flush=True)


@contextlib.contextmanager
def _size_check(enabled: bool):
    """`--no-size-check`: `FOVJAX_SIZE_CHECK=0` while the command runs, so that the library's
    own checks (`StereoRig`, `FoveatedRenderer`, `render_stereo`) let the frame through too."""
    from fovjax.render import SIZE_CHECK_VARIABLE

    if enabled:
        yield
        return
    before = os.environ.get(SIZE_CHECK_VARIABLE)
    os.environ[SIZE_CHECK_VARIABLE] = "0"
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(SIZE_CHECK_VARIABLE, None)
        else:
            os.environ[SIZE_CHECK_VARIABLE] = before


@contextlib.contextmanager
def _one_line_warnings(name: str):
    """A warning the library raises while a command runs is one line on stderr, `fovjax
    COMMAND: warning: ...`, not Python's two (the file and line of the code that warned, and
    that line's source)."""
    previous = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        kind = "" if category in (UserWarning, RuntimeWarning) else f" ({category.__name__})"
        print(f"{name}: warning{kind}: {message}", file=sys.stderr, flush=True)

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = previous


def _exit_interrupted(name: str) -> None:
    """Say what was written and end the process now, without Python's finalisation."""
    try:
        sys.stdout.flush()
        print(f"{name}: interrupted; {_written_text()}", file=sys.stderr, flush=True)
    finally:
        os._exit(INTERRUPTED)


def _on_interrupt_exit(name: str) -> None:
    """Ctrl-C (and SIGTERM, `kill`'s signal, taken as Ctrl-C) ends the program at once with
    `_exit_interrupted`, wherever the main thread is.

    Raising KeyboardInterrupt instead is not enough: raised inside a garbage-collection callback
    it is printed and ignored, and after one raised inside an XLA compile the interpreter's
    exit can crash. Blocks that must finish (writing a file, a session's frame, a recording)
    install their own handler for their duration (`fovjax.files`, `fovjax.devices.record`)
    and end with KeyboardInterrupt, which `main` answers the same way."""
    for signum in INTERRUPT_SIGNALS:
        if signal.getsignal(signum) is not signal.SIG_IGN:
            signal.signal(signum, lambda signum, frame: _exit_interrupted(name))


def _explain(err: Exception) -> tuple[int, str]:
    """Exit status and one line for an error that ended a command."""
    from ..devices import DeviceError

    if isinstance(err, UsageError):
        return 2, str(err)
    if isinstance(err, DeviceError):
        return 1, str(err)
    if isinstance(err, ImportError) and "pip install" in str(err):  # an optional extra is missing
        return 1, str(err)
    if isinstance(err, UnicodeDecodeError):
        return 2, f"a file is not UTF-8 text ({err.reason} at byte {err.start})"
    if isinstance(err, ValueError | OSError):
        return 2, str(err) or type(err).__name__
    return 1, (
        f"internal error, {type(err).__name__}: {err} "
        "(please report it; `fovjax --debug ...` shows the traceback)"
    )


# -- what a command wrote, for the message on Ctrl-C --------------------------------------------
_WRITTEN: list[str] = []


def wrote(*paths) -> None:
    """Note files (or folders) a command has finished writing (each once)."""
    for p in paths:
        if p is not None and str(p) not in _WRITTEN:
            _WRITTEN.append(str(p))


def _written_text() -> str:
    if not _WRITTEN:
        return "nothing was written"
    shown = _WRITTEN[:6]
    more = f" and {len(_WRITTEN) - len(shown)} more" if len(_WRITTEN) > len(shown) else ""
    return f"wrote {', '.join(shown)}{more} (complete); nothing else"


# -- argument checks ----------------------------------------------------------------------------
class UsageError(ValueError):
    """A bad argument or input file of a `fovjax` command: one line on stderr, exit status 2."""


def _show(value) -> str:
    return repr(value) if isinstance(value, str) else f"{value}"


# fovjax.trace.BACKENDS (the built-in backends), spelled out so that parsing arguments imports no
# JAX (tested equal).
BACKENDS = ("auto", "jax", "embree", "warp")


def add_backend(parser: argparse.ArgumentParser) -> None:
    """`--backend`: the ray-query backend of every command that renders."""
    parser.add_argument(
        "--backend",
        default="auto",
        choices=BACKENDS,
        help="ray queries: auto (default: Embree through XLA's FFI on CPU where it builds, Warp on a GPU "
        "where installed, else the JAX traversal), jax, embree or warp",
    )


def backend(value: str, option: str = "--backend") -> None:
    """An explicitly named backend whose package is missing fails before anything is built."""
    import importlib.util

    if value == "embree" and importlib.util.find_spec("embreex") is None:
        raise ImportError(f"{option} embree needs embreex: pip install 'fovjax[embree]'")
    if value == "warp" and importlib.util.find_spec("warp") is None:
        raise ImportError(f"{option} warp needs NVIDIA Warp: pip install 'fovjax[gpu]'")


def number(value, option: str, *, gt=None, ge=None, lt=None, le=None, integer: bool = False):
    """`value` is a finite number (an integer with `integer`) within the bounds given."""
    bounds = [(gt, ">", lambda v, b: v > b), (ge, ">=", lambda v, b: v >= b)]
    bounds += [(lt, "<", lambda v, b: v < b), (le, "<=", lambda v, b: v <= b)]
    is_number = isinstance(value, int | float) and not isinstance(value, bool)
    ok = is_number and math.isfinite(value) and (not integer or float(value).is_integer())
    parts = []
    for bound, sign, holds in bounds:
        if bound is not None:
            parts.append(f"{sign} {bound:g}")
            ok = ok and holds(value, bound)
    if not ok:
        what = "a whole number" if integer or isinstance(value, int) else "a finite number"
        raise UsageError(f"{option} {_show(value)}: expected {what} {' and '.join(parts)}".rstrip())
    return value


def seed(value, option: str = "--seed"):
    """A PRNG seed: a whole number 0 .. 2**32 - 1 (what JAX keys and NumPy generators share)."""
    if value is not None:
        number(value, option, ge=0, le=2**32 - 1, integer=True)
    return value


def squares(values, option: str):
    """Samples per pixel: each a perfect square 1, 4, 9, 16, ..."""
    for v in [values] if isinstance(values, int) else values:
        if not (isinstance(v, int) and v >= 1 and math.isqrt(v) ** 2 == v):
            raise UsageError(f"{option} {v}: expected a perfect square (1, 4, 9, 16, ...) samples per pixel")
    return values


def choice(value, option: str, choices) -> str:
    if value not in choices:
        raise UsageError(f"{option} {_show(value)}: expected one of {', '.join(map(str, choices))}")
    return value


def fovea_periphery(fovea, periphery, where: str) -> None:
    """Fovea and periphery eccentricities (degrees): 0 <= fovea <= periphery <= 180."""
    number(fovea, f"{where} fovea", ge=0, le=180)
    number(periphery, f"{where} periphery", ge=0, le=180)
    if periphery < fovea:
        raise UsageError(
            f"{where} {fovea:g},{periphery:g}: the periphery ({periphery:g}°) must not be smaller than "
            f"the fovea ({fovea:g}°)"
        )


def display_point(xy, option: str) -> None:
    """A point in normalised display coordinates: both in [0, 1]."""
    if not all(isinstance(v, int | float) and math.isfinite(v) and 0 <= v <= 1 for v in xy):
        raise UsageError(
            f"{option} {','.join(f'{v:g}' for v in xy)}: expected normalised display coordinates in [0, 1]"
        )


REGIONS_HELP = (
    "how eccentricity is measured for the fovea/periphery regions: angle (fovjax's reading: the exact "
    "angle between a pixel's ray and the gaze ray on the rig's own field of view) or thesis (the reading "
    "behind the thesis's Table 2: planar eq. 4-5 at the SX111's 16 px/°, scaled to the eye's rows; on "
    "the 90° rig a threshold then covers about twice the pixels, and a thesis level such as 12.5°/25° "
    "compares like-for-like with the thesis's participants only under it)"
)


def add_regions(parser, default: str = "angle") -> None:
    """The `--regions angle|thesis` option of every command that renders foveated frames
    (`fovjax.foveate.with_regions`)."""
    parser.add_argument(
        "--regions",
        choices=("angle", "thesis"),
        default=default,
        help=f"{REGIONS_HELP} (default {default})",
    )


def regions(foveation, args, eye_height: int):
    """`foveation` with the regions `--regions` chose, for eyes of `eye_height` rows."""
    from ..foveate import with_regions

    return with_regions(foveation, args.regions, eye_height)


def head_gaze_fovea(args) -> None:
    """The frame options `render` and `inspect` share: `--head` (yaw, pitch, roll), `--gaze`
    (both eyes' display points) and `--fovea`/`--periphery`."""
    for name, value in zip(("yaw", "pitch", "roll"), args.head, strict=True):
        number(value, f"--head {name}")
    display_point(args.gaze[0], "--gaze (left eye)")
    display_point(args.gaze[1], "--gaze (right eye)")
    fovea_periphery(args.fovea, args.periphery, "--fovea/--periphery")


def _existing_ancestor(path: Path) -> Path:
    path = path.absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def output(path, option: str, *, suffixes=None, directory: bool = False) -> Path:
    """An output file (of a type in `suffixes`) or folder that can be created or overwritten."""
    p = Path(path)
    what = "folder" if directory else "file"
    if not directory and p.is_dir():
        raise UsageError(f"{option} {path}: is a folder; expected a file name")
    if suffixes is not None and p.suffix.lower() not in suffixes:
        raise UsageError(
            f"{option} {path}: unknown output type {p.suffix or '(no suffix)'!r} "
            f"(expected {', '.join(suffixes)})"
        )
    if p.exists():
        if directory and not p.is_dir():
            raise UsageError(f"{option} {path}: exists and is not a folder")
        if not directory and p.is_dir():
            raise UsageError(f"{option} {path}: is a folder; expected a file name")
        if not os.access(p, os.W_OK):
            raise UsageError(f"{option} {path}: cannot write the {what} (permission denied)")
        return p
    base = _existing_ancestor(p)
    if not base.is_dir():
        raise UsageError(f"{option} {path}: cannot create the {what}: {base} is a file, not a folder")
    if not os.access(base, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {path}: cannot create the {what}: no write permission in {base}")
    return p


def input_file(path, option: str, *, suffixes=None, text: bool = False) -> Path:
    """An existing readable file (of a type in `suffixes`); with `text`, UTF-8 text (a bad byte
    is reported as FILE:LINE)."""
    p = Path(path)
    if not p.exists():
        raise UsageError(f"{option} {path}: no such file")
    if p.is_dir():
        raise UsageError(f"{option} {path}: is a folder; expected a file")
    if suffixes is not None and p.suffix.lower() not in suffixes:
        raise UsageError(
            f"{option} {path}: unknown file type {p.suffix or '(no suffix)'!r} "
            f"(expected {', '.join(suffixes)})"
        )
    try:
        raw = p.read_bytes() if text else b""
        if not text and not os.access(p, os.R_OK):
            raise PermissionError("permission denied")
    except OSError as err:
        raise UsageError(f"{option} {path}: cannot read ({err.strerror or err})") from None
    if text:
        bad = raw.find(b"\x00")
        try:
            raw.decode("utf-8-sig")
        except UnicodeDecodeError as err:
            bad = err.start if bad < 0 else min(bad, err.start)
        if bad >= 0:
            line = raw[:bad].count(b"\n") + 1
            raise UsageError(
                f"{path}:{line}: not a text file (byte 0x{raw[bad]:02x} at offset {bad}); "
                f"{option} expects UTF-8 text"
            )
    return p


def add_size_check(parser: argparse.ArgumentParser) -> None:
    """`--no-size-check`: the option of every command that renders, to skip `frame_size`."""
    parser.add_argument(
        "--no-size-check",
        action="store_true",
        help="render even when the frame's estimated memory is more than this machine has free "
        "(the check refuses such a frame before any work; FOVJAX_SIZE_CHECK=0 does the same)",
    )


FRAME_KINDS = ("foveated", "full")


def frame_size(
    args,
    width: int,
    height: int,
    spp: int,
    *,
    kinds=FRAME_KINDS,
    eyes: int = 2,
    kept_images: int = 0,
    option: str = "--width/--height",
) -> None:
    """The frames a command renders (`kinds`: "foveated" and/or "full", `eyes` of
    `width` x `height` at `spp`, `kept_images` held besides) fit in the machine's free memory
    (`fovjax.render.check_frame_memory`), or a UsageError naming `option`'s value, the estimate
    and the limit. Call it last in `validate`, after the values themselves are checked; skipped
    with `--no-size-check` (or FOVJAX_SIZE_CHECK=0)."""
    if getattr(args, "no_size_check", False):
        return
    if getattr(args, "distributed", None) is not None:
        # Asking JAX for its platform would start its backends before jax.distributed may; the
        # renderer's own check (`FoveatedRenderer`) runs once it has started.
        return
    from ..render import FrameTooLargeError, RenderConfig, check_frame_memory

    config = RenderConfig(max_depth=getattr(args, "max_depth", 5), backend=getattr(args, "backend", "auto"))
    for kind in kinds:
        try:
            check_frame_memory(
                width,
                height,
                spp,
                foveated=kind == "foveated",
                eyes=eyes,
                config=config,
                kept_images=kept_images,
                where=f"{option} {width}x{height}",
            )
        except FrameTooLargeError as err:
            raise UsageError(str(err)) from None


def add_overwrite(parser: argparse.ArgumentParser) -> None:
    """`--overwrite`: replace another run's files in the output folder (`output_folder`)."""
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the files of an earlier run in the output folder (without it, a folder holding "
        "them is refused, so that old and new files are never mixed)",
    )


def output_folder(path, option: str, patterns, *, overwrite: bool = False) -> Path:
    """An output folder (`output(directory=True)`) that holds no earlier run's files: those
    matching `patterns` (globs such as "frame_*.png"). With `overwrite` they are listed for
    `clear_outputs` to remove once every argument is checked; without it a UsageError names the
    folder, a few of the files and `--overwrite`. Other files in the folder are left alone."""
    p = output(path, option, directory=True)
    found = sorted({f for pattern in patterns for f in p.glob(pattern) if f.is_file()}) if p.is_dir() else []
    if found and not overwrite:
        more = f" and {len(found) - 3} more" if len(found) > 3 else ""
        shown = ", ".join(f.name for f in found[:3]) + more
        raise UsageError(
            f"{option} {path}: holds another run's files ({shown}); choose a new folder, or --overwrite "
            "to replace them"
        )
    return p


def clear_outputs(folder, patterns) -> list[Path]:
    """Remove an earlier run's files (those matching `patterns`) from `folder` before a command
    writes its own (`--overwrite`); returns what was removed."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    removed = sorted({f for pattern in patterns for f in folder.glob(pattern) if f.is_file()})
    for f in removed:
        f.unlink()
    return removed


def scene(name: str, option: str = "--scene") -> list[Path]:
    """A built-in scene name (or alias), or existing scene files of supported formats: a file, a
    folder or a glob pattern (`fovjax.scene.scene_files`). Returns the files ([] for a built-in)."""
    from ..scene import BUILTIN, SUPPORTED_FORMATS, scene_files

    if name in BUILTIN or name == "cornell":
        return []
    formats = ", ".join(SUPPORTED_FORMATS)
    not_builtin = f"{option} {name!r}: not a built-in scene (atrium, cornell, spheres) nor"
    try:
        files = scene_files(name)
    except (OSError, ValueError) as err:
        raise UsageError(f"{not_builtin} scene files: {err}") from None
    for file in files:
        if file.suffix.lower() not in SUPPORTED_FORMATS:
            raise UsageError(f"{not_builtin} a scene file ({formats})")
        if not file.is_file():
            raise UsageError(f"{not_builtin} an existing file")
        input_file(file, option)
    return files


def source_spec(spec: str, kind: str, option: str) -> None:
    """A gaze/head source spec that parses and names an existing recording (nothing is opened)."""
    from ..devices import source_from_spec

    try:
        source_from_spec(spec, kind)
    except (ValueError, OSError) as err:
        raise UsageError(f"{option} {spec}: {err}") from None


__all__ = [
    "INTERRUPT_SIGNALS",
    "atomic_path",
    "deferred_interrupt",
    "INTERRUPTED",
    "build_parser",
    "main",
    "wrote",
    "UsageError",
    "BACKENDS",
    "add_backend",
    "backend",
    "number",
    "seed",
    "squares",
    "choice",
    "fovea_periphery",
    "display_point",
    "REGIONS_HELP",
    "add_regions",
    "regions",
    "head_gaze_fovea",
    "output",
    "add_size_check",
    "FRAME_KINDS",
    "frame_size",
    "add_overwrite",
    "output_folder",
    "clear_outputs",
    "input_file",
    "scene",
    "source_spec",
]
