"""The native handlers: one library of XLA FFI handlers (Embree ray queries, the Whitted
integrator, the foveated frame's selection, slots and reconstruction), built with the system's
C++ compiler on first use, and the one place a program chooses between a stage's native and JAX
implementations.

- `status()`: whether the handlers built and loaded here, and why not where they did not;
- `start_build()`, `building()`: build them in the background while other work goes on
  (`status()` waits for it);
- `release_scenes(host_id)`, `cached_scenes()`: the Embree scenes the handlers keep per BVH;
- `sources()`: the native sources (each beside the package that owns its JAX oracle).

Siblings use `fovjax.native.internal` (`plan_native`, `on_platforms`, `handler`, the layout).
"""

from ._library import NativeStatus as NativeStatus
from ._library import building as building
from ._library import cached_scenes as cached_scenes
from ._library import embree_library as embree_library
from ._library import release_scenes as release_scenes
from ._library import sources as sources
from ._library import start_build as start_build
from ._library import status as status

__all__ = [
    "NativeStatus",
    "building",
    "cached_scenes",
    "embree_library",
    "release_scenes",
    "sources",
    "start_build",
    "status",
]
