"""The `Scene` pytree: triangles, per-face materials, lights.

Arrays are host NumPy float32/int32 when a scene is built or loaded; they become JAX arrays (or
tracers) when a scene is passed into a jitted function, which is what makes gradients w.r.t.
vertices or material colours possible. Static metadata (names, texture paths, the content hash)
lives in static fields so it never becomes a tracer.
"""

from __future__ import annotations

import dataclasses
import hashlib

import equinox as eqx
import numpy as np
from jaxtyping import Array, Float, Int

POINT_LIGHT = 0
DIRECTIONAL_LIGHT = 1
SPOT_LIGHT = 2
LIGHT_KINDS = {"point": POINT_LIGHT, "directional": DIRECTIONAL_LIGHT, "spot": SPOT_LIGHT}


class Materials(eqx.Module):
    """Per-material Blinn–Phong parameters, one row per material.

    `kr` is the mirror reflectivity (the thesis's Kr), `ns` the specular exponent, `ke` emission.
    `texture` indexes `Scene.textures` for a diffuse map, or is -1 for none; with a map the
    diffuse colour is `kd * texture(uv)` (as MTL multiplies map_Kd by Kd and glTF multiplies
    baseColorTexture by baseColorFactor).
    """

    ka: Float[np.ndarray | Array, "M 3"]
    kd: Float[np.ndarray | Array, "M 3"]
    ks: Float[np.ndarray | Array, "M 3"]
    ke: Float[np.ndarray | Array, "M 3"]
    kr: Float[np.ndarray | Array, "M 3"]
    ns: Float[np.ndarray | Array, " M"]
    texture: Int[np.ndarray | Array, " M"]
    names: tuple[str, ...] = eqx.field(static=True)

    def __len__(self) -> int:
        return len(self.names)


def make_materials(specs: list[dict], names: list[str] | None = None) -> Materials:
    """Build `Materials` from a list of dicts with optional keys ka, kd, ks, ke, kr, ns, texture.

    Missing keys take defaults: ka=0, kd=0.8 grey, ks=0, ke=0, kr=0, ns=32, texture=-1.
    A scalar kr is broadcast to RGB.
    """
    if not specs:
        raise ValueError("materials: need at least one material")
    defaults = {
        "ka": (0.0, 0.0, 0.0),
        "kd": (0.8, 0.8, 0.8),
        "ks": (0.0, 0.0, 0.0),
        "ke": (0.0, 0.0, 0.0),
        "kr": (0.0, 0.0, 0.0),
    }
    cols = {}
    for key, default in defaults.items():
        rows = []
        for i, spec in enumerate(specs):
            value = np.broadcast_to(np.asarray(spec.get(key, default), np.float32), (3,))
            if not np.all(np.isfinite(value)):
                raise ValueError(
                    f"material {i} ({(names or [''] * len(specs))[i]!r}): {key}={value} is not finite"
                )
            rows.append(value)
        cols[key] = np.stack(rows).astype(np.float32)
    ns = np.asarray([float(s.get("ns", 32.0)) for s in specs], np.float32)
    texture = np.asarray([int(s.get("texture", -1)) for s in specs], np.int32)
    if names is None:
        names = [s.get("name", f"material{i}") for i, s in enumerate(specs)]
    return Materials(**cols, ns=ns, texture=texture, names=tuple(names))


