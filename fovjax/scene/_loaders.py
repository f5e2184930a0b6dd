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
what they share (`_Part`, the texture table, texture files); `_files.py` turns a folder, a
pattern or a list into the files to read. This module dispatches each file on its suffix and
assembles the parts of all the files into one `Scene`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import equinox as eqx
import numpy as np

from ._files import scene_files
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
    skip: int | Sequence[int] = (),
    scale: float = 1.0,
    lights: Lights | None = None,
    name: str | None = None,
) -> Scene:
    """Load a triangle scene from OBJ (+MTL), glTF/GLB or PLY files: one file or many.

    Args:
        path: the file; its extension picks the format (.obj, .gltf, .glb, .ply). Or several
            files making one scene: a folder (its scene files), a glob pattern, or a list of
            these; `scene_files(path)` lists them in the order `skip` counts (by name, with
            numbers compared as numbers: `part_2.obj` before `part_10.obj`).
        skip: indices (from 0) into that list of files to leave out. The thesis loads Sponza
            from its 382 parts, `sponza_0.obj` to `sponza_381.obj`, leaving out parts 2 and 4,
            scaled by 2 (its Figure 54): `load_scene("Sponza/sponza_*.obj", skip=[2, 4],
            scale=2)`.
        scale: multiplies every vertex position (the thesis loaded Sponza scaled by 2).
        lights: the scene's lights. Files carry none that we read, so by default one white point
            light (colour 1) is a headlight at the position of `fovjax.scenes.default_camera`
            for the loaded scene: every surface point that camera sees has a clear line to the
            light, so the default view shows the whole model lit (shaded by n·l, no shadow
            visible from there). Materials keep the file's Ka (MTL's default is 0, so the scene's
            ambient adds nothing unless the file sets Ka). Pass `lights` for any other set-up.
        name: the scene's name; defaults to the file's stem, or with several files to the name
            of the folder holding the first.

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

    With several files each keeps its own materials: a material that another file already
    defined with the same name and the same values is shared (parts of one model usually
    share one MTL); one with the same name and other values is kept apart, named
    `"name (file name)"`. Textures are decoded once however many files use them.

    Textures are read with Pillow, converted to RGB, decoded from sRGB to linear float32 and
    flipped vertically so that `Scene.textures[i][row, col]` covers `v = (row + 0.5) / H`,
    `u = (col + 0.5) / W`, with the OBJ convention (v = 0 at the bottom of the image; trimesh
    converts glTF UVs to it). A texture file that is missing or unreadable gives a warning
    naming it, and the material falls back to its `kd`.

    Vertex normals and texture coordinates are kept when the file has them (normals are
    normalised; parts without normals get trimesh's area-weighted ones, parts without UVs get 0).

    Errors name the file and the line (OBJ/MTL) or field, and are raised for every file before
    any is parsed where they can be: a missing file raises `FileNotFoundError` (so does a folder
    or pattern with no scene file); an unreadable one `OSError`; a `skip` index out of range or
    a `scale` that is not a positive finite number, an unknown extension, a file that does not
    parse, no triangles, NaN/inf values, or face indices out of range raise `ValueError` (with
    several files, a file's error also gives its index, for `skip`). Zero-area triangles are
    dropped with a warning giving their count.
    """
    _check_scale(scale)
    files = scene_files(path)
    skipped = _check_skip(skip, len(files))
    chosen = [(i, f) for i, f in enumerate(files) if i not in skipped]
    if not chosen:
        n = len(files)
        files_text = f"{n} file{'s' * (n != 1)}"
        raise ValueError(f"load_scene: skip={sorted(skipped)} leaves none of the {files_text} to load")
    for _, file in chosen:  # every file checked before any is parsed
        ext = file.suffix.lower()
        if ext not in SUPPORTED_FORMATS:
            known = ", ".join(SUPPORTED_FORMATS)
            raise ValueError(f"{file}: unknown scene format {ext!r} (supported: {known})")
        if not file.exists():  # a folder is expanded by scene_files, so a path that exists is a file
            raise FileNotFoundError(f"{file}: scene file does not exist")

    textures = _TextureTable()
    parts, materials = [], _MaterialTable()
    for i, file in chosen:
        try:
            file_parts, specs, names = _load_file(file, textures)
        except ValueError as e:
            if len(files) == 1:
                raise
            hint = f"index {i} of the {len(files)} scene files; skip=[{i}] leaves it out"
            raise ValueError(f"{e} ({hint})") from e
        index = [materials.add(spec, n, file) for spec, n in zip(specs, names, strict=True)]
        parts += [dataclasses.replace(p, material=index[p.material]) for p in file_parts]
    first = chosen[0][1]
    where = str(first) if len(chosen) == 1 else f"{first.parent} ({len(chosen)} scene files)"
    if name is None:
        name = files[0].stem if len(files) == 1 else files[0].resolve().parent.name
    return _assemble(where, parts, materials, textures, scale=scale, lights=lights, name=name)


