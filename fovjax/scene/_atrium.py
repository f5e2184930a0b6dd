"""`atrium`: a procedural indoor courtyard laid out like Sponza, at a chosen triangle count."""

from __future__ import annotations

import functools

import numpy as np

from . import _geometry as g
from ._scene import Scene, _build_scene, make_lights, make_materials

# Layout, in metres, y up, the court's long axis along x (Sponza-like extent: 30 x 13 x 15 m).
HALF_LENGTH = 15.0  # outer walls at x = +-15
HALF_WIDTH = 6.5  # outer walls at z = +-6.5
WALL_HEIGHT = 15.0
WALL_THICKNESS = 0.5
ARCADE_Z = 3.5  # centre line of the two arcades, z = +-3.5
ARCADE_DEPTH = 0.7  # thickness of the arcade walls
INNER_X = HALF_LENGTH - WALL_THICKNESS  # inner face of the end walls
INNER_Z = HALF_WIDTH - WALL_THICKNESS  # inner face of the long walls

# (name, columns' x, pier half-width, column radius, base top, capital bottom, springing, top)
STOREYS = (
    ("ground", np.arange(-12.0, 12.0 + 1e-9, 3.0), 0.40, 0.28, 0.0, 0.3, 3.1, 3.4, 5.2),
    ("upper", np.arange(-12.0, 12.0 + 1e-9, 2.0), 0.25, 0.17, 5.6, 5.8, 8.0, 8.2, 9.6),
)
SLAB_THICKNESS = 0.4  # gallery floor over the ground storey, gallery roof over the upper one

LIGHT_POSITION = (0.0, 12.0, 0.0)  # high in the court, above the galleries' roofs
LIGHT_COLOR = (0.7, 0.7, 0.7)  # the thesis's single Sponza light had colour 0.7

MATERIALS = [
    {"name": "stone_wall", "kd": (0.62, 0.56, 0.47), "ka": (0.62, 0.56, 0.47), "ns": 16.0},
    {"name": "stone_arcade", "kd": (0.70, 0.64, 0.54), "ka": (0.70, 0.64, 0.54), "ns": 16.0},
    {"name": "floor", "kd": (0.42, 0.38, 0.33), "ka": (0.42, 0.38, 0.33), "ks": (0.05,) * 3, "ns": 32.0},
    {
        "name": "floor_polished",
        "kd": (0.20, 0.19, 0.18),
        "ka": (0.20, 0.19, 0.18),
        "ks": (0.6,) * 3,
        "ns": 300.0,
        "kr": (0.45,) * 3,
    },
    {
        "name": "column_polished",
        "kd": (0.55, 0.50, 0.44),
        "ka": (0.55, 0.50, 0.44),
        "ks": (0.5,) * 3,
        "ns": 120.0,
        "kr": (0.25,) * 3,
    },
    {"name": "cloth_red", "kd": (0.55, 0.06, 0.05), "ka": (0.55, 0.06, 0.05), "ns": 8.0},
    {"name": "cloth_green", "kd": (0.08, 0.40, 0.10), "ka": (0.08, 0.40, 0.10), "ns": 8.0},
    {"name": "cloth_blue", "kd": (0.06, 0.12, 0.50), "ka": (0.06, 0.12, 0.50), "ns": 8.0},
    {"name": "plaster", "kd": (0.75, 0.72, 0.66), "ka": (0.75, 0.72, 0.66), "ns": 16.0},
]
_M = {spec["name"]: i for i, spec in enumerate(MATERIALS)}
_CLOTHS = ("cloth_red", "cloth_green", "cloth_blue")


