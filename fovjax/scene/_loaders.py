"""`load_scene`: OBJ+MTL, glTF/GLB and PLY files into a `Scene`, through trimesh.

trimesh parses the geometry. Around it this module adds what a renderer needs and what trimesh
leaves out or gets wrong silently:

- OBJ: a fast pre-scan of the text (regular expressions over the whole file, no Python loop per
  line unless something is wrong) that reports NaN/inf or unparsable numbers, index 0 and
  out-of-range `v`/`vt`/`vn` indices with their line number (trimesh would crash with a bare
  IndexError, or silently wrap index 0 and drop bad UVs), and rewrites relative (negative)
  indices to absolute ones (trimesh resolves them against the end of the file, not the line).
- MTL: our own parser, because trimesh keeps only Kd/Ka/Ks/Ns and a bare `map_Kd` file name.
  It reads Ka, Kd, Ks, Ke, Ns, the reflectivity (see `load_scene`) and `map_Kd` with options.
- glTF: metallic-roughness PBR parameters mapped to Blinn-Phong (see `load_scene`).
- Textures: decoded to float32 linear RGB (sRGB transfer function removed), flipped so that
  row 0 is v = 0; `Materials.texture` indexes `Scene.textures`.

One private module per format: `_obj.py` (OBJ and MTL), `_gltf.py`, `_ply.py`; `_parts.py` holds
what they share (`_Part`, the texture table, texture files); this module dispatches on the
suffix and assembles the parts into a `Scene`.
"""

from __future__ import annotations

from pathlib import Path

import equinox as eqx
import numpy as np

from ._gltf import _load_gltf
from ._obj import _load_obj
from ._parts import (
    SUPPORTED_FORMATS,
    _TextureTable,
)
from ._ply import _load_ply
from ._scene import Lights, Materials, Scene, Textures, _build_scene, make_lights, make_materials