def _load_file(file: Path, textures: _TextureTable):
    try:
        data = file.read_bytes()
    except OSError as e:
        raise OSError(f"{file}: cannot read scene file ({e.strerror or e})") from e
    ext = file.suffix.lower()
    if ext == ".obj":
        parts, specs, names = _load_obj(file, data, textures)
    elif ext in (".gltf", ".glb"):
        parts, specs, names = _load_gltf(file, data, textures)
    else:
        parts, specs, names = _load_ply(file, data)
    if not parts:
        raise ValueError(f"{file}: the file contains no triangles")
    return parts, specs, names


def _check_scale(scale) -> None:
    if not isinstance(scale, int | float | np.integer | np.floating) or isinstance(scale, bool):
        raise TypeError(f"load_scene: scale must be a number, got {scale!r} ({type(scale).__name__})")
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"load_scene: scale must be a positive finite number, got {scale!r}")


def _check_skip(skip, count: int) -> set[int]:
    values = [skip] if isinstance(skip, int | np.integer) else skip
    try:
        values = list(values)
    except TypeError:
        raise TypeError(
            f"load_scene: skip must be a file index or a list of them, got {skip!r} ({type(skip).__name__})"
        ) from None
    for value in values:
        if not isinstance(value, int | np.integer) or isinstance(value, bool):
            raise TypeError(
                f"load_scene: skip holds {value!r} ({type(value).__name__}); expected file indices (int)"
            )
        if not 0 <= value < count:
            raise ValueError(
                f"load_scene: skip index {value} is out of range: the scene has {count} "
                f"file{'s' if count != 1 else ''} (indices 0 to {count - 1})"
            )
    return {int(v) for v in values}


class _MaterialTable:
    """Materials of several files: one entry per distinct (name, values); a name that comes back
    with other values is kept apart under the file's name."""

    def __init__(self):
        self.specs: list[dict] = []
        self.names: list[str] = []
        self.index: dict = {}

    def add(self, spec: dict, name: str, file: Path) -> int:
        values = tuple(sorted((k, tuple(np.ravel(v).tolist())) for k, v in spec.items() if k != "name"))
        key = (name, values)
        if key not in self.index:
            shown = name if name not in self.names else f"{name} ({file.name})"
            self.index[key] = len(self.specs)
            self.specs.append(spec)
            self.names.append(shown)
        return self.index[key]


# ----------------------------------------------------------------------------------------------
# Assembly


def _assemble(path, parts, material_table, textures, *, scale, lights, name) -> Scene:
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
    materials: Materials = make_materials(material_table.specs, names=material_table.names)
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
        name=name,
    )
    if headlight:
        from ._poses import default_camera

        eye = default_camera(scene).position
        scene = eqx.tree_at(lambda s: s.lights, scene, make_lights([eye], [[1.0, 1.0, 1.0]]))
    return scene
