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
"""

from __future__ import annotations

import io
import json
import re
import struct
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import equinox as eqx
import numpy as np

from ._scene import Lights, Materials, Scene, make_lights, make_materials, make_scene

SUPPORTED_FORMATS = {".obj": "OBJ", ".gltf": "glTF", ".glb": "glTF binary", ".ply": "PLY"}

# MTL illumination models with ray-traced reflection ("Reflection on and Ray trace on", MTL spec:
# 3 = reflection, 4 = glass + reflection, 5 = Fresnel reflection, 6/7 = refraction + reflection).
_RAYTRACED_REFLECTION_ILLUM = {3, 4, 5, 6, 7}

# Options of MTL texture statements and how many arguments each takes (-o/-s/-t take 1 to 3).
_MTL_MAP_OPTIONS = {
    "-blendu": 1, "-blendv": 1, "-cc": 1, "-clamp": 1, "-texres": 1, "-bm": 1, "-boost": 1,
    "-imfchan": 1, "-type": 1, "-mm": 2, "-o": 3, "-s": 3, "-t": 3,
}  # fmt: skip


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
# OBJ


# Patterns start with a literal newline (the text is given a leading one), which the regex
# engine finds fast; `^` with re.M would be tried at every character of a large file.
_RE_USEMTL = re.compile(r"\nusemtl[ \t]+([^\n]*)")
_RE_MTLLIB = re.compile(r"\nmtllib[ \t]+([^\n]*)")
_RE_NEEDS_CLEANUP = re.compile(r"\n[ \t]+(?:v|vt|vn|f|usemtl|mtllib)\s|\n(?:v|vt|vn|f|usemtl|mtllib)\t")
_SYNTHETIC_MTL = "__fovjax_materials__.mtl"
_WIDTH = {"v": 3, "vt": 1, "vn": 3}


def _load_obj(path: Path, data: bytes, textures: _TextureTable):
    import trimesh

    text = data.decode("utf-8", errors="replace").replace("\r\n", "\n").replace("\r", "\n")
    text = "\n" + text  # so that every line, the first too, starts after a newline
    if _RE_NEEDS_CLEANUP.search(text):
        # trimesh expects keywords at the start of a line followed by one space
        text = re.sub(r"^[ \t]*(v|vt|vn|f|usemtl|mtllib)[ \t]+", r"\1 ", text, flags=re.M)
    text, _ = _prescan_obj(text, path)

    material_names = []
    for raw in _RE_USEMTL.findall(text):
        material_name = raw.split("#", 1)[0].strip()
        if material_name and material_name not in material_names:
            material_names.append(material_name)
    mtl_specs = {}
    for raw in _RE_MTLLIB.findall(text):
        for mtl_path in _mtllib_paths(path.parent, raw.split("#", 1)[0].strip()):
            if not mtl_path.is_file():
                warnings.warn(
                    f"{path}: material library {mtl_path.name!r} not found (looked for {mtl_path}); "
                    "its materials get the default grey",
                    stacklevel=3,
                )
                continue
            for material_name, spec in _parse_mtl(mtl_path, textures).items():
                mtl_specs.setdefault(material_name, spec)

    # Hand trimesh a material library with just the names, so that it groups faces by
    # material and tags each group with its name, without loading any image itself.
    synthetic = "".join(f"newmtl {n}\n" for n in material_names)
    text = _RE_MTLLIB.sub("\n", text)  # keep the line breaks, so line numbers stay right
    if material_names:
        text = f"mtllib {_SYNTHETIC_MTL}" + text  # on the empty line 0 we added
    try:
        loaded = trimesh.exchange.obj.load_obj(
            io.StringIO(text), resolver=_OneFileResolver(_SYNTHETIC_MTL, synthetic), group_material=True
        )
    except Exception as e:  # trimesh raises assorted errors on malformed files: find the line
        _walk_lines(text, path)
        raise ValueError(f"{path}: could not parse OBJ ({type(e).__name__}: {e})") from e
    geometries = loaded.get("geometry", {})
    for geometry in geometries.values():
        arrays = [
            geometry.get("vertices"),
            geometry.get("vertex_normals"),
            getattr(geometry.get("visual"), "uv", None),
        ]
        if any(a is not None and not np.isfinite(np.asarray(a, np.float64)).all() for a in arrays):
            _walk_lines(text, path)  # raises, naming the line with the NaN or inf

    # One material per usemtl name, in order of first use in the file; faces without a known
    # material share one default material, listed last.
    found = []
    for geometry in geometries.values():
        material = getattr(geometry.get("visual"), "material", None)
        found.append(getattr(material, "name", None) if material is not None else None)
    known = [n for n in material_names if n in mtl_specs and n in found]
    missing = [n for n in material_names if n not in mtl_specs and n in found]
    index = {n: i for i, n in enumerate(known)}
    specs = [mtl_specs[n] for n in known]
    names = list(known)
    if any(n not in index for n in found):
        specs.append({})
        names.append("default")

    parts = []
    for geometry, material_name in zip(geometries.values(), found, strict=True):
        faces = _fan_triangulate(np.asarray(geometry.get("faces", np.zeros((0, 3)))))
        if faces.size == 0:
            continue
        visual = geometry.get("visual")
        uv = getattr(visual, "uv", None) if visual is not None else None
        parts.append(
            _Part(
                vertices=np.asarray(geometry["vertices"], np.float64),
                faces=faces.astype(np.int64),
                material=index.get(material_name, len(known)),
                normals=_optional(geometry.get("vertex_normals")),
                uvs=_optional(uv),
            )
        )
    parts.sort(key=lambda p: p.material)
    if missing:
        warnings.warn(
            f"{path}: materials {missing} are used (usemtl) but no MTL file defines them; "
            "they get the default grey",
            stacklevel=3,
        )
    return parts, specs, names


def _fan_triangulate(faces: np.ndarray) -> np.ndarray:
    """(F, k) polygons (trimesh returns uniform quads or n-gons untriangulated) to triangles."""
    if faces.ndim != 2 or faces.shape[1] <= 3:
        return faces
    k = faces.shape[1]
    fans = [faces[:, [0, i, i + 1]] for i in range(1, k - 1)]
    return np.stack(fans, axis=1).reshape(-1, 3)


def _optional(a):
    return None if a is None else np.asarray(a, np.float64)


def _mtllib_paths(folder: Path, value: str) -> list[Path]:
    """`mtllib` takes one or more file names; a single name may contain spaces."""
    value = value.replace("\\", "/")
    whole = folder / value
    if whole.is_file() or " " not in value:
        return [_resolve_case(whole)]
    return [_resolve_case(folder / v) for v in value.split()]


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


class _OneFileResolver:
    """A trimesh resolver that serves one in-memory file (our synthetic MTL)."""

    def __init__(self, name: str, text: str):
        self.name, self.data = name, text.encode()

    def get(self, name):
        if name.strip() != self.name:
            raise FileNotFoundError(name)
        return self.data

    __getitem__ = get

    def namespaced(self, namespace):
        return self

    def keys(self):
        return [self.name]


def _prescan_obj(text: str, path: Path) -> tuple[str, dict]:
    """Check the faces of an OBJ text cheaply; return the text ready for trimesh and the
    number of v/vt/vn lines.

    The fast path looks at face lines as one string (NumPy parses the indices); only when it
    finds something unusual (relative indices, mixed face formats, an index 0 or out of range,
    fewer than 3 vertices) does `_walk_lines` go through the file line by line, to name the
    bad line or to rewrite relative indices. Vertex numbers are parsed by trimesh and only
    rechecked line by line if trimesh fails or returns NaN/inf.
    """
    counts = {key: text.count(f"\n{key} ") for key in ("v", "vt", "vn")}
    if counts["v"] == 0:
        raise ValueError(f"{path}: no vertices ('v' lines) found")
    face_lines = [chunk.partition("\n")[0] for chunk in text.split("\nf ")[1:]]
    if not face_lines:
        raise ValueError(f"{path}: no faces ('f' lines) found, so no triangles")
    if not _faces_look_valid(face_lines, counts):
        text = _walk_lines(text, path, check_numbers=False)
    return text, counts


def _faces_look_valid(face_lines: list[str], counts: dict) -> bool:
    """True if every face has >= 3 vertices of one uniform format (v, v/vt, v/vt/vn or v//vn)
    with absolute indices in range. False means "look closer", not necessarily an error."""
    joined = " ".join(face_lines)
    if "#" in joined or "-" in joined:
        return False  # comments or relative indices: the careful path handles them
    tokens = joined.split()
    if min(len(line.split()) for line in face_lines) < 3:
        return False
    n, first = len(tokens), tokens[0]
    slashes, double = first.count("/"), "//" in first
    if slashes > 2 or joined.count("/") != n * slashes or joined.count("//") != (n if double else 0):
        return False
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # fromstring warns (or raises) when it stops early
            values = np.fromstring(joined.replace("//", " ").replace("/", " "), sep=" ", dtype=np.int64)
    except (ValueError, DeprecationWarning):
        return False
    kinds = ["v", "vn"] if double else ["v", "vt", "vn"][: slashes + 1]
    if values.size != n * len(kinds):
        return False
    values = values.reshape(n, len(kinds))
    return all(values[:, k].min() >= 1 and values[:, k].max() <= counts[kind] for k, kind in enumerate(kinds))


def _walk_lines(text: str, path: Path, check_numbers: bool = True) -> str:
    """Check the file line by line: numbers of v/vt/vn lines (if `check_numbers`), and every
    face against the vertices defined before it; rewrite relative face indices to absolute ones
    (trimesh would resolve them against the end of the file). Raises naming the first bad line."""
    lines = text.split("\n")
    totals = {key: text.count(f"\n{key} ") for key in ("v", "vt", "vn")}
    counts = {"v": 0, "vt": 0, "vn": 0}
    # the text starts with a newline we added, so list index i is line i of the file
    for lineno, line in enumerate(lines):
        key, _, body = line.partition(" ")
        if key in counts:
            if check_numbers:
                _check_numbers(body.split("#", 1)[0].split(), key, line, f"{path}:{lineno}")
            counts[key] += 1
        elif key == "f":
            new = _check_face(body.split("#", 1)[0].split(), counts, totals, line, f"{path}:{lineno}")
            if new is not None:
                lines[lineno] = "f " + new
    return "\n".join(lines)


def _check_numbers(tokens, key, line, where):
    try:
        values = [float(t) for t in tokens]
    except ValueError:
        raise ValueError(
            f"{where}: {key!r} line has a value that is not a number: {line.strip()!r}"
        ) from None
    if len(values) < _WIDTH[key]:
        raise ValueError(f"{where}: {key!r} line needs at least {_WIDTH[key]} numbers: {line.strip()!r}")
    if not np.isfinite(values).all():
        raise ValueError(f"{where}: {key!r} line has a NaN or infinite value: {line.strip()!r}")


def _check_face(tokens, counts, totals, line, where) -> str | None:
    """Validate one face; return it with absolute indices if it had relative ones."""
    if len(tokens) < 3:
        raise ValueError(f"{where}: a face needs at least 3 vertices: {line.strip()!r}")
    changed, out = False, []
    for token in tokens:
        fields = token.split("/")
        if len(fields) > 3 or not fields[0]:
            raise ValueError(f"{where}: malformed face vertex {token!r} in {line.strip()!r}")
        new = []
        for value, kind in zip(fields, ("v", "vt", "vn"), strict=False):
            if value == "":
                new.append("")
                continue
            try:
                i = int(value)
            except ValueError:
                raise ValueError(
                    f"{where}: face index {value!r} is not an integer in {line.strip()!r}"
                ) from None
            if i < 0:
                if -i > counts[kind]:
                    raise ValueError(
                        f"{where}: relative {kind} index {i} reaches before the first {kind!r} line "
                        f"(only {counts[kind]} defined above this line)"
                    )
                i = counts[kind] + i + 1
                changed = True
            elif i == 0 or i > totals[kind]:
                raise ValueError(
                    f"{where}: {kind} index {i} out of range (the file has {totals[kind]} {kind!r} lines; "
                    "indices start at 1)"
                )
            new.append(str(i))
        out.append("/".join(new))
    return " ".join(out) if changed else None


# ----------------------------------------------------------------------------------------------
# MTL


def _parse_mtl(mtl_path: Path, textures: _TextureTable) -> dict[str, dict]:
    """Parse an MTL file into `make_materials` specs keyed by material name."""
    try:
        text = mtl_path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        warnings.warn(f"{mtl_path}: cannot read material library ({e}); using defaults", stacklevel=4)
        return {}
    specs: dict[str, dict] = {}
    current = None
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        key, args = parts[0].lower(), parts[1:]
        where = f"{mtl_path}:{lineno}"
        if key == "newmtl":
            name = " ".join(args)
            current = {"name": name, "_where": where}
            specs[name] = current
            continue
        if current is None:
            continue  # statements before the first newmtl have nothing to apply to
        if key in ("ka", "kd", "ks", "ke", "kr"):
            if args and args[0].lower() in ("spectral", "xyz"):
                warnings.warn(f"{where}: {parts[0]} {args[0]} is not supported; ignored", stacklevel=4)
                continue
            current[key] = _mtl_numbers(args, where, parts[0], 1, 3)
        elif key == "ns":
            current["ns"] = float(_mtl_numbers(args, where, parts[0], 1, 1)[0])
        elif key == "illum":
            current["_illum"] = int(_mtl_numbers(args, where, parts[0], 1, 1)[0])
        elif key == "refl":
            try:
                current["_refl"] = _mtl_numbers(args, where, parts[0], 1, 3)
            except ValueError:
                pass  # `refl -type sphere file`: a reflection map, not a reflectivity
        elif key == "map_kd":
            file_name = _map_file_name(args)
            if not file_name:
                raise ValueError(f"{where}: map_Kd has no file name")
            current["texture"] = _load_texture_file(mtl_path.parent, file_name, where, textures)
    out = {}
    for name, spec in specs.items():
        kr = spec.pop("kr", None)
        refl = spec.pop("_refl", None)
        illum = spec.pop("_illum", None)
        spec.pop("_where")
        if kr is None and refl is not None:
            kr = refl
        if kr is None and illum in _RAYTRACED_REFLECTION_ILLUM:
            kr = spec.get("ks", (0.0, 0.0, 0.0))
        if kr is not None:
            spec["kr"] = kr
        for key in ("ka", "kd", "ks", "ke", "kr"):
            if key in spec:
                spec[key] = np.broadcast_to(np.asarray(spec[key], np.float32), (3,))
        if spec.get("texture") is None:
            spec.pop("texture", None)
        out[name] = spec
    return out


def _mtl_numbers(args, where, key, lo, hi) -> list[float]:
    if not lo <= len(args) <= hi:
        raise ValueError(f"{where}: {key} needs {lo} to {hi} numbers, got {len(args)}: {' '.join(args)!r}")
    try:
        values = [float(a) for a in args]
    except ValueError:
        raise ValueError(f"{where}: {key} has a value that is not a number: {' '.join(args)!r}") from None
    if not np.isfinite(values).all():
        raise ValueError(f"{where}: {key} has a NaN or infinite value: {' '.join(args)!r}")
    return values


def _map_file_name(args: list[str]) -> str:
    """Skip `-option value...` pairs of a texture statement; the rest is the file name."""
    i = 0
    while i < len(args) and args[i].lower() in _MTL_MAP_OPTIONS:
        n = _MTL_MAP_OPTIONS[args[i].lower()]
        i += 1
        taken = 0
        while taken < n and i < len(args) - 1:
            if n == 3 and taken >= 1 and not _is_number(args[i]):
                break
            i += 1
            taken += 1
    return " ".join(args[i:]).replace("\\", "/")


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


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


# ----------------------------------------------------------------------------------------------
# PLY


def _load_ply(path: Path, data: bytes):
    import trimesh

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
    scene = make_scene(
        vertices,
        faces,
        face_material=face_material,
        materials=materials,
        lights=lights,
        normals=normals,
        uvs=uvs,
        textures=textures.images,
        texture_paths=textures.names,
        name=name or Path(path).stem,
        where=str(path),
    )
    if headlight:
        from ._poses import default_camera

        eye = default_camera(scene).position
        scene = eqx.tree_at(lambda s: s.lights, scene, make_lights([eye], [[1.0, 1.0, 1.0]]))
    return scene
