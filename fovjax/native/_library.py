"""The native handler library: built with the system's C++ compiler on first use, loaded, its
layout checked against the Python side's, its handlers registered with XLA.

The sources are the `.cc` and `.h` files of the packages that own each stage (`csrc/library.cc`
includes them as one translation unit). They are compiled once into the cache directory
(`$FOVJAX_CACHE_DIR/native`, default `~/.cache/fovjax/native`; `FOVJAX_NATIVE_DIR` overrides),
under a name that hashes every source, the jaxlib version (its FFI headers), the compiler and the
flags, so a new fovjax or jaxlib builds afresh and a stale library is never loaded. With GCC the
build uses link-time optimisation (`PARALLEL_FLAGS`) only to spread the back end's work, most of
the build, over every core: the frames are bit for bit those of a plain build. A caller with other
work to do first (the command line loads the scene and builds its BVH) starts the build in the
background (`start_build`); `status()` waits for it. XLA's FFI headers come from the installed
jaxlib (`jax.ffi.include_dir()`); Embree is the library inside the `embreex` wheel, opened at
run time. Anything missing (no compiler, no embreex, a library whose struct or data layout does
not match) leaves `status()` False with the reason, and every stage runs its JAX implementation.
`FOVJAX_NATIVE=0` turns the native handlers off; `FOVJAX_NATIVE_FLAGS` adds compiler flags after
the project's (its own library: the flags are in the name); `FOVJAX_NATIVE_SANITIZE=1` builds them with
AddressSanitizer and UndefinedBehaviorSanitizer (the process must then start with the sanitizer
runtime preloaded: `.ci/sanitize`).
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import glob
import hashlib
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import jax

from .. import _environment
from ._layout import layout_differences, parse_layout

PACKAGE = Path(__file__).resolve().parents[1]  # fovjax/: the sources' include root
ENTRY = Path(__file__).with_name("csrc") / "library.cc"
# FFI target -> the handler's symbol in the library. Each stage's Python wrapper lives with the
# package that owns its JAX oracle (fovjax.trace, fovjax.render, fovjax.foveate).
HANDLERS = {
    "fovjax_embree_query": "FovjaxEmbreeQuery",
    "fovjax_embree_whitted": "FovjaxEmbreeWhitted",
    "fovjax_whitted_adjoint": "FovjaxWhittedAdjoint",
    "fovjax_camera_frame": "FovjaxCameraFrame",
    "fovjax_select_samples": "FovjaxSelectSamples",
    "fovjax_whitted_slots": "FovjaxWhittedSlots",
    "fovjax_fill_and_blur": "FovjaxFillAndBlur",
    "fovjax_taa_blend": "FovjaxTaaBlend",
    "fovjax_patney_prefilter": "FovjaxPatneyPrefilter",
    "fovjax_layer_blend": "FovjaxLayerBlend",
}
# The library's C entry points (library.cc's extern "C"), read by `_load`.
ENTRY_POINTS = (
    "fovjax_native_layout",
    "fovjax_embree_init",
    "fovjax_embree_error",
    "fovjax_embree_version",
    "fovjax_embree_release",
    "fovjax_embree_packet_width",
    "fovjax_embree_cached_scenes",
)
FLAGS = (
    "-O3",
    "-fno-math-errno",
    "-ffp-contract=off",
    "-std=c++17",
    "-shared",
    "-fPIC",
    "-Wall",
    "-Wextra",
    "-Wno-attributes",
)
# GCC's link-time optimisation, for its parallel back end: the one translation unit is split into
# partitions that compile at once, one per core (`auto`), where a plain build compiles them one
# after another; the partitions, and so the library, do not depend on the number of cores. The
# sources ask for IEEE arithmetic (no -ffast-math, no contraction), so inlining across the
# partitions changes no result: the atrium's frames are bit for bit those of a plain build
# (benchmarks/first_render.py --check-frames). A compiler without it (clang, an old GCC, no LTO
# plugin) builds plainly.
PARALLEL_FLAGS = ("-flto=auto",)
SANITIZE_FLAGS = (
    "-fsanitize=address,undefined",
    "-fno-omit-frame-pointer",
    "-fno-sanitize-recover=undefined",
    "-g",
)

BUILD_TIMEOUT_S = 600
_lock = threading.Lock()
_state: dict = {}
# The background build (`start_build`): the thread and what it built or raised.
_background: dict = {}


class NativeStatus:
    """Whether the native handlers can run here, and why not if they cannot."""

    def __init__(self, available: bool, reason: str, library: str | None = None, **info):
        self.available = available
        self.reason = reason
        self.library = library
        self.info = info

    def __bool__(self) -> bool:
        return self.available

    def __repr__(self) -> str:
        return f"NativeStatus(available={self.available}, reason={self.reason!r})"


def sources() -> list[Path]:
    """Every native source of the package (what the build includes and its hash covers)."""
    return sorted(p for p in PACKAGE.rglob("*") if p.suffix in (".cc", ".h") and p.is_file())


def _native_dir() -> Path:
    return _environment.path("FOVJAX_NATIVE_DIR") or _environment.cache_dir("native")


def _compiler() -> str | None:
    for name in (os.environ.get("CXX"), "c++", "g++", "clang++"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def _extra_flags() -> tuple[str, ...]:
    """`FOVJAX_NATIVE_FLAGS`, split as a shell would: compiler flags after the project's (a
    later `-O` wins; `-march=native`, `-O0` for a quick build of a change)."""
    value = _environment.text("FOVJAX_NATIVE_FLAGS") or ""
    try:
        return tuple(shlex.split(value))
    except ValueError as exc:
        said = f"FOVJAX_NATIVE_FLAGS={value!r} cannot be split into flags as a shell would: {exc}"
        raise ValueError(said) from None


def _flags_said() -> str:
    """`FOVJAX_NATIVE_FLAGS` as a message names it."""
    return f"FOVJAX_NATIVE_FLAGS={' '.join(_extra_flags())!r}"


def _flags() -> tuple[str, ...]:
    sanitize = SANITIZE_FLAGS if _environment.switch("FOVJAX_NATIVE_SANITIZE") else ()
    return FLAGS + _extra_flags() + sanitize


def embree_library() -> str | None:
    """The Embree 4 shared library inside the installed embreex wheel (its file name carries a
    hash that changes per release), or None."""
    import importlib.util

    spec = importlib.util.find_spec("embreex")
    if spec is None or not spec.submodule_search_locations:
        return None
    site = Path(next(iter(spec.submodule_search_locations))).parent
    found = sorted(glob.glob(str(site / "embreex.libs" / "libembree4*.so*")))
    return found[0] if found else None


def _gcc(compiler: str, version: str) -> bool:
    """Whether `compiler` is GCC (its `--version` text), which takes `PARALLEL_FLAGS`."""
    return "Free Software Foundation" in version and "clang" not in version.lower()


def library_path(compiler: str, flags: tuple[str, ...] | None = None) -> Path:
    """Where the library built by `compiler` with `flags` (default: this machine's) is kept: a name
    hashing every source, the jaxlib version, the compiler's version and the flags."""
    import jaxlib

    flags = _flags() if flags is None else flags
    version = _compiler_version(compiler)
    digest = hashlib.sha256()
    for path in sources():
        digest.update(str(path.relative_to(PACKAGE)).encode())
        digest.update(path.read_bytes())
    # jaxlib's version attribute (pyright cannot see it).
    digest.update(jaxlib.__version__.encode())  # pyright: ignore[reportPrivateImportUsage]
    digest.update(version.encode())
    digest.update(" ".join(flags).encode())
    return _native_dir() / f"fovjax_native-{digest.hexdigest()[:16]}.so"


@functools.cache
def _compiler_version(compiler: str) -> str:
    return subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=30).stdout


