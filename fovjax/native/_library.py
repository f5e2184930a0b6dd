"""The native handler library: built with the system's C++ compiler on first use, loaded, its
layout checked against the Python side's, its handlers registered with XLA.

The sources are the `.cc` and `.h` files of the packages that own each stage (`csrc/library.cc`
includes them as one translation unit). They are compiled once into the cache directory
(`$FOVJAX_CACHE_DIR/native`, default `~/.cache/fovjax/native`; `FOVJAX_NATIVE_DIR` overrides),
under a name that hashes every source, the jaxlib version (its FFI headers), the compiler and the
flags, so a new fovjax or jaxlib builds afresh and a stale library is never loaded. XLA's FFI
headers come from the installed jaxlib (`jax.ffi.include_dir()`); Embree is the library inside
the `embreex` wheel, opened at run time. Anything missing (no compiler, no embreex, a library
whose struct or data layout does not match) leaves `status()` False with the reason, and every
stage runs its JAX implementation. `FOVJAX_NATIVE=0` turns the native handlers off;
`FOVJAX_NATIVE_SANITIZE=1` builds them with AddressSanitizer and UndefinedBehaviorSanitizer (the
process must then start with the sanitizer runtime preloaded: `.ci/sanitize`).
"""

from __future__ import annotations

import ctypes
import glob
import hashlib
import os
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
    "fovjax_select_samples": "FovjaxSelectSamples",
    "fovjax_whitted_slots": "FovjaxWhittedSlots",
    "fovjax_fill_and_blur": "FovjaxFillAndBlur",
}
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
SANITIZE_FLAGS = (
    "-fsanitize=address,undefined",
    "-fno-omit-frame-pointer",
    "-fno-sanitize-recover=undefined",
    "-g",
)

_lock = threading.Lock()
_state: dict = {}


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


def _flags() -> tuple[str, ...]:
    return FLAGS + (SANITIZE_FLAGS if _environment.switch("FOVJAX_NATIVE_SANITIZE") else ())


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


def build(compiler: str, flags: tuple[str, ...] | None = None) -> tuple[Path, float]:
    """The compiled library's path (compiling it if absent) and the seconds spent compiling."""
    import jaxlib

    flags = _flags() if flags is None else flags
    include = jax.ffi.include_dir()
    version = subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=30).stdout
    digest = hashlib.sha256()
    for path in sources():
        digest.update(str(path.relative_to(PACKAGE)).encode())
        digest.update(path.read_bytes())
    # jaxlib's version attribute (pyright cannot see it).
    digest.update(jaxlib.__version__.encode())  # pyright: ignore[reportPrivateImportUsage]
    digest.update(version.encode())
    digest.update(" ".join(flags).encode())
    out_dir = _native_dir()
    path = out_dir / f"fovjax_native-{digest.hexdigest()[:16]}.so"
    if path.exists():
        return path, 0.0
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    fd, tmp = tempfile.mkstemp(prefix=path.stem + ".", suffix=".tmp.so", dir=out_dir)
    os.close(fd)
    try:
        # XLA's headers as system headers: their own warnings are not the project's.
        cmd = [compiler, *flags, f"-I{PACKAGE}", "-isystem", include, str(ENTRY), "-o", tmp]
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        if done.returncode != 0:
            lines = [ln for ln in done.stderr.splitlines() if "error" in ln][:3] or done.stderr.splitlines()[
                -3:
            ]
            raise RuntimeError(f"{Path(compiler).name} failed to compile {ENTRY.name}: " + " | ".join(lines))
        os.replace(tmp, path)  # atomic: a concurrent process never loads half a library
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path, time.perf_counter() - t0


def status() -> NativeStatus:
    """Build (once), load and register the native handlers; cached for the process."""
    with _lock:
        if "status" not in _state:
            _state["status"] = _load()
        return _state["status"]


def _load() -> NativeStatus:
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
    try:
        path, seconds = build(compiler)
    except (OSError, RuntimeError, ValueError, subprocess.SubprocessError) as exc:
        return NativeStatus(False, f"could not build the native handlers: {exc}")
    try:
        lib = ctypes.CDLL(str(path))
    except OSError as exc:
        return NativeStatus(False, f"could not load {path}: {exc}")
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
