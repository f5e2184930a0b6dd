"""BVH construction and ray queries.

- `build_bvh(scene)` — binned SAH on the host, cached on disk;
- `closest_hit(bvh, origins, directions, tmin, tmax)` → `Hit(t, prim, u, v)`;
- `occluded(bvh, origins, directions, tmax)` → bool;
on a backend: `"auto"` (default: Embree through XLA's FFI on CPU, Warp on CUDA, else JAX,
chosen per platform inside the program), `"embree"`, `"warp"` or `"jax"` (the `while_loop`
traversal, any XLA device: the reference the others are tested against), or one registered with
`register_backend` (a `RayBackend`); `describe_backend()` names what "auto" runs and why,
`embree_status()` whether the native handlers (`fovjax.native`) built, `start_embree_build()`
builds them in the background ahead of use (a first run);
- `merge_bvhs(bvhs)` → one BVH of several trees (levels of detail), queried with `level=` per ray;
- `Traversal(lanes=, packets=, steps_per_refill=)`: the JAX traversal's tuning (`traversal=`).
"""

from ..native import release_scenes as release_embree_scenes
from ..native import start_build as start_embree_build
from ..native import status as embree_status
from ._backends import BACKENDS as BACKENDS
from ._backends import BUILTIN_BACKENDS as BUILTIN_BACKENDS
from ._backends import QueryOptions as QueryOptions
from ._backends import RayBackend as RayBackend
from ._backends import RayBatch as RayBatch
from ._backends import backend_names as backend_names
from ._backends import describe_backend as describe_backend
from ._backends import register_backend as register_backend
from ._backends import resolve_backend as resolve_backend
from ._backends import unregister_backend as unregister_backend
from ._build import BuildParams as BuildParams
from ._bvh import BVH as BVH
from ._bvh import build_bvh as build_bvh
from ._bvh import last_build_info as last_build_info
from ._bvh import merge_bvhs as merge_bvhs
from ._query import (
    Hit as Hit,
)
from ._query import (
    brute_force_closest_hit as brute_force_closest_hit,
)
from ._query import (
    closest_hit as closest_hit,
)
from ._query import (
    hit_geometry as hit_geometry,
)
from ._query import (
    occluded as occluded,
)
from ._traverse import Traversal as Traversal

__all__ = [
    "BuildParams",
    "BVH",
    "build_bvh",
    "last_build_info",
    "merge_bvhs",
    "embree_status",
    "release_embree_scenes",
    "start_embree_build",
    "BACKENDS",
    "BUILTIN_BACKENDS",
    "QueryOptions",
    "RayBackend",
    "RayBatch",
    "backend_names",
    "register_backend",
    "unregister_backend",
    "Hit",
    "brute_force_closest_hit",
    "closest_hit",
    "describe_backend",
    "hit_geometry",
    "occluded",
    "resolve_backend",
    "Traversal",
]
