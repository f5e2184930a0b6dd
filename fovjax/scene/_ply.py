"""PLY through trimesh: one part with the file's vertex normals, the default material."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from ._parts import (
    _optional,
    _Part,
)

# ----------------------------------------------------------------------------------------------
# PLY


def _load_ply(path: Path, data: bytes):
    import trimesh.exchange.ply

    try:
        loaded = trimesh.exchange.ply.load_ply(io.BytesIO(data))
    except Exception as e:  # trimesh raises assorted errors on malformed files
        raise ValueError(f"{path}: could not parse PLY ({type(e).__name__}: {e})") from e
    faces = loaded.get("faces")
    if faces is None or len(faces) == 0:
        raise ValueError(f"{path}: the PLY has no faces (element 'face' is missing or empty)")
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"{path}: PLY faces must be triangles; got faces of shape {faces.shape}")
    vertices = np.asarray(loaded["vertices"], np.float64)
    part = _Part(
        vertices=vertices,
        faces=faces.astype(np.int64),
        material=0,
        normals=_optional(loaded.get("vertex_normals")),
    )
    return [part], [{}], ["default"]
