"""`cornell_box`: the Cornell box from the Cornell University Program of Computer Graphics'
published "Cornell Box Data" (graphics.cornell.edu/online/box/data.html)."""

from __future__ import annotations

import numpy as np

from . import _geometry as g
from ._scene import Scene, _build_scene, make_lights, make_materials

# Quads exactly as published, in millimetres (x, y, z); y is up, the open side faces -z.
# The real box is not a perfect cube, so neither are these.
FLOOR = [(552.8, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 559.2), (549.6, 0.0, 559.2)]
CEILING = [(556.0, 548.8, 0.0), (556.0, 548.8, 559.2), (0.0, 548.8, 559.2), (0.0, 548.8, 0.0)]
BACK_WALL = [(549.6, 0.0, 559.2), (0.0, 0.0, 559.2), (0.0, 548.8, 559.2), (556.0, 548.8, 559.2)]
RIGHT_WALL = [(0.0, 0.0, 559.2), (0.0, 0.0, 0.0), (0.0, 548.8, 0.0), (0.0, 548.8, 559.2)]  # green
LEFT_WALL = [(552.8, 0.0, 0.0), (549.6, 0.0, 559.2), (556.0, 548.8, 559.2), (556.0, 548.8, 0.0)]  # red
LIGHT = [(343.0, 548.8, 227.0), (343.0, 548.8, 332.0), (213.0, 548.8, 332.0), (213.0, 548.8, 227.0)]
SHORT_BLOCK = [
    [(130.0, 165.0, 65.0), (82.0, 165.0, 225.0), (240.0, 165.0, 272.0), (290.0, 165.0, 114.0)],
    [(290.0, 0.0, 114.0), (290.0, 165.0, 114.0), (240.0, 165.0, 272.0), (240.0, 0.0, 272.0)],
    [(130.0, 0.0, 65.0), (130.0, 165.0, 65.0), (290.0, 165.0, 114.0), (290.0, 0.0, 114.0)],
    [(82.0, 0.0, 225.0), (82.0, 165.0, 225.0), (130.0, 165.0, 65.0), (130.0, 0.0, 65.0)],
    [(240.0, 0.0, 272.0), (240.0, 165.0, 272.0), (82.0, 165.0, 225.0), (82.0, 0.0, 225.0)],
]
TALL_BLOCK = [
    [(423.0, 330.0, 247.0), (265.0, 330.0, 296.0), (314.0, 330.0, 456.0), (472.0, 330.0, 406.0)],
    [(423.0, 0.0, 247.0), (423.0, 330.0, 247.0), (472.0, 330.0, 406.0), (472.0, 0.0, 406.0)],
    [(472.0, 0.0, 406.0), (472.0, 330.0, 406.0), (314.0, 330.0, 456.0), (314.0, 0.0, 456.0)],
    [(314.0, 0.0, 456.0), (314.0, 330.0, 456.0), (265.0, 330.0, 296.0), (265.0, 0.0, 296.0)],
    [(265.0, 0.0, 296.0), (265.0, 330.0, 296.0), (423.0, 330.0, 247.0), (423.0, 0.0, 247.0)],
]
# Published camera: position, viewing direction, up, focal length 0.035 and film 0.025 x 0.025.
CAMERA_POSITION_MM = (278.0, 273.0, -800.0)
CAMERA_FOV_DEG = float(np.degrees(2 * np.arctan(0.025 / 2 / 0.035)))  # 39.3 degrees vertical

# The emitting patch is coplanar with the ceiling in the data; we lower it by 1 mm so the two
# never overlap, and put the point light that does the shading 10 mm below the ceiling at the
# patch's centre, so shadow rays to it never graze the patch.
LIGHT_PATCH_DROP_MM = 1.0
POINT_LIGHT_DROP_MM = 10.0

# RGB reflectances commonly used for the measured spectra (Morgan McGuire's Cornell box OBJ,
# public domain: white 0.725 0.71 0.68, red 0.63 0.065 0.05, green 0.14 0.45 0.091; its mirror
# variant's tall block Kd 0.01, Ks 0.95, Ns 1000). Ka = Kd as in those files.
WHITE, RED, GREEN = (0.725, 0.71, 0.68), (0.63, 0.065, 0.05), (0.14, 0.45, 0.091)


def _quad(mb: g.MeshBuilder, corners_mm, n: int, material: int, scale: float, flip: bool = False):
    """A bilinear patch through four corners (in order round the quad), n x n cells."""
    c = np.asarray(corners_mm, np.float64) * scale
    s = np.linspace(0.0, 1.0, n + 1)
    u, v = s[:, None, None], s[None, :, None]
    points = (1 - u) * (1 - v) * c[0] + u * (1 - v) * c[1] + u * v * c[2] + (1 - u) * v * c[3]
    du = (1 - v) * (c[1] - c[0]) + v * (c[2] - c[3])
    dv = (1 - u) * (c[3] - c[0]) + u * (c[2] - c[1])
    normals = np.cross(du, dv) * (-1.0 if flip else 1.0)
    mb.add_grid(points, normals, material, flip=flip)


