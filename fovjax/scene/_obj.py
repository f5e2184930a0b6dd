"""OBJ and MTL: a fast pre-scan of the OBJ text that reports bad numbers and indices with their
line, trimesh for the geometry, and our own MTL parser (Ka, Kd, Ks, Ke, Ns, reflectivity,
`map_Kd` with options)."""

from __future__ import annotations

import io
import re
import warnings
from pathlib import Path
from typing import Any, cast

import numpy as np

from ._parts import (
    _load_texture_file,
    _optional,
    _Part,
    _resolve_case,
    _TextureTable,
)

# MTL illumination models with ray-traced reflection ("Reflection on and Ray trace on", MTL spec:
# 3 = reflection, 4 = glass + reflection, 5 = Fresnel reflection, 6/7 = refraction + reflection).
_RAYTRACED_REFLECTION_ILLUM = {3, 4, 5, 6, 7}

# Options of MTL texture statements and how many arguments each takes (-o/-s/-t take 1 to 3).
_MTL_MAP_OPTIONS = {
    "-blendu": 1, "-blendv": 1, "-cc": 1, "-clamp": 1, "-texres": 1, "-bm": 1, "-boost": 1,
    "-imfchan": 1, "-type": 1, "-mm": 2, "-o": 3, "-s": 3, "-t": 3,
}  # fmt: skip


# ----------------------------------------------------------------------------------------------
# OBJ


# Patterns start with a literal newline (the text is given a leading one), which the regex
# engine finds fast; `^` with re.M would be tried at every character of a large file.
_RE_USEMTL = re.compile(r"\nusemtl[ \t]+([^\n]*)")
_RE_MTLLIB = re.compile(r"\nmtllib[ \t]+([^\n]*)")
_RE_NEEDS_CLEANUP = re.compile(r"\n[ \t]+(?:v|vt|vn|f|usemtl|mtllib)\s|\n(?:v|vt|vn|f|usemtl|mtllib)\t")
# A `v` or `vn` line with fewer than 3 numbers, or a `vt` line with none (trimesh would shape
# the whole array by them, or shift every later vertex, without a word).
_RE_SHORT_VERTEX = re.compile(r"\n(?:(?:v|vn) +[^ \n#]+(?: +[^ \n#]+)?|vt) *(?:#[^\n]*)?(?=\n|$)")
_SYNTHETIC_MTL = "__fovjax_materials__.mtl"
_WIDTH = {"v": 3, "vt": 1, "vn": 3}


def _load_obj(path: Path, data: bytes, textures: _TextureTable):
    import trimesh.exchange.obj

    text = data.decode("utf-8", errors="replace").replace("\r\n", "\n").replace("\r", "\n")
    text = "\n" + text  # so that every line, the first too, starts after a newline
    if _RE_NEEDS_CLEANUP.search(text):
        # trimesh expects keywords at the start of a line followed by one space
        text = re.sub(r"^[ \t]*(v|vt|vn|f|usemtl|mtllib)[ \t]+", r"\1 ", text, flags=re.M)
    text, _ = _prescan_obj(text, path)
    if _RE_SHORT_VERTEX.search(text):
        _walk_lines(text, path)  # raises, naming the first short line

    material_names = []
    for raw in _RE_USEMTL.findall(text):
        material_name = raw.split("#", 1)[0].strip()
        if material_name and material_name not in material_names:
            material_names.append(material_name)
    mtl_specs = {}
    not_found = []  # (line of the mtllib, the library's path)
    for match in _RE_MTLLIB.finditer(text):
        line = text.count("\n", 0, match.start() + 1)  # the text starts with a newline we added
        for mtl_path in _mtllib_paths(path.parent, match.group(1).split("#", 1)[0].strip()):
            if not mtl_path.is_file():
                not_found.append((line, mtl_path))
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
        # Duck-typed: trimesh only calls the resolver's get/[] (see `_OneFileResolver`).
        resolver = cast(Any, _OneFileResolver(_SYNTHETIC_MTL, synthetic))
        loaded = trimesh.exchange.obj.load_obj(io.StringIO(text), resolver=resolver, group_material=True)
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
    for line, mtl_path in not_found:
        used = f"; materials {missing} render in the default grey" if missing else ""
        warnings.warn(
            f"{path}:{line}: material library {mtl_path.name!r} not found (looked for {mtl_path}){used}",
            stacklevel=3,
        )
    if missing and not not_found:
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


def _mtllib_paths(folder: Path, value: str) -> list[Path]:
    """`mtllib` takes one or more file names; a single name may contain spaces."""
    value = value.replace("\\", "/")
    whole = folder / value
    if whole.is_file() or " " not in value:
        return [_resolve_case(whole)]
    return [_resolve_case(folder / v) for v in value.split()]


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
        count = f"{_WIDTH[key]} numbers" if _WIDTH[key] > 1 else "1 number"
        raise ValueError(f"{where}: {key!r} line needs at least {count}: {line.strip()!r}")
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
    current: dict[str, object] | None = None
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
