"""`fovjax build`: build the native handlers (C++: the Embree ray queries, the Whitted integrator,
the foveated frame's selection, slots and fill) now, into the cache, so that the first
`fovjax render` does not wait for them. The install in README.md runs it; anything that renders
builds them on first use otherwise."""

from __future__ import annotations

import argparse
import sys
import time


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "build",
        help="build the native handlers (C++) now, so that the first render does not wait for them",
        description="Compile the native handlers (the Embree ray queries, the Whitted integrator and "
        "the foveated frame's stages, one C++ library) with the system's C++ compiler into fovjax's "
        "cache (FOVJAX_NATIVE_DIR, else FOVJAX_CACHE_DIR/native), load them and say where they are. "
        "Nothing is compiled where they are already built. Exit status 1 where they cannot be built "
        "or loaded here, with the reason (fovjax then renders with the JAX ray traversal and "
        "integrator).",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from fovjax import trace

    start = time.perf_counter()
    print(
        "fovjax build: the native handlers (C++): building them where they are not built ...",
        file=sys.stderr,
        flush=True,
    )
    found = trace.embree_status()
    if not found:
        print(
            f"fovjax build: the native handlers cannot run here: {found.reason} "
            "(fovjax renders with the JAX ray traversal and integrator instead)",
            file=sys.stderr,
        )
        return 1
    seconds = found.info.get("compile_seconds", 0.0)
    how = f"built in {seconds:.1f} s" if seconds else "already built"
    print(f"native handlers: {found.library} ({how}; {found.reason})")
    print(f"ready in {time.perf_counter() - start:.1f} s")
    return 0
