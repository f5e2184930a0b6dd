"""The Embree XLA FFI handler: built with the system's C++ compiler on first use, loaded, registered.

`_embree_ffi.cc` (shipped with the package) is compiled once into the cache directory
(`$FOVJAX_CACHE_DIR/native`, default `~/.cache/fovjax/native`; `FOVJAX_NATIVE_DIR` overrides),
under a name that hashes the source, the jaxlib version (its FFI headers) and the compiler, so a
new fovjax or jaxlib builds afresh and a stale library is never loaded. XLA's FFI headers come
from the installed jaxlib (`jax.ffi.include_dir()`); Embree is the library inside the `embreex`
wheel, opened at run time. Anything missing (no compiler, no embreex, a library whose layout does
not match) leaves `embree_status()` False with the reason, and `backend="auto"` uses the JAX
traversal. `FOVJAX_NATIVE=0` turns the native backend off.
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

SOURCE = Path(__file__).with_name("_embree_ffi.cc")
TARGET = "fovjax_embree_query"
# The Whitted integrator's primal (`fovjax.render.radiance` with `RenderConfig.integrator`).
WHITTED_TARGET = "fovjax_embree_whitted"
SELECT_TARGET = "fovjax_select_samples"
FILL_TARGET = "fovjax_fill_and_blur"
SLOTS_TARGET = "fovjax_whitted_slots"
_FLAGS = ("-O3", "-fno-math-errno", "-ffp-contract=off", "-std=c++17", "-shared", "-fPIC", "-Wno-attributes")

_lock = threading.Lock()
_state: dict = {}


class NativeStatus:
    """Whether the Embree FFI backend can run here, and why not if it cannot."""

    def __init__(self, available: bool, reason: str, library: str | None = None, **info):
        self.available = available
        self.reason = reason
        self.library = library
        self.info = info

    def __bool__(self) -> bool:
        return self.available

    def __repr__(self) -> str:
        return f"NativeStatus(available={self.available}, reason={self.reason!r})"


def _native_dir() -> Path:
    env = os.environ.get("FOVJAX_NATIVE_DIR")
    if env:
        return Path(env)
    root = os.environ.get("FOVJAX_CACHE_DIR")
    if root:
        return Path(root) / "native"
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "fovjax" / "native"


def _compiler() -> str | None:
    for name in (os.environ.get("CXX"), "c++", "g++", "clang++"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


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


def _build(compiler: str) -> tuple[Path, float]:
    """The compiled handler's path (compiling it if absent) and the seconds spent compiling."""
    include = jax.ffi.include_dir()
    import jaxlib

    version = subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=30).stdout
    digest = hashlib.sha256()
    for part in (
        SOURCE.read_bytes(),
        # jaxlib's version attribute (pyright cannot see it).
        jaxlib.__version__.encode(),  # pyright: ignore[reportPrivateImportUsage]
        version.encode(),
        " ".join(_FLAGS).encode(),
    ):
        digest.update(part)
    out_dir = _native_dir()
    path = out_dir / f"fovjax_embree_ffi-{digest.hexdigest()[:16]}.so"
    if path.exists():
        return path, 0.0
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    fd, tmp = tempfile.mkstemp(prefix=path.stem + ".", suffix=".tmp.so", dir=out_dir)
    os.close(fd)
    try:
        cmd = [compiler, *_FLAGS, f"-I{include}", str(SOURCE), "-o", tmp]
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
        if done.returncode != 0:
            lines = [ln for ln in done.stderr.splitlines() if "error" in ln][:3] or done.stderr.splitlines()[
                -3:
            ]
            raise RuntimeError(f"{Path(compiler).name} failed to compile {SOURCE.name}: " + " | ".join(lines))
        os.replace(tmp, path)  # atomic: a concurrent process never loads half a library
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path, time.perf_counter() - t0


def embree_status() -> NativeStatus:
    """Build (once), load and register the Embree FFI handler; cached for the process."""
    with _lock:
        if "status" not in _state:
            _state["status"] = _load()
        return _state["status"]


def _load() -> NativeStatus:
    if os.environ.get("FOVJAX_NATIVE", "1") == "0":
        return NativeStatus(False, "turned off by FOVJAX_NATIVE=0")
    if not sys.platform.startswith("linux"):
        return NativeStatus(False, f"the Embree FFI handler is built for Linux only (this is {sys.platform})")
    library = embree_library()
    if library is None:
        return NativeStatus(False, "embreex is not installed (pip install 'fovjax[embree]')")
    compiler = _compiler()
    if compiler is None:
        return NativeStatus(False, "no C++ compiler found (set CXX, or install g++)")
    try:
        path, seconds = _build(compiler)
    except (OSError, RuntimeError, subprocess.SubprocessError) as exc:
        return NativeStatus(False, f"could not build the Embree FFI handler: {exc}")
    try:
        lib = ctypes.CDLL(str(path))
    except OSError as exc:
        return NativeStatus(False, f"could not load {path}: {exc}")
    lib.fovjax_embree_init.argtypes = [ctypes.c_char_p]
    lib.fovjax_embree_error.restype = ctypes.c_char_p
    lib.fovjax_embree_version.restype = ctypes.c_long
    lib.fovjax_embree_release.argtypes = [ctypes.c_int32]
    if lib.fovjax_embree_init(library.encode()) != 0:
        return NativeStatus(False, f"Embree ({Path(library).name}): {lib.fovjax_embree_error().decode()}")
    jax.ffi.register_ffi_target(TARGET, jax.ffi.pycapsule(lib.FovjaxEmbreeQuery), platform="cpu")
    jax.ffi.register_ffi_target(WHITTED_TARGET, jax.ffi.pycapsule(lib.FovjaxEmbreeWhitted), platform="cpu")
    jax.ffi.register_ffi_target(SELECT_TARGET, jax.ffi.pycapsule(lib.FovjaxSelectSamples), platform="cpu")
    jax.ffi.register_ffi_target(FILL_TARGET, jax.ffi.pycapsule(lib.FovjaxFillAndBlur), platform="cpu")
    jax.ffi.register_ffi_target(SLOTS_TARGET, jax.ffi.pycapsule(lib.FovjaxWhittedSlots), platform="cpu")
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


def release_embree_scenes(host_id: int | None = None) -> int:
    """Free the Embree scenes built for one BVH (its `host_id`) or for all (None); they are
    rebuilt on next use. Returns how many were freed."""
    lib = _state.get("lib")
    if lib is None:
        return 0
    return int(lib.fovjax_embree_release(-1 if host_id is None else int(host_id)))


def cached_embree_scenes() -> int:
    lib = _state.get("lib")
    return 0 if lib is None else int(lib.fovjax_embree_cached_scenes())