def load_scene(
    path,
    *,
    scale: float = 1.0,
    lights: Lights | None = None,
    name: str | None = None,
) -> Scene:
    """Load a triangle scene from an OBJ (+MTL), glTF/GLB or PLY file.

    Args:
        path: the file; its extension picks the format (.obj, .gltf, .glb, .ply).
        scale: multiplies every vertex position (the thesis loaded Sponza scaled by 2).
        lights: the scene's lights. Files carry none that we read, so by default one white point
            light (colour 1) is a headlight at the position of `fovjax.scenes.default_camera`
            for the loaded scene: every surface point that camera sees has a clear line to the
            light, so the default view shows the whole model lit (shaded by n·l, no shadow
            visible from there). Materials keep the file's Ka (MTL's default is 0, so the scene's
            ambient adds nothing unless the file sets Ka). Pass `lights` for any other set-up.
        name: the scene's name; defaults to the file's stem.

    Materials (`Scene.materials`, Blinn-Phong; the diffuse colour at a point is
    `kd * texture(uv)` where `texture >= 0`, as the MTL spec multiplies `map_Kd` by `Kd` and glTF
    multiplies `baseColorTexture` by `baseColorFactor`; colours are linear RGB):

    - OBJ/MTL: `Ka`, `Kd`, `Ks`, `Ke` (emission), `Ns`, `map_Kd` (with its options skipped).
      Reflectivity `kr`, first match wins: `Kr r [g b]` (an extension used by Whitted ray
      tracers, the thesis's Kr); `refl` followed by numbers only (`refl 0.5`, a scalar form some
      exporters write; the MTL spec's `refl -type sphere file` is a reflection *map* and is
      ignored); otherwise `illum` 3 to 7 ("reflection on, ray trace on" in the MTL spec), which
      by that spec reflects with the colour `Ks`. Sponza's MTL uses `illum 2`, so it has no
      mirrors. A face without `usemtl`, or with a name no MTL defines, gets a default grey
      material (the latter with a warning). Alpha (`d`, `map_d`), bump and specular maps are
      ignored.
    - glTF: per primitive, `baseColorFactor`/`baseColorTexture`, `metallicFactor`,
      `roughnessFactor` (spec defaults 1 when absent) and `emissiveFactor`, mapped as
      `kd = base * (1 - metallic)`, `ka = kd`,
      `ks = 0.04 * (1 - metallic) + base * metallic` (the Fresnel reflectance at normal
      incidence), `ns = 2 / roughness**4 - 2` clipped to [1, 10000] (the Blinn-Phong exponent
      whose lobe matches a microfacet distribution of width `alpha = roughness**2`),
      `kr = ks * (1 - roughness)**2` (only smooth surfaces mirror), `ke = emissiveFactor`.
      trimesh stores `baseColorFactor` as 8-bit, so `kd` is quantised to 1/255.
    - PLY: geometry only, one default grey material (colours are not read).

    Textures are read with Pillow, converted to RGB, decoded from sRGB to linear float32 and
    flipped vertically so that `Scene.textures[i][row, col]` covers `v = (row + 0.5) / H`,
    `u = (col + 0.5) / W`, with the OBJ convention (v = 0 at the bottom of the image; trimesh
    converts glTF UVs to it). A texture file that is missing or unreadable gives a warning
    naming it, and the material falls back to its `kd`.

    Vertex normals and texture coordinates are kept when the file has them (normals are
    normalised; parts without normals get trimesh's area-weighted ones, parts without UVs get 0).

    Errors name the file and the line (OBJ/MTL) or field: a missing file raises
    `FileNotFoundError`; an unreadable one `OSError`; an unknown extension, a file that does not
    parse, no triangles, NaN/inf values, or face indices out of range raise `ValueError`.
    Zero-area triangles are dropped with a warning giving their count.
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in SUPPORTED_FORMATS:
        known = ", ".join(SUPPORTED_FORMATS)
        raise ValueError(f"{path}: unknown scene format {ext!r} (supported: {known})")
    if not path.exists():
        raise FileNotFoundError(f"{path}: scene file does not exist")
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a directory, not a scene file")
    try:
        data = path.read_bytes()
    except OSError as e:
        raise OSError(f"{path}: cannot read scene file ({e.strerror or e})") from e
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"load_scene: scale must be a positive finite number, got {scale}")

    textures = _TextureTable()
    if ext == ".obj":
        parts, specs, names = _load_obj(path, data, textures)
    elif ext in (".gltf", ".glb"):
        parts, specs, names = _load_gltf(path, data, textures)
    else:
        parts, specs, names = _load_ply(path, data)
    if not parts:
        raise ValueError(f"{path}: the file contains no triangles")
    return _assemble(path, parts, specs, names, textures, scale=scale, lights=lights, name=name)


# ----------------------------------------------------------------------------------------------
# Assembly


def _assemble(path, parts, specs, names, textures, *, scale, lights, name) -> Scene:
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts])
    vertices = np.concatenate([p.vertices for p in parts]) * scale
    faces = np.concatenate([p.faces + o for p, o in zip(parts, offsets[:-1], strict=True)])
    face_material = np.concatenate([np.full(len(p.faces), p.material, np.int32) for p in parts])

    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"{path}: {int(bad.sum())} vertices are NaN or infinite "
            f"(first: vertex {i} = {vertices[i].tolist()})"
        )
    out = (faces < 0) | (faces >= len(vertices))
    if out.any():
        i = int(np.flatnonzero(out.any(axis=1))[0])
        raise ValueError(
            f"{path}: face {i} has vertex index {faces[i].tolist()} out of range for {len(vertices)} vertices"
        )

    normals = None
    if any(p.normals is not None for p in parts):
        import trimesh

        chunks = []
        for p in parts:
            n = p.normals
            if n is None or n.shape != p.vertices.shape:
                n = trimesh.Trimesh(p.vertices, p.faces, process=False).vertex_normals
            n = np.asarray(n, np.float64)
            if not np.isfinite(n).all():
                raise ValueError(f"{path}: vertex normals contain NaN or infinite values")
            length = np.linalg.norm(n, axis=1, keepdims=True)
            zero = length[:, 0] == 0
            if zero.any():
                fallback = trimesh.Trimesh(p.vertices, p.faces, process=False).vertex_normals
                n[zero] = fallback[zero]
                length = np.linalg.norm(n, axis=1, keepdims=True)
            chunks.append(n / np.maximum(length, 1e-30))
        normals = np.concatenate(chunks)

    uvs = None
    if any(p.uvs is not None for p in parts):
        chunks = []
        for p in parts:
            uv = p.uvs
            if uv is None or uv.shape != (len(p.vertices), 2):
                uv = np.zeros((len(p.vertices), 2))
            chunks.append(uv)
        uvs = np.concatenate(chunks)
        if not np.isfinite(uvs).all():
            raise ValueError(f"{path}: texture coordinates contain NaN or infinite values")

    headlight = lights is None
    if headlight:  # placeholder until the scene exists to place the camera in
        lights = make_lights([[0.0, 0.0, 0.0]], [[1.0, 1.0, 1.0]])
    materials: Materials = make_materials(specs, names=names)
    scene = _build_scene(
        str(path),
        vertices,
        faces,
        face_material=face_material,
        materials=materials,
        lights=lights,
        normals=normals,
        uvs=uvs,
        textures=Textures(tuple(textures.images), tuple(textures.names)),
        name=name or Path(path).stem,
    )
    if headlight:
        from ._poses import default_camera

        eye = default_camera(scene).position
        scene = eqx.tree_at(lambda s: s.lights, scene, make_lights([eye], [[1.0, 1.0, 1.0]]))
    return scene