def _face_inward(corners_mm, inside_mm) -> bool:
    """Whether a quad's winding (right-hand rule) must be flipped so its normal faces `inside`."""
    c = np.asarray(corners_mm, np.float64)
    normal = np.cross(c[1] - c[0], c[3] - c[0])
    return float(normal @ (np.asarray(inside_mm) - c.mean(axis=0))) < 0


def cornell_box(
    *,
    mirror_block: bool = False,
    subdivisions: int = 1,
    units: str = "m",
    light_color=(1.0, 1.0, 1.0),
) -> Scene:
    """The classic Cornell box, from its published dimensions.

    Geometry is the published data (walls, short and tall blocks, the light patch at
    y = 548.8 mm), in metres by default (`units="mm"` keeps millimetres). The box is open at
    z = 0 towards the published camera (see `default_camera`). The left wall (x ~ 556) is red,
    the right wall (x = 0) green, the rest white; the emitting patch (`ke` = 1) sits 1 mm
    under the ceiling so it never overlaps it. Lighting comes from one point light at the
    patch's centre (x = 278, z = 279.5 mm), 10 mm under the ceiling, colour `light_color`.

    Args:
        mirror_block: make the tall block a mirror (Kd 0.01, Ks 0.95, Ns 1000, Kr 0.95) to
            exercise reflections.
        subdivisions: split every quad into `subdivisions**2` cells (2 triangles each); the
            default gives 32 triangles, two for each of the 16 published quads (5 walls, the
            light patch, 5 faces of each block; the blocks have no bottom face, as published).
        units: "m" or "mm".
    """
    if units not in ("m", "mm"):
        raise ValueError(f"cornell_box: units must be 'm' or 'mm', got {units!r}")
    if int(subdivisions) < 1:
        raise ValueError(f"cornell_box: subdivisions must be >= 1, got {subdivisions}")
    n = int(subdivisions)
    scale = 1e-3 if units == "m" else 1.0
    mirror = {"kd": (0.01,) * 3, "ka": (0.01,) * 3, "ks": (0.95,) * 3, "ns": 1000.0, "kr": (0.95,) * 3}
    specs = [
        {"name": "white", "kd": WHITE, "ka": WHITE, "ns": 10.0},
        {"name": "red", "kd": RED, "ka": RED, "ns": 10.0},
        {"name": "green", "kd": GREEN, "ka": GREEN, "ns": 10.0},
        {"name": "short_block", "kd": WHITE, "ka": WHITE, "ns": 10.0},
        {"name": "tall_block", **(mirror if mirror_block else {"kd": WHITE, "ka": WHITE, "ns": 10.0})},
        {"name": "light", "kd": (0.78,) * 3, "ka": (0.78,) * 3, "ke": (1.0, 1.0, 1.0), "ns": 10.0},
    ]
    white, red, green, short_m, tall_m, light_m = range(6)
    centre = (278.0, 274.4, 279.6)  # inside the box: walls face it
    mb = g.MeshBuilder()
    for quad, material in (
        (FLOOR, white),
        (CEILING, white),
        (BACK_WALL, white),
        (RIGHT_WALL, green),
        (LEFT_WALL, red),
    ):
        _quad(mb, quad, n, material, scale, flip=_face_inward(quad, centre))
    patch = [(x, y - LIGHT_PATCH_DROP_MM, z) for x, y, z in LIGHT]
    _quad(mb, patch, n, light_m, scale, flip=_face_inward(patch, (278.0, 0.0, 279.5)))
    for block, material in ((SHORT_BLOCK, short_m), (TALL_BLOCK, tall_m)):
        block_centre = np.asarray(block[0]).mean(axis=0) * (1, 0.5, 1)  # mid-height of the block
        for quad in block:  # normals face out of the block
            _quad(mb, quad, n, material, scale, flip=not _face_inward(quad, block_centre))
    # quads meeting at an edge interpolate it from opposite ends; snap so the edges match exactly
    vertices, faces, normals, face_material = mb.build(weld=1e-9 * 556.0 * scale)
    light_centre = np.asarray(LIGHT, np.float64).mean(axis=0) - (0.0, POINT_LIGHT_DROP_MM, 0.0)
    return _build_scene(
        "cornell_box()",
        vertices,
        faces,
        face_material=face_material,
        materials=make_materials(specs),
        lights=make_lights([light_centre * scale], [light_color]),
        normals=normals,
        name="cornell_box",
    )
