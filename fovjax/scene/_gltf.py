"""glTF and GLB through trimesh: missing image files reported by name, metallic-roughness PBR
mapped to Blinn-Phong."""

from __future__ import annotations

import json
import struct
import warnings
from pathlib import Path

import numpy as np

from ._parts import (
    SUPPORTED_FORMATS,
    _optional,
    _Part,
    _TextureTable,
    image_to_linear_rgb,
)

# ----------------------------------------------------------------------------------------------
# glTF


def _gltf_missing_images(path: Path, data: bytes) -> None:
    """Warn about image files a glTF references that do not exist (trimesh drops them silently)."""
    try:
        if path.suffix.lower() == ".glb":
            if data[:4] != b"glTF":
                return
            (length,) = struct.unpack_from("<I", data, 12)
            header = json.loads(data[20 : 20 + length])
        else:
            header = json.loads(data)
    except Exception:
        return  # trimesh reports the parse error itself
    for i, image in enumerate(header.get("images", []) or []):
        uri = image.get("uri")
        if not uri or uri.startswith("data:"):
            continue
        from urllib.parse import unquote

        image_path = path.parent / unquote(uri)
        if not image_path.is_file():
            warnings.warn(
                f"{path}: texture file {uri!r} (images[{i}]) not found (looked for {image_path}); "
                "materials using it fall back to baseColorFactor",
                stacklevel=4,
            )


def _load_gltf(path: Path, data: bytes, textures: _TextureTable):
    import trimesh

    _gltf_missing_images(path, data)
    try:
        scene = trimesh.load(path, force="scene", process=False)
    except Exception as e:  # trimesh raises assorted errors on malformed files
        raise ValueError(f"{path}: could not parse {SUPPORTED_FORMATS[path.suffix.lower()]} ({e})") from e
    if not isinstance(scene, trimesh.Scene):  # force="scene" makes one
        raise ValueError(f"{path}: trimesh did not read a scene from it")
    specs, names, lookup = [], [], {}
    parts = []
    for node in scene.graph.nodes_geometry:
        transform, geometry_name = scene.graph[node]
        geometry = scene.geometry[geometry_name]
        faces = getattr(geometry, "faces", None)
        if faces is None or len(faces) == 0:
            continue  # points or lines
        material = getattr(geometry.visual, "material", None)
        key = id(material) if material is not None else None
        if key not in lookup:
            lookup[key] = len(specs)
            spec, material_name = _pbr_to_blinn_phong(material, textures)
            specs.append(spec)
            names.append(material_name or f"material{len(names)}")
        vertices = np.asarray(geometry.vertices, np.float64)
        transform = np.asarray(transform, np.float64)
        vertices = vertices @ transform[:3, :3].T + transform[:3, 3]
        normals = None
        if "vertex_normals" in geometry._cache:  # only normals the file provided
            normal_matrix = np.linalg.inv(transform[:3, :3]).T
            normals = np.asarray(geometry.vertex_normals, np.float64) @ normal_matrix.T
        faces = np.asarray(faces, np.int64)
        if np.linalg.det(transform[:3, :3]) < 0:
            faces = faces[:, ::-1]  # a mirroring node transform flips the winding
        uv = getattr(geometry.visual, "uv", None)
        parts.append(
            _Part(vertices=vertices, faces=faces, material=lookup[key], normals=normals, uvs=_optional(uv))
        )
    return parts, specs, names


def _pbr_to_blinn_phong(material, textures: _TextureTable) -> tuple[dict, str | None]:
    """Map a trimesh material (PBRMaterial from glTF, or SimpleMaterial) to a `make_materials`
    spec; see `load_scene` for the formulas."""
    if material is None:
        return {}, None
    name = getattr(material, "name", None)
    if hasattr(material, "baseColorFactor") or hasattr(material, "metallicFactor"):
        factor = material.baseColorFactor
        base = np.ones(3) if factor is None else np.asarray(factor, np.float64)[:3] / 255.0
        metallic = 1.0 if material.metallicFactor is None else float(material.metallicFactor)
        roughness = 1.0 if material.roughnessFactor is None else float(material.roughnessFactor)
        metallic, roughness = float(np.clip(metallic, 0, 1)), float(np.clip(roughness, 0, 1))
        kd = base * (1.0 - metallic)
        ks = 0.04 * (1.0 - metallic) + base * metallic
        ns = float(np.clip(2.0 / max(roughness, 1e-3) ** 4 - 2.0, 1.0, 1e4))
        kr = ks * (1.0 - roughness) ** 2
        emissive = getattr(material, "emissiveFactor", None)
        ke = np.zeros(3) if emissive is None else np.asarray(emissive, np.float64)[:3]
        spec = {"ka": kd, "kd": kd, "ks": ks, "ns": ns, "kr": kr, "ke": ke}
        image = getattr(material, "baseColorTexture", None)
    else:  # SimpleMaterial: 8-bit RGBA colours
        spec = {}
        for key, attr in (("ka", "ambient"), ("kd", "diffuse"), ("ks", "specular")):
            value = getattr(material, attr, None)
            if value is not None:
                spec[key] = np.asarray(value, np.float64)[:3] / 255.0
        glossiness = getattr(material, "glossiness", None)
        if glossiness is not None:
            spec["ns"] = float(glossiness)
        image = getattr(material, "image", None)
    if image is not None:
        spec["texture"] = textures.add(("image", id(image)), name or "texture", image_to_linear_rgb(image))
    return spec, name