def _plan(edge: float, floor_cells: tuple[int, int] | None = None) -> list[tuple]:
    """The primitives of the atrium, tessellated for a target edge length (metres): a list of
    (add function, args, kwargs, triangle count). Flat walls get coarser cells than curved
    parts. `floor_cells` overrides the floor grid (to fine-tune the total)."""
    flat, curved = 2.0 * edge, 0.5 * edge
    plan = []

    def emit(count, add, *args, **kwargs):
        plan.append((add, args, kwargs, count))

    def box(lo, hi, material, cell=flat, skip=()):
        n = tuple(g.divisions(hi[a] - lo[a], cell) for a in range(3))
        count = g.box_count(*n) - sum(
            2 * n[(a + 1) % 3] * n[(a + 2) % 3] for a in range(3) for s in "-+" if s + "xyz"[a] in skip
        )
        emit(count, g.add_box, lo, hi, n, _M[material], skip=skip)

    # floor: a polished strip down the middle of the court, plain stone elsewhere
    nx, nz = floor_cells or (g.divisions(2 * HALF_LENGTH, edge), g.divisions(2 * HALF_WIDTH, edge))

    def floor_material(x, z):
        strip = (np.abs(z) < 1.3) & (np.abs(x) < 11.5)
        return np.where(strip, _M["floor_polished"], _M["floor"])

    x0, x1, z0, z1 = -HALF_LENGTH, HALF_LENGTH, -HALF_WIDTH, HALF_WIDTH
    emit(g.floor_count(nx, nz), g.add_floor, x0, x1, z0, z1, 0.0, nx, nz, floor_material)

    # outer walls: two long ones, two end ones between them
    for s in (-1.0, 1.0):
        z_in, z_out = s * INNER_Z, s * HALF_WIDTH
        box((-HALF_LENGTH, 0.0, min(z_in, z_out)), (HALF_LENGTH, WALL_HEIGHT, max(z_in, z_out)), "stone_wall")
        x_in, x_out = s * INNER_X, s * HALF_LENGTH
        box((min(x_in, x_out), 0.0, -INNER_Z), (max(x_in, x_out), WALL_HEIGHT, INNER_Z), "stone_wall")

    for s in (-1.0, 1.0):
        z_court, z_back = s * (ARCADE_Z - ARCADE_DEPTH / 2), s * (ARCADE_Z + ARCADE_DEPTH / 2)
        z0, z1 = min(z_court, z_back), max(z_court, z_back)
        for i_storey, storey in enumerate(STOREYS):
            _, xs, pier, radius, y_base, y_shaft, y_capital, y_spring, y_top = storey
            shaft_material = "column_polished" if i_storey == 0 else "stone_arcade"
            for x in xs:
                box((x - pier, y_base, z0), (x + pier, y_shaft, z1), "stone_arcade", cell=edge)
                box((x - pier, y_capital, z0), (x + pier, y_spring, z1), "stone_arcade", cell=edge)
                n_around = g.divisions(2 * np.pi * radius, curved, minimum=8)
                n_height = g.divisions(y_capital - y_shaft, edge)
                count = g.cylinder_count(n_around, n_height)
                centre = (x, s * ARCADE_Z)
                emit(count, g.add_cylinder, centre, y_shaft, y_capital, radius, n_around, n_height,
                     _M[shaft_material])  # fmt: skip
            half_span = (xs[1] - xs[0]) / 2
            arch_radius = half_span - pier
            n_arc = g.divisions(np.pi * arch_radius, curved, minimum=6)
            n_radial = g.divisions(y_top - y_spring - arch_radius, edge)
            n_depth = g.divisions(ARCADE_DEPTH, edge)
            for x_mid in (xs[:-1] + xs[1:]) / 2:
                count = g.arch_count(n_arc, n_radial, n_depth, half_span, y_top - y_spring)
                bay = g.ArchBay(
                    x_mid, half_span, arch_radius, y_spring, y_top, z0, z1, n_arc, n_radial, n_depth
                )
                emit(count, g.add_arch_bay, bay, _M["stone_arcade"])
            # solid piers from the last column to the end walls
            box((xs[-1], y_base, z0), (INNER_X, y_top, z1), "stone_arcade")
            box((-INNER_X, y_base, z0), (xs[0], y_top, z1), "stone_arcade")
            # gallery floor / roof over this storey, from the arcade back to the outer wall
            z_wall = s * INNER_Z
            y_slab = y_top + SLAB_THICKNESS
            box((-INNER_X, y_top, min(z_court, z_wall)), (INNER_X, y_slab, max(z_court, z_wall)), "plaster")
            if i_storey == 1:
                # balustrades between the upper columns, on the court side
                zb = (min(z_court, z_court + s * 0.25), max(z_court, z_court + s * 0.25))
                for xa, xb in zip(xs[:-1], xs[1:], strict=True):
                    box(
                        (xa + pier, y_base, zb[0]),
                        (xb - pier, y_base + 0.9, zb[1]),
                        "stone_arcade",
                        cell=edge,
                    )
                # parapet along the roof's court edge
                yp = y_top + SLAB_THICKNESS
                box((-INNER_X, yp, zb[0]), (INNER_X, yp + 0.9, zb[1]), "stone_wall")

        # hanging cloths in front of every other upper bay, and in the end bays below
        xs = STOREYS[1][1]
        z_cloth = s * (ARCADE_Z - ARCADE_DEPTH / 2 - 0.15)
        hangings = [(xa + 0.3, xb - 0.3, 9.45, 6.4) for xa, xb in zip(xs[:-1:2], xs[1::2], strict=True)]
        xs0 = STOREYS[0][1]
        hangings += [(xs0[0] + 0.5, xs0[1] - 0.5, 5.1, 1.6), (xs0[-2] + 0.5, xs0[-1] - 0.5, 5.1, 1.6)]
        for k, (xa, xb, y_hi, y_lo) in enumerate(hangings):
            material = _CLOTHS[(k + (0 if s < 0 else 1)) % 3]
            nu = g.divisions(xb - xa, curved, minimum=12)
            nv = g.divisions(y_hi - y_lo, 2 * curved, minimum=6)
            folds = max(2, round((xb - xa) / 0.5))
            cloth = g.Cloth(xa, xb, y_hi, y_lo, z_cloth, folds, 0.07, 0.25, nu, nv, facing=-s)
            emit(g.sheet_count(nu, nv), g.add_cloth, cloth, _M[material])
    return plan


