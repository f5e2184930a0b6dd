"""What the renderer shares with the ray queries and users do not need: the backend's own
distance and barycentrics of a hit with the closed-form derivatives of `hit_geometry`, and the
Warp meshes of BVHs (`warp_mesh_words`: a mesh's id as operand of a Warp kernel) and Warp itself,
imported and initialised quietly (`require_warp`). Sibling
packages import it from here; nothing here is part of the stable public API."""

from ._backends import lowering_platform as lowering_platform
from ._query import _backend_geometry as backend_geometry
from ._warp import _require_warp as require_warp
from ._warp import compile_ahead as compile_warp_ahead
from ._warp import mesh_id_target as mesh_id_target
from ._warp import warp_mesh_words as warp_mesh_words

__all__ = [
    "backend_geometry",
    "compile_warp_ahead",
    "lowering_platform",
    "mesh_id_target",
    "require_warp",
    "warp_mesh_words",
]
