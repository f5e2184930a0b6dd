"""`spheres`: a minimal scene for fast tests."""

from __future__ import annotations

import numpy as np

from . import _geometry as g
from ._scene import Scene, _build_scene, make_lights, make_materials

# (centre, radius, material name); they rest on the ground plane y = 0
SPHERES = (
    ((-1.6, 0.7, 0.0), 0.7, "red"),
    ((0.0, 1.0, -0.6), 1.0, "mirror"),
    ((1.5, 0.6, 0.4), 0.6, "blue"),
    ((0.2, 0.35, 1.4), 0.35, "green"),
)
MATERIALS = [
    {"name": "ground", "kd": (0.6, 0.6, 0.6), "ka": (0.6, 0.6, 0.6), "ns": 16.0},
    {"name": "red", "kd": (0.7, 0.1, 0.08), "ka": (0.7, 0.1, 0.08), "ks": (0.3,) * 3, "ns": 64.0},
    {
        "name": "mirror",
        "kd": (0.05,) * 3,
        "ka": (0.05,) * 3,
        "ks": (0.9,) * 3,
        "ns": 500.0,
        "kr": (0.85,) * 3,
    },
    {"name": "blue", "kd": (0.1, 0.15, 0.7), "ka": (0.1, 0.15, 0.7), "ks": (0.5,) * 3, "ns": 128.0},
    {"name": "green", "kd": (0.1, 0.6, 0.15), "ka": (0.1, 0.6, 0.15), "ns": 16.0},
]
LIGHT_POSITION = (3.0, 6.0, 4.0)
GROUND_HALF_SIZE = 6.0


def spheres(*, subdivisions: int = 3, ground_cells: int = 8, light_color=(1.0, 1.0, 1.0)) -> Scene:
    """Four icospheres (red, mirror with Kr 0.85, glossy blue, green) resting on a grey ground
    square (12 m a side, `ground_cells`^2 cells), lit by one point light at (3, 6, 4).

    Each sphere has `20 * 4**subdivisions` triangles: 5,248 in all by default, 448 with
    `subdivisions=1`. Units are metres, y up. Spheres are closed; the ground is a plane.
    """
    if not 0 <= int(subdivisions) <= 7:
        raise ValueError(f"spheres: subdivisions must be in 0..7, got {subdivisions}")
    if int(ground_cells) < 1:
        raise ValueError(f"spheres: ground_cells must be >= 1, got {ground_cells}")
    index = {m["name"]: i for i, m in enumerate(MATERIALS)}
    mb = g.MeshBuilder()
    h, n = GROUND_HALF_SIZE, int(ground_cells)
    g.add_floor(mb, -h, h, -h, h, 0.0, n, n, lambda x, z: np.zeros_like(x, dtype=np.int64))
    for centre, radius, material in SPHERES:
        g.add_icosphere(mb, centre, radius, int(subdivisions), index[material])
    vertices, faces, normals, face_material = mb.build()
    return _build_scene(
        "spheres()",
        vertices,
        faces,
        face_material=face_material,
        materials=make_materials([dict(m) for m in MATERIALS]),
        lights=make_lights([LIGHT_POSITION], [light_color]),
        normals=normals,
        name="spheres",
    )