class Lights(eqx.Module):
    """Lights, one row each, of three kinds (`kind`):

    - POINT_LIGHT: `position` is a point; infinite range and no falloff, as the thesis's light
      ("emitted to all directions like the point light", infinite range like the directional
      light, §2.3.4 and Fig 56);
    - DIRECTIONAL_LIGHT: `position` is the direction *towards* the light;
    - SPOT_LIGHT: a point light focused in a cone (§2.3.4: "all the parameters of point light and
      additionally the angle of the cone"): `position` is its apex, `direction` the cone's axis
      (the way it shines), `cone_deg` its (inner, outer) half-angles in degrees. A point within
      the inner angle of the axis is lit fully, beyond the outer angle not at all (no shadow ray
      is traced to it), and in between by a factor falling linearly in the cosine of the angle
      from 1 to 0. The thesis names one angle: equal inner and outer angles (`make_lights`'
      default) give its hard-edged cone; the falloff between two is fovjax's addition. Infinite
      range and no distance falloff, as the point light.

    `direction` and `cone_deg` are ignored for the other kinds (`make_lights` fills them with
    zeros and 180°)."""

    position: Float[np.ndarray | Array, "L 3"]
    color: Float[np.ndarray | Array, "L 3"]
    kind: Int[np.ndarray | Array, " L"]
    direction: Float[np.ndarray | Array, "L 3"] | None = None
    cone_deg: Float[np.ndarray | Array, "L 2"] | None = None

    def __len__(self) -> int:
        return int(np.shape(self.kind)[0])

    def take(self, index) -> Lights:
        """The lights at `index` (an integer array), every field with them."""
        index = np.asarray(index, np.int64).reshape(-1)
        direction = np.zeros((len(self), 3), np.float32) if self.direction is None else self.direction
        cone = np.full((len(self), 2), 180.0, np.float32) if self.cone_deg is None else self.cone_deg
        return Lights(
            position=np.asarray(self.position)[index],
            color=np.asarray(self.color)[index],
            kind=np.asarray(self.kind)[index],
            direction=np.asarray(direction)[index],
            cone_deg=np.asarray(cone)[index],
        )


def make_lights(position, color, kind=None, *, direction=None, cone_deg=None) -> Lights:
    """`Lights` from per-light rows (see `Lights` for the kinds).

    Args:
        position: (L, 3) points (point and spot lights) or directions towards the light
            (directional lights).
        color: (L, 3) linear RGB.
        kind: (L,) `POINT_LIGHT`, `DIRECTIONAL_LIGHT` or `SPOT_LIGHT` (None: every light a
            point light).
        direction: (L, 3) each spot light's axis, the way it shines (nonzero for a spot; any
            value, e.g. zeros, for the other kinds); None where no light is a spot.
        cone_deg: each spot light's half-angles in degrees: (L,) outer angles (a hard-edged
            cone, the thesis's), or (L, 2) (inner, outer) with 0 <= inner <= outer <= 180 and
            outer > 0; None where no light is a spot.

    Raises:
        ValueError: shapes that differ, values that are not finite, an unknown kind, or a spot
            light without a nonzero direction or a valid cone, each naming the light.
    """
    position = np.atleast_2d(np.asarray(position, np.float32))
    color = np.atleast_2d(np.asarray(color, np.float32))
    if position.shape != color.shape or position.shape[-1] != 3:
        raise ValueError(f"lights: position {position.shape} and color {color.shape} must both be (L, 3)")
    n = position.shape[0]
    if kind is None:
        kind = np.full(n, POINT_LIGHT, np.int32)
    kind = np.asarray(kind, np.int32).reshape(-1)
    if kind.shape != (n,):
        raise ValueError(f"lights: kind must have one entry per light ({n}), got shape {kind.shape}")
    unknown = ~np.isin(kind, list(LIGHT_KINDS.values()))
    if unknown.any():
        i = int(np.flatnonzero(unknown)[0])
        raise ValueError(f"lights: light {i} has kind {int(kind[i])}, expected one of {LIGHT_KINDS}")
    if not np.all(np.isfinite(position)) or not np.all(np.isfinite(color)):
        raise ValueError("lights: position and color must be finite")
    spot = kind == SPOT_LIGHT
    if direction is None:
        if spot.any():
            i = int(np.flatnonzero(spot)[0])
            raise ValueError(f"lights: light {i} is a spot light and needs a direction (its axis), got None")
        direction = np.zeros((n, 3), np.float32)
    direction = np.atleast_2d(np.asarray(direction, np.float32))
    if direction.shape != (n, 3) or not np.isfinite(direction).all():
        raise ValueError(f"lights: direction must be ({n}, 3) finite numbers, got {direction.tolist()}")
    if cone_deg is None:
        if spot.any():
            i = int(np.flatnonzero(spot)[0])
            raise ValueError(
                f"lights: light {i} is a spot light and needs cone_deg (its cone's angle), got None"
            )
        cone_deg = np.full((n, 2), 180.0, np.float32)
    cone = np.asarray(cone_deg, np.float32)
    if cone.shape == (n,):
        cone = np.stack([cone, cone], axis=-1)
    if cone.shape != (n, 2) or not np.isfinite(cone).all():
        raise ValueError(
            f"lights: cone_deg must be {n} outer half-angles or ({n}, 2) (inner, outer) half-angles in "
            f"degrees, got {np.asarray(cone_deg).tolist()}"
        )
    for i in np.flatnonzero(spot):
        inner, outer = (float(a) for a in cone[i])
        if not (0.0 <= inner <= outer <= 180.0 and outer > 0.0):
            raise ValueError(
                f"lights: spot light {i} has cone_deg (inner {inner:g}, outer {outer:g}), expected "
                "0 <= inner <= outer <= 180 and outer > 0 (half-angles in degrees)"
            )
        if not np.any(direction[i] != 0):
            raise ValueError(
                f"lights: spot light {i} has direction {direction[i].tolist()}, expected a nonzero axis"
            )
    return Lights(position=position, color=color, kind=kind, direction=direction, cone_deg=cone)