def _choices(compiler: str) -> list[tuple[str, ...]]:
    """The flags to build with, in order of preference: with `PARALLEL_FLAGS` first where the
    compiler is GCC (and no sanitizer is asked for), then plain."""
    if not _environment.switch("FOVJAX_NATIVE_SANITIZE") and _gcc(compiler, _compiler_version(compiler)):
        # The user's flags last, after PARALLEL_FLAGS too: theirs win (`-fno-lto`).
        return [FLAGS + PARALLEL_FLAGS + _extra_flags(), _flags()]
    return [_flags()]


def build(compiler: str, flags: tuple[str, ...] | None = None) -> tuple[Path, float]:
    """The compiled library's path (compiling it if absent) and the seconds spent compiling.

    Without `flags`: a library already built with any of this machine's choices (`_choices`) is
    used; otherwise the first choice is built, and where that fails (a GCC without link-time
    optimisation) the plain build, whose error is the one raised."""
    choices = [flags] if flags is not None else _choices(compiler)
    for choice in choices:
        path = library_path(compiler, choice)
        if path.exists():
            return path, 0.0
    t0 = time.perf_counter()
    for choice in choices[:-1]:
        with contextlib.suppress(RuntimeError, subprocess.SubprocessError):
            return _compile(compiler, choice), time.perf_counter() - t0
    return _compile(compiler, choices[-1]), time.perf_counter() - t0


