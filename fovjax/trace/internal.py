"""What the renderer shares with the ray queries and users do not need: the backend's own
distance and barycentrics of a hit with the closed-form derivatives of `hit_geometry`. Sibling
packages import it from here; nothing here is part of the stable public API."""

from ._query import _backend_geometry as backend_geometry

__all__ = ["backend_geometry"]
