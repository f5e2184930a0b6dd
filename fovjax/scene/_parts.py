"""What every format's loader produces, and what they share: geometry parts with one material
each, the table of textures (decoded to float32 linear RGB, deduplicated) they index, texture
files found by a case-insensitive name."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

SUPPORTED_FORMATS = {".obj": "OBJ", ".gltf": "glTF", ".glb": "glTF binary", ".ply": "PLY"}


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The inverse sRGB transfer function (IEC 61966-2-1), for values in [0, 1]."""
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


_SRGB8_TO_LINEAR = srgb_to_linear(np.arange(256) / 255.0).astype(np.float32)


@dataclass
class _Part:
    """One piece of geometry with a single material (world space)."""

    vertices: np.ndarray
    faces: np.ndarray
    material: int
    normals: np.ndarray | None = None
    uvs: np.ndarray | None = None


@dataclass
class _TextureTable:
    """Textures loaded so far, deduplicated by resolved path (or by image identity)."""

    images: list = field(default_factory=list)
    names: list = field(default_factory=list)
    index: dict = field(default_factory=dict)

    def add(self, key, name: str, image: np.ndarray) -> int:
        if key not in self.index:
            self.index[key] = len(self.images)
            self.images.append(image)
            self.names.append(name)
        return self.index[key]


def _optional(a):
    return None if a is None else np.asarray(a, np.float64)


def _resolve_case(p: Path) -> Path:
    """The path itself if it exists, else a case-insensitive match in its folder (files
    written on Windows often differ in case from the names in the MTL), else the path."""
    if p.exists() or not p.parent.is_dir():
        return p
    lower = p.name.lower()
    for candidate in p.parent.iterdir():
        if candidate.name.lower() == lower:
            return candidate
    return p


# ----------------------------------------------------------------------------------------------
# Textures


def image_to_linear_rgb(image) -> np.ndarray:
    """A PIL image to (H, W, 3) float32 linear RGB, row 0 at the image's bottom (v = 0)."""
    rgb = np.asarray(image.convert("RGB"), dtype=np.uint8)
    return np.ascontiguousarray(_SRGB8_TO_LINEAR[rgb][::-1])


def _load_texture_file(folder: Path, file_name: str, where: str, textures: _TextureTable) -> int | None:
    from PIL import Image

    tex_path = _resolve_case(folder / file_name)
    key = str(tex_path.resolve()) if tex_path.exists() else None
    if key is not None and key in textures.index:
        return textures.index[key]
    if not tex_path.is_file():
        warnings.warn(
            f"{where}: texture file {file_name!r} not found (looked for {tex_path}); using Kd instead",
            stacklevel=5,
        )
        return None
    try:
        with Image.open(tex_path) as image:
            pixels = image_to_linear_rgb(image)
    except Exception as e:  # Pillow raises several kinds on corrupt or unknown images
        warnings.warn(f"{where}: cannot read texture {str(tex_path)!r} ({e}); using Kd instead", stacklevel=5)
        return None
    return textures.add(key, file_name, pixels)