def _compile(compiler: str, flags: tuple[str, ...]) -> Path:
    path = library_path(compiler, flags)
    include = jax.ffi.include_dir()
    out_dir = path.parent
    out_dir.mkdir(parents=True, exist_ok=True)
    _remove_abandoned(out_dir)
    fd, tmp = tempfile.mkstemp(prefix=path.stem + ".", suffix=".tmp.so", dir=out_dir)
    os.close(fd)
    try:
        # XLA's headers as system headers: their own warnings are not the project's.
        cmd = [compiler, *flags, f"-I{PACKAGE}", "-isystem", include, str(ENTRY), "-o", tmp]
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
        if done.returncode != 0:
            lines = [ln for ln in done.stderr.splitlines() if "error" in ln][:3] or done.stderr.splitlines()[
                -3:
            ]
            said = f" (with {_flags_said()})" if _extra_flags() else ""
            raise RuntimeError(
                f"{Path(compiler).name} failed to compile {ENTRY.name}{said}: " + " | ".join(lines)
            )
        os.replace(tmp, path)  # atomic: a concurrent process never loads half a library
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def _remove_abandoned(out_dir: Path) -> None:
    """Remove the temporary outputs of builds that ended without finishing (a process killed
    while it compiled): older than a build may take, so none is still being written."""
    for tmp in out_dir.glob("fovjax_native-*.tmp.so"):
        with contextlib.suppress(OSError):
            if time.time() - tmp.stat().st_mtime > 2 * BUILD_TIMEOUT_S:
                tmp.unlink()


def start_build() -> Path | None:
    """Start building the handler library in a background thread, so that the caller's other
    work (loading a scene, building its BVH) overlaps the compile; `status()` waits for it and
    loads what it built. Returns the library being built, or None where there is nothing to
    build: the handlers are already loaded or built (in the cache), or cannot run here
    (`status()` then says why)."""
    with _lock:
        if "status" in _state or "thread" in _background:
            return None
        found = _prerequisites()
        if isinstance(found, NativeStatus):
            return None
        compiler, _ = found
        try:
            choices = _choices(compiler)
            if any(library_path(compiler, choice).exists() for choice in choices):
                return None
            path = library_path(compiler, choices[0])
            path.parent.mkdir(parents=True, exist_ok=True)
        except (OSError, ValueError, subprocess.SubprocessError):
            return None  # status() tries in the foreground and says what went wrong

        def run() -> None:
            try:
                _background["result"] = build(compiler)
            except Exception as exc:  # handed to status(), which reports it
                _background["error"] = exc

        # Not a daemon: a process that ends (an error) while it runs waits for it, so the next
        # run finds the library built. Ctrl-C reaches the compiler too (the same process group).
        thread = threading.Thread(target=run, name="fovjax-native-build")
        _background["thread"] = thread
        thread.start()
        return path


def building() -> bool:
    """Whether a build `start_build` began is not loaded yet: `status()` would wait for it."""
    return "thread" in _background


def _built_library(compiler: str) -> tuple[Path, float]:
    """The library `start_build` built (waiting for it), else one built here and now."""
    thread = _background.pop("thread", None)
    if thread is None:
        return build(compiler)
    thread.join()
    if "error" in _background:
        raise _background.pop("error")
    return _background.pop("result")