class Scene(eqx.Module):
    """A triangle scene.

    - `vertices` (V, 3) float32, `faces` (F, 3) int32 indices into vertices;
    - `face_material` (F,) int32 index into `materials`;
    - `normals` (V, 3) float32 vertex normals for smooth shading, or None (flat shading);
    - `uvs` (V, 2) float32 texture coordinates, or None;
    - `textures` tuple of (H, W, 3) float32 linear-RGB images referenced by `materials.texture`;
      row 0 is v = 0 (the image's bottom, OBJ convention), texel [row, col] is centred on
      u = (col + 0.5) / W, v = (row + 0.5) / H;
    - `ambient` (3,) ambient light colour (multiplied by Ka);
    - `content_hash` sha256 of the geometry (vertices and faces), the BVH cache key.
    """

    vertices: Float[np.ndarray | Array, "V 3"]
    faces: Int[np.ndarray | Array, "F 3"]
    face_material: Int[np.ndarray | Array, " F"]
    materials: Materials
    lights: Lights
    normals: Float[np.ndarray | Array, "V 3"] | None = None
    uvs: Float[np.ndarray | Array, "V 2"] | None = None
    textures: tuple = ()
    ambient: Float[np.ndarray | Array, " 3"] = eqx.field(default_factory=lambda: np.full(3, 0.1, np.float32))
    name: str = eqx.field(static=True, default="scene")
    texture_paths: tuple[str, ...] = eqx.field(static=True, default=())
    content_hash: str = eqx.field(static=True, default="")

    @property
    def num_triangles(self) -> int:
        return int(np.shape(self.faces)[0])

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) array: min corner, max corner."""
        v = np.asarray(self.vertices)
        return np.stack([v.min(axis=0), v.max(axis=0)])

    def triangles(self) -> np.ndarray:
        """(F, 3, 3) float32 corner positions, host NumPy."""
        return np.asarray(self.vertices)[np.asarray(self.faces)]


def geometry_hash(vertices: np.ndarray, faces: np.ndarray) -> str:
    h = hashlib.sha256()
    v = np.ascontiguousarray(vertices, dtype=np.float32)
    f = np.ascontiguousarray(faces, dtype=np.int32)
    h.update(str(v.shape).encode())
    h.update(v.tobytes())
    h.update(str(f.shape).encode())
    h.update(f.tobytes())
    return h.hexdigest()


def validate_geometry(vertices, faces, where: str = "scene") -> tuple[np.ndarray, np.ndarray]:
    """Check shapes, finiteness and index range; return float32/int32 copies.

    `where` names the file (or builder) in error messages.
    """
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"{where}: vertices must have shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"{where}: faces must have shape (F, 3) triangles, got {f.shape}")
    if f.shape[0] == 0:
        raise ValueError(f"{where}: the mesh has no triangles")
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"{where}: {int(bad.sum())} vertices are NaN or infinite (first: vertex {i} = {v[i].tolist()})"
        )
    if not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"{where}: face indices must be integers, got dtype {f.dtype}")
    out = (f < 0) | (f >= v.shape[0])
    if out.any():
        i = int(np.flatnonzero(out.any(axis=1))[0])
        raise ValueError(
            f"{where}: face {i} has index {f[i].tolist()} out of range for {v.shape[0]} vertices"
        )
    return v.astype(np.float32), f.astype(np.int32)


def drop_degenerate(vertices: np.ndarray, faces: np.ndarray, rel_eps: float = 1e-12):
    """Mask of faces with non-zero area (relative to the scene's size squared)."""
    tri = vertices[faces].astype(np.float64)
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    extent = float(np.ptp(vertices, axis=0).max()) if len(vertices) else 1.0
    return area2 > rel_eps * max(extent, 1e-30) ** 2


@dataclasses.dataclass(frozen=True)
class Textures:
    """Texture images (each (H, W, 3) float, linear RGB) with the files they came from
    (`paths`: empty, or one name per image), as `make_scene` takes them.

    Raises:
        ValueError: `paths` neither empty nor one string per image.
    """

    images: tuple
    paths: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "images", tuple(self.images))
        object.__setattr__(self, "paths", tuple(self.paths))
        if self.paths and (
            len(self.paths) != len(self.images) or not all(isinstance(p, str) for p in self.paths)
        ):
            raise ValueError(
                f"Textures: paths must be empty or one string per image ({len(self.images)} images), "
                f"got {self.paths!r}"
            )


