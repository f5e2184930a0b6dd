"""BVH construction and ray queries.

- `build_bvh(scene)` — binned SAH on the host, cached on disk;
- `closest_hit(bvh, origins, directions, tmin, tmax)` → `Hit(t, prim, u, v)`;
- `occluded(bvh, origins, directions, tmax)` → bool;
both with `backend="jax"` (default, any XLA device) or `"embree"` (CPU, needs embreex);
- `merge_bvhs(bvhs)` → one BVH of several trees (levels of detail), queried with `level=` per ray.
"""

from ._build import BuildParams as BuildParams
from ._bvh import BVH as BVH
from ._bvh import build_bvh as build_bvh
from ._bvh import last_build_info as last_build_info
from ._bvh import merge_bvhs as merge_bvhs
from ._query import (
    BACKENDS as BACKENDS,
)
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