def status() -> NativeStatus:
    """Build (once), load and register the native handlers; cached for the process."""
    with _lock:
        if "status" not in _state:
            _state["status"] = _load()
        return _state["status"]


def _prerequisites() -> tuple[str, str] | NativeStatus:
    """The compiler and the Embree library to build and run the handlers with, or the reason
    they cannot run here (an unavailable status)."""
    try:
        if not _environment.switch("FOVJAX_NATIVE"):
            return NativeStatus(False, "turned off by FOVJAX_NATIVE=0")
    except ValueError as exc:  # a bad value: named, and the handlers stay off
        return NativeStatus(False, str(exc))
    if not sys.platform.startswith("linux"):
        return NativeStatus(False, f"the native handlers are built for Linux only (this is {sys.platform})")
    library = embree_library()
    if library is None:
        return NativeStatus(False, "embreex is not installed (pip install 'fovjax[embree]')")
    compiler = _compiler()
    if compiler is None:
        return NativeStatus(False, "no C++ compiler found (set CXX, or install g++)")
    return compiler, library


def _load() -> NativeStatus:
    found = _prerequisites()
    if isinstance(found, NativeStatus):
        return found
    compiler, library = found
    try:
        path, seconds = _built_library(compiler)
    except (OSError, RuntimeError, ValueError, subprocess.SubprocessError) as exc:
        return NativeStatus(False, f"could not build the native handlers: {exc}")
    try:
        lib = ctypes.CDLL(str(path))
    except OSError as exc:
        return NativeStatus(False, f"could not load {path}: {exc}")
    missing = [name for name in ENTRY_POINTS + tuple(HANDLERS.values()) if not hasattr(lib, name)]
    if missing:
        said = f", built with {_flags_said()}" if _extra_flags() else ""
        return NativeStatus(
            False,
            f"{path} lacks the handlers' entry points ({', '.join(missing[:3])}"
            f"{', …' if len(missing) > 3 else ''}){said}: remove it to build it again",
        )
    lib.fovjax_native_layout.restype = ctypes.c_char_p
    differences = layout_differences(parse_layout(lib.fovjax_native_layout().decode()))
    if differences:
        return NativeStatus(
            False, f"the native layout differs from the Python side's: {'; '.join(differences)}"
        )
    lib.fovjax_embree_init.argtypes = [ctypes.c_char_p]
    lib.fovjax_embree_error.restype = ctypes.c_char_p
    lib.fovjax_embree_version.restype = ctypes.c_long
    lib.fovjax_embree_release.argtypes = [ctypes.c_int32]
    if lib.fovjax_embree_init(library.encode()) != 0:
        return NativeStatus(False, f"Embree ({Path(library).name}): {lib.fovjax_embree_error().decode()}")
    for target, symbol in HANDLERS.items():
        jax.ffi.register_ffi_target(target, jax.ffi.pycapsule(getattr(lib, symbol)), platform="cpu")
    _state["lib"] = lib
    version = lib.fovjax_embree_version()
    width = lib.fovjax_embree_packet_width()
    return NativeStatus(
        True,
        f"Embree {version // 10000}.{version // 100 % 100}.{version % 100} through XLA's FFI, "
        f"{width}-ray packets",
        library=str(path),
        compile_seconds=seconds,
        embree=library,
        packet_width=width,
    )


def release_scenes(host_id: int | None = None) -> int:
    """Free the Embree scenes built for one BVH (its `host_id`) or for all (None); they are
    rebuilt on next use. Returns how many were freed."""
    lib = _state.get("lib")
    if lib is None:
        return 0
    return int(lib.fovjax_embree_release(-1 if host_id is None else int(host_id)))


def cached_scenes() -> int:
    """How many Embree scenes the handlers hold."""
    lib = _state.get("lib")
    return 0 if lib is None else int(lib.fovjax_embree_cached_scenes())


def exported_layout() -> dict[str, str]:
    """The layout the loaded library exports (empty where none is loaded)."""
    lib = _state.get("lib")
    return {} if lib is None else parse_layout(lib.fovjax_native_layout().decode())