def _count(edge: float) -> int:
    return sum(p[3] for p in _plan(edge))


def _edge_bracket(triangles: int) -> tuple[float, float]:
    """Edge lengths just below and just above the one giving `triangles` (bisection on
    log(edge); the count only falls as the edge grows)."""
    lo, hi = np.log(0.005), np.log(20.0)
    for _ in range(24):
        mid = 0.5 * (lo + hi)
        if _count(np.exp(mid)) > triangles:
            lo = mid
        else:
            hi = mid
    return float(np.exp(lo)), float(np.exp(hi))


def _tessellation(triangles: int) -> tuple[float, tuple[int, int] | None]:
    """Edge length and floor grid for a triangle budget. The common edge length gets close;
    the floor grid (about a sixth of the triangles) then takes up the remainder, as the other
    parts change in steps of many triangles at once (e.g. all 26 upper columns together)."""
    best: tuple[float, float, tuple[int, int] | None] | None = None
    for edge in _edge_bracket(triangles):
        plan = _plan(edge)
        floor = sum(p[3] for p in plan if p[0] is g.add_floor)
        total = sum(p[3] for p in plan)
        candidates: list[tuple[float, float, tuple[int, int] | None]] = [(abs(total - triangles), edge, None)]
        wanted = triangles - (total - floor)
        if floor / 4 <= wanted <= floor * 4:
            nz = max(1, round(np.sqrt(wanted / 2 * HALF_WIDTH / HALF_LENGTH)))
            nx = max(1, round(wanted / (2 * nz)))
            candidates.append((abs(total - floor + g.floor_count(nx, nz) - triangles), edge, (nx, nz)))
        best = min([best, *candidates] if best else candidates, key=lambda c: c[0])
    if best is None:
        raise ValueError(f"atrium: no tessellation for {triangles} triangles")
    return best[1], best[2]


@functools.cache
def min_triangles() -> int:
    """The triangle count of the coarsest atrium (every element at its minimum tessellation)."""
    return _count(1e6)


def atrium(triangles: int = 262_000, *, light_position=LIGHT_POSITION, light_color=LIGHT_COLOR) -> Scene:
    """An indoor courtyard like Sponza in layout and scale, with about `triangles` triangles.

    Units are metres, y is up, the court's long axis is x. Outer walls enclose 30 m x 13 m and
    rise 15 m; round the court run two storeys of arched colonnades (9 columns and 8 arches a
    side below, 13 columns and 12 arches above, with balustrades), each storey roofed by a
    gallery slab that reaches back to the outer wall; the court itself is open to the sky.
    Cloths in red, green and blue hang in front of every other upper arch and in the end arches
    below. Reflective surfaces: a polished strip down the middle of the floor (Kr 0.45) and the
    polished ground-floor columns (Kr 0.25). One point light, colour 0.7 as in the thesis's
    Sponza, high in the court at (0, 12, 0).

    Columns (cylinders with caps), capitals, bases, arch bays (a rectangle minus a half-disc,
    extruded), walls, slabs, piers, balustrades and parapets are closed solids; the floor is a
    plane and the cloths are open sheets. Every element is tessellated from one target edge
    length, found by bisection, and the floor grid then takes up the remainder, so the total is
    within a few hundred triangles of `triangles` (0.1% at the default size);
    `atrium(triangles=20_000)` is a small version for tests.
    Vertex normals are analytic (smooth on columns, arches' undersides and cloths).
    """
    triangles = int(triangles)
    if triangles < min_triangles():
        raise ValueError(
            f"atrium: triangles={triangles} is below the coarsest atrium ({min_triangles()} triangles)"
        )
    edge, floor_cells = _tessellation(triangles)
    mb = g.MeshBuilder()
    for add, args, kwargs, _ in _plan(edge, floor_cells):
        add(mb, *args, **kwargs)
    vertices, faces, normals, face_material = mb.build()
    return _build_scene(
        f"atrium(triangles={triangles})",
        vertices,
        faces,
        face_material=face_material,
        materials=make_materials([dict(m) for m in MATERIALS]),
        lights=make_lights([light_position], [light_color]),
        normals=normals,
        name="atrium",
    )