def make_scene(
    vertices,
    faces,
    *,
    face_material=None,
    materials: Materials | None = None,
    lights: Lights | None = None,
    normals=None,
    uvs=None,
    textures=(),
    ambient=(0.1, 0.1, 0.1),
    name: str = "scene",
) -> Scene:
    """Validate arrays and build a `Scene`. Zero-area triangles are dropped with a warning;
    errors and warnings name the scene by `name`.

    `textures`: the images (H, W, 3) `Materials.texture` indexes, a sequence, or `Textures`
    (the images with the files they came from, kept as `Scene.texture_paths`)."""
    return _build_scene(
        name,
        vertices,
        faces,
        face_material=face_material,
        materials=materials,
        lights=lights,
        normals=normals,
        uvs=uvs,
        textures=textures,
        ambient=ambient,
        name=name,
    )


def _build_scene(
    where,
    vertices,
    faces,
    *,
    face_material=None,
    materials=None,
    lights=None,
    normals=None,
    uvs=None,
    textures=(),
    ambient=(0.1, 0.1, 0.1),
    name="scene",
) -> Scene:
    """`make_scene`, with errors and warnings naming `where` (a loader's file, or the name)."""
    import warnings

    if not isinstance(textures, Textures):
        textures = Textures(tuple(textures))
    texture_paths, textures = textures.paths, textures.images
    v, f = validate_geometry(vertices, faces, where)
    nf = f.shape[0]
    fm = np.zeros(nf, np.int32) if face_material is None else np.asarray(face_material, np.int32)
    if fm.shape != (nf,):
        raise ValueError(f"{where}: face_material must have shape ({nf},), got {fm.shape}")
    materials = materials if materials is not None else make_materials([{}])
    if fm.size and (fm.min() < 0 or fm.max() >= len(materials)):
        raise ValueError(f"{where}: face_material index out of range for {len(materials)} materials")
    keep = drop_degenerate(v, f)
    if not keep.all():
        warnings.warn(f"{where}: dropped {int((~keep).sum())} zero-area triangles of {nf}", stacklevel=2)
        f, fm = f[keep], fm[keep]
        if f.shape[0] == 0:
            raise ValueError(f"{where}: every triangle has zero area")
    if normals is not None:
        normals = np.asarray(normals, np.float32)
        if normals.shape != v.shape:
            raise ValueError(f"{where}: normals must have shape {v.shape}, got {normals.shape}")
        if not np.isfinite(normals).all():
            raise ValueError(f"{where}: vertex normals contain NaN or inf")
    if uvs is not None:
        uvs = np.asarray(uvs, np.float32)
        if uvs.shape != (v.shape[0], 2):
            raise ValueError(f"{where}: uvs must have shape ({v.shape[0]}, 2), got {uvs.shape}")
    lights = lights if lights is not None else make_lights(np.zeros((0, 3)), np.zeros((0, 3)))
    return Scene(
        vertices=v,
        faces=f,
        face_material=fm,
        materials=materials,
        lights=lights,
        normals=normals,
        uvs=uvs,
        textures=tuple(np.asarray(t, np.float32) for t in textures),
        ambient=np.asarray(ambient, np.float32),
        name=name,
        texture_paths=tuple(texture_paths),
        content_hash=geometry_hash(v, f),
    )
