"""The layout the native handlers and the Python side share: the mirror of `csrc/layout.h`.

The loader compares the library's export (`fovjax_native_layout`) with `LAYOUT` before it
registers a handler; `tests/test_native_layout.py` compares `LAYOUT` with the constants of the
packages that own each code (regions and sample classes in `fovjax.foveate`, light kinds in
`fovjax.scene`, specular terms in `fovjax.render`) and with the operands the wrappers pass."""

from __future__ import annotations

# Materials: rows of ka, kd, ks, ke, kr (3 each) and ns (1).
MATERIAL_COLUMNS = (("ka", 3), ("kd", 3), ("ks", 3), ("ke", 3), ("kr", 3), ("ns", 1))
# Lights: rows of position (or direction towards the light), colour, a spot light's unit axis
# and the cosines of its (inner, outer) half-angles.
LIGHT_COLUMNS = (("position", 3), ("color", 3), ("direction", 3), ("cone", 2))
# Cameras: rows of position, rotation (3×3, row-major), tan(vfov / 2), aspect, offset.
CAMERA_COLUMNS = (("position", 3), ("rotation", 9), ("tan_half_vfov", 1), ("aspect", 1), ("offset", 2))
LIGHT_KINDS = {"point": 0, "directional": 1, "spot": 2}
SPECULARS = {"blinn-phong": 0, "phong": 1}
REGIONS = {"fovea": 0, "periphery": 1, "outside": 2}
CLASSES = {"mandatory": 0, "optional": 1, "skipped": 2}
# Sampling rules (`Foveation.rule`), and "pixel-mask": the foveation methods' pixel masks (every
# sub-sample of the pixels whose P is 1; `fovjax.foveate._methods._sparse.pixel_selection`).
RULES = {"either": 0, "strict": 1, "thesis-measured": 2, "pixel-mask": 3}
# Shadow modes of a shading class (`fovjax.render.internal.SHADOWS_ALL`, ...).
SHADOWS = {"all": 0, "brightest": 1, "none": 2}
# The shading adjoint's fields (`fovjax.render.internal.SHADING_FIELDS`): bit i of its `moving`
# attribute asks for field i's gradient.
ADJOINT_FIELDS = {"ka": 0, "kd": 1, "ks": 2, "ke": 3, "kr": 4, "ns": 5, "light_color": 6, "ambient": 7}
# A stored path's face where no ray was traced at that level (`render/_replay.py`); -1 is a miss.
PATH_NOT_TRACED = -2
# The Whitted handlers' scene operands, in the order the handlers bind them.
SCENE_OPERANDS = (
    "bvh_host_id",
    "bvh_vertices",
    "bvh_faces",
    "bvh_first_face",
    "vertices",
    "faces",
    "face_material",
    "normals",
    "uvs",
    "materials",
    "texture",
    "texels",
    "texture_shape",
    "lights",
    "light_kind",
    "ambient",
    "environment",
    "offset",
)


def stride(columns) -> int:
    return sum(width for _, width in columns)


MATERIAL_STRIDE = stride(MATERIAL_COLUMNS)
LIGHT_STRIDE = stride(LIGHT_COLUMNS)
CAMERA_STRIDE = stride(CAMERA_COLUMNS)


def expected_layout() -> dict[str, str]:
    """What `fovjax_native_layout` must export, as the Python side reads it."""
    layout = {
        "material_stride": str(MATERIAL_STRIDE),
        "light_stride": str(LIGHT_STRIDE),
        "camera_stride": str(CAMERA_STRIDE),
        "scene_operands": ",".join(SCENE_OPERANDS),
        "path_not_traced": str(PATH_NOT_TRACED),
    }
    groups = (
        ("light", LIGHT_KINDS),
        ("specular", SPECULARS),
        ("region", REGIONS),
        ("class", CLASSES),
        ("rule", RULES),
        ("shadows", SHADOWS),
        ("adjoint", ADJOINT_FIELDS),
    )
    for prefix, codes in groups:
        layout.update({f"{prefix}_{name.replace('-', '_')}": str(code) for name, code in codes.items()})
    return layout


def parse_layout(text: str) -> dict[str, str]:
    """`name=value;name=value` as a dict."""
    return dict(item.split("=", 1) for item in text.split(";") if item)


def layout_differences(exported: dict[str, str]) -> list[str]:
    """Each name whose value differs between the library's export and the Python side, as
    "name: library X, Python Y" (empty: they agree)."""
    expected = expected_layout()
    return [
        f"{name}: library {exported.get(name, 'missing')!r}, Python {expected.get(name, 'missing')!r}"
        for name in sorted(set(expected) | set(exported))
        if exported.get(name) != expected.get(name)
    ]
