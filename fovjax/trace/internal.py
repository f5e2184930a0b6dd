"""What the renderer shares with the ray queries and users do not need: the backend's own
distance and barycentrics of a hit with the closed-form derivatives of `hit_geometry`, and the
native Whitted integrator's call (`embree_whitted` on `whitted_operands`, with `embree_status`
saying whether it runs) and the foveated frame's native sample selection
(`native_select_samples`), integrator of its slots (`native_whitted_slots`) and
reconstruction (`native_fill_and_blur`). Sibling packages import
these from here; nothing here is part of the stable public API."""

from ._embree import embree_whitted as embree_whitted
from ._embree import native_fill_and_blur as native_fill_and_blur
from ._embree import native_select_samples as native_select_samples
from ._embree import native_whitted_slots as native_whitted_slots
from ._embree import whitted_operands as whitted_operands
from ._native import embree_status as embree_status
from ._query import _backend_geometry as backend_geometry

__all__ = [
    "backend_geometry",
    "embree_status",
    "embree_whitted",
    "native_fill_and_blur",
    "native_select_samples",
    "native_whitted_slots",
    "whitted_operands",
]
