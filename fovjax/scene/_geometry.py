"""Vectorised NumPy tessellation of the primitives the built-in scenes are made of.

Every surface is a structured grid of points `P[i, j]` (with normals `N[i, j]`) cut into two
triangles per cell, wound so that the geometric normal is `dP/di x dP/dj`. Solids are closed:
the grids of neighbouring faces are built from the same coordinate arrays, so shared edges have
bit-identical vertices (which is what a watertight ray-triangle test needs; vertices are not
shared by index, so each face keeps its own shading normals). Each primitive has a matching
`*_count` function so scenes can plan their tessellation for a triangle budget without building.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np


class MeshBuilder:
    """Accumulates (vertices, faces, normals, material) pieces and concatenates them once."""

    def __init__(self):
        self._vertices, self._faces, self._normals, self._materials = [], [], [], []
        self._count = 0

    def add(self, vertices, faces, normals, material: int):
        vertices = np.asarray(vertices, np.float64).reshape(-1, 3)
        normals = np.asarray(normals, np.float64).reshape(-1, 3)
        self._vertices.append(vertices)
        self._normals.append(normals)
        self._faces.append(np.asarray(faces, np.int64) + self._count)
        self._materials.append(np.full(len(faces), material, np.int32))
        self._count += len(vertices)

    def add_grid(self, points, normals, material: int, flip: bool = False):
        """A structured (nu+1, nv+1, 3) grid of points; `flip` reverses the winding."""
        nu, nv = points.shape[0] - 1, points.shape[1] - 1
        faces = grid_faces(nu, nv)
        if flip:
            faces = faces[:, ::-1]
        self.add(points.reshape(-1, 3), faces, normals.reshape(-1, 3), material)

    def build(self, weld: float = 0.0):
        """Concatenate. With `weld > 0`, vertices closer than about `weld` get bit-identical
        coordinates (not merged: their normals stay apart), closing cracks of an ulp or two."""
        vertices = np.concatenate(self._vertices)
        if weld > 0:
            keys = np.round(vertices / weld).astype(np.int64)
            _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
            vertices = vertices[first][inverse.reshape(-1)]
        faces = np.concatenate(self._faces)
        normals = np.concatenate(self._normals)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        return vertices, faces, normals, np.concatenate(self._materials)


@functools.lru_cache(maxsize=256)
def grid_faces(nu: int, nv: int) -> np.ndarray:
    """Triangles of an (nu+1) x (nv+1) vertex grid, vertex (i, j) at index i*(nv+1)+j
    (cached: read-only)."""
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a = i * (nv + 1) + j
    b = a + (nv + 1)
    lower = np.stack([a, b, b + 1], axis=-1).reshape(-1, 3)
    upper = np.stack([a, b + 1, a + 1], axis=-1).reshape(-1, 3)
    faces = np.concatenate([lower, upper])
    faces.setflags(write=False)
    return faces


def divisions(length: float, edge: float, minimum: int = 1) -> int:
    """Number of segments so that each is at most about `edge` long."""
    return max(minimum, int(np.ceil(length / edge - 1e-9)))


# --- axis-aligned box ------------------------------------------------------------------------


def box_count(nx: int, ny: int, nz: int) -> int:
    return 4 * (nx * ny + ny * nz + nx * nz)


def add_box(mb: MeshBuilder, lo, hi, n, material: int, skip=()):
    """A closed box [lo, hi] with n = (nx, ny, nz) divisions per axis; `skip` names faces to
    leave out (e.g. "-y" for a face that rests on another solid's face)."""
    xs, ys, zs = (np.linspace(lo[a], hi[a], n[a] + 1) for a in range(3))
    coords = (xs, ys, zs)
    for axis in range(3):
        u_axis, v_axis = (axis + 1) % 3, (axis + 2) % 3  # right-handed: u x v = +axis
        for side, value in ((-1, lo[axis]), (1, hi[axis])):
            if ("-" if side < 0 else "+") + "xyz"[axis] in skip:
                continue
            u, v = np.meshgrid(coords[u_axis], coords[v_axis], indexing="ij")
            points = np.empty(u.shape + (3,))
            points[..., axis] = value
            points[..., u_axis] = u
            points[..., v_axis] = v
            normal = np.zeros(3)
            normal[axis] = side
            mb.add_grid(points, np.broadcast_to(normal, points.shape), material, flip=bool(side < 0))


# --- vertical cylinder -------------------------------------------------------------------------


def cylinder_count(n_around: int, n_height: int, caps: bool = True) -> int:
    return 2 * n_around * n_height + (2 * n_around if caps else 0)


def add_cylinder(mb: MeshBuilder, centre_xz, y0, y1, radius, n_around, n_height, material, caps=True):
    """A closed vertical cylinder: side grid plus two fan caps sharing the rim vertices."""
    theta = np.linspace(0.0, 2 * np.pi, n_around + 1)
    cos, sin = np.cos(theta), np.sin(theta)
    cos[-1], sin[-1] = cos[0], sin[0]  # close the seam exactly
    rim_x, rim_z = centre_xz[0] + radius * cos, centre_xz[1] + radius * sin
    ys = np.linspace(y0, y1, n_height + 1)
    points = np.stack(np.broadcast_arrays(rim_x[None, :], ys[:, None], rim_z[None, :]), axis=-1)
    normals = np.stack(np.broadcast_arrays(cos[None, :], 0.0 * ys[:, None], sin[None, :]), axis=-1)
    mb.add_grid(points, normals, material)  # (height x around): d/dy x d/dtheta = outward
    if not caps:
        return
    j = np.arange(n_around)
    for y, up in ((y0, -1.0), (y1, 1.0)):
        ring = np.stack([rim_x[:-1], np.full(n_around, y), rim_z[:-1]], axis=-1)
        vertices = np.concatenate([[[centre_xz[0], y, centre_xz[1]]], ring])
        nxt = (j + 1) % n_around + 1
        faces = np.stack([np.zeros(n_around, np.int64), j + 1, nxt], axis=-1)
        if up > 0:
            faces = faces[:, [0, 2, 1]]
        mb.add(vertices, faces, np.broadcast_to([0.0, up, 0.0], vertices.shape), material)


# --- arch bay: a rectangle with a semicircular opening, extruded -------------------------------


def _arch_angles(n_arc: int, half_span: float, height: float) -> tuple[np.ndarray, int, int]:
    """Angles of the arc vertices: uniform on [0, pi] plus the two angles whose rays from the
    arc centre pass through the top corners of the bay (so every outer segment is straight);
    uniform angles too close to a corner are dropped to avoid slivers. Returns the angles and
    the indices of the two corner angles."""
    corner = float(np.arctan2(height, half_span))
    corners = np.array([corner, np.pi - corner])
    uniform = np.linspace(0.0, np.pi, n_arc + 1)
    far = np.abs(uniform[:, None] - corners[None, :]).min(axis=1) > 0.25 * np.pi / n_arc
    far[0] = far[-1] = True
    theta = np.concatenate([uniform[far], corners])
    order = np.argsort(theta, kind="stable")
    theta = theta[order]
    where = np.argsort(order)  # positions of the concatenated entries after sorting
    n_far = int(far.sum())
    return theta, int(where[n_far]), int(where[n_far + 1])


@functools.lru_cache(maxsize=1024)
def arch_count(n_arc: int, n_radial: int, n_depth: int, half_span: float, height: float) -> int:
    k = len(_arch_angles(n_arc, half_span, height)[0]) - 1
    return 4 * k * n_radial + 4 * k * n_depth + 4 * n_radial * n_depth


@dataclasses.dataclass(frozen=True)
class ArchBay:
    """One bay of an arcade: the rectangle [x_mid - half_span, x_mid + half_span] x [y_spring,
    y_top] minus the half-disc of `radius` centred at (x_mid, y_spring), extruded from z0 to
    z1, cut into `n_arc` steps along the arc, `n_radial` from the arc outwards and `n_depth`
    along z.

    Raises:
        ValueError: a radius outside (0, half_span], a top not above the arc's crown, z1 <= z0,
            or a division count below 1.
    """

    x_mid: float
    half_span: float
    radius: float
    y_spring: float
    y_top: float
    z0: float
    z1: float
    n_arc: int
    n_radial: int
    n_depth: int

    def __post_init__(self):
        if not 0 < self.radius <= self.half_span:
            raise ValueError(f"ArchBay: radius must be in (0, half_span={self.half_span}], got {self.radius}")
        if not self.y_top > self.y_spring + self.radius:
            raise ValueError(
                f"ArchBay: y_top {self.y_top} must be above the arc's crown y_spring + radius "
                f"= {self.y_spring + self.radius}"
            )
        if not self.z1 > self.z0:
            raise ValueError(f"ArchBay: z1 must be > z0, got z0={self.z0}, z1={self.z1}")
        for name in ("n_arc", "n_radial", "n_depth"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ValueError(f"ArchBay: {name} must be a whole number >= 1, got {value!r}")


def add_arch_bay(mb, bay: ArchBay, material):
    """A closed solid: the bay's profile (`ArchBay`) extruded from z0 to z1.

    The profile is cut by rays from the arc centre: arc point A_k, outer boundary point B_k
    (on the bay's sides or top), and `n_radial` steps between them. The straight bits of the
    bottom (at angles 0 and pi, between the arc and the bay's corners) are the flats that rest
    on the columns' capitals.
    """
    x_mid, half_span, radius, y_spring, y_top = bay.x_mid, bay.half_span, bay.radius, bay.y_spring, bay.y_top
    z0, z1, n_arc, n_radial, n_depth = bay.z0, bay.z1, bay.n_arc, bay.n_radial, bay.n_depth
    h = y_top - y_spring
    theta, corner_right, corner_left = _arch_angles(n_arc, half_span, h)
    cos, sin = np.cos(theta), np.sin(theta)
    cos[0], sin[0], cos[-1], sin[-1] = 1.0, 0.0, -1.0, 0.0
    arc = np.stack([x_mid + radius * cos, y_spring + radius * sin], axis=-1)
    # Outer boundary where the ray from the arc centre leaves the bay: right side, top, left side.
    k = np.arange(len(theta))
    right, left = k <= corner_right, k >= corner_left
    top = ~(right | left)
    x_right, x_left = x_mid + half_span, x_mid - half_span
    outer = np.empty_like(arc)
    outer[right] = np.stack([np.full(right.sum(), x_right), y_spring + half_span * np.tan(theta[right])], -1)
    outer[left] = np.stack([np.full(left.sum(), x_left), y_spring - half_span * np.tan(theta[left])], -1)
    outer[top] = np.stack([x_mid + h * cos[top] / sin[top], np.full(top.sum(), y_top)], -1)
    outer[corner_right] = [x_right, y_top]
    outer[corner_left] = [x_left, y_top]
    outer[0, 1] = outer[-1, 1] = y_spring

    s = np.linspace(0.0, 1.0, n_radial + 1)
    profile = arc[:, None, :] + (outer - arc)[:, None, :] * s[None, :, None]  # (K+1, R+1, 2)
    profile[:, 0], profile[:, -1] = arc, outer  # exact, so the extruded strips share these edges
    zs = np.linspace(z0, z1, n_depth + 1)

    def lift(p2, z):
        return np.concatenate([p2, np.full(p2.shape[:-1] + (1,), z)], axis=-1)

    # Front (z0, normal -z) and back (z1, +z): d/dtheta x d/dradial = -z.
    mb.add_grid(lift(profile, z0), np.broadcast_to([0, 0, -1.0], profile.shape[:2] + (3,)), material)
    mb.add_grid(
        lift(profile, z1), np.broadcast_to([0, 0, 1.0], profile.shape[:2] + (3,)), material, flip=True
    )

    def extrude(curve2):  # (n, 2) -> (n, D+1, 3)
        return np.stack(np.broadcast_arrays(curve2[:, None, 0], curve2[:, None, 1], zs[None, :]), axis=-1)

    # Intrados (the arch's underside), normal towards the arc centre.
    inward = np.stack([-cos, -sin, 0 * cos], axis=-1)
    mb.add_grid(
        extrude(arc), np.broadcast_to(inward[:, None, :], (len(arc), len(zs), 3)), material, flip=True
    )
    # Outer boundary: right side, top, left side as separate flat strips (own corner vertices,
    # so shading normals do not bend round the corners), normal away from the bay.
    for lo, hi, normal in (
        (0, corner_right, (1.0, 0, 0)),
        (corner_right, corner_left, (0, 1.0, 0)),
        (corner_left, len(outer) - 1, (-1.0, 0, 0)),
    ):
        strip = extrude(outer[lo : hi + 1])
        mb.add_grid(strip, np.broadcast_to(normal, strip.shape), material)
    # Bottom flats at angle 0 (right) and pi (left), normal -y.
    down = np.broadcast_to([0, -1.0, 0], (n_radial + 1, len(zs), 3))
    mb.add_grid(extrude(profile[0]), down, material)
    mb.add_grid(extrude(profile[-1]), down, material, flip=True)


# --- a hanging cloth: an open, folded sheet -----------------------------------------------------


def sheet_count(nu: int, nv: int) -> int:
    return 2 * nu * nv


@dataclasses.dataclass(frozen=True)
class Cloth:
    """A cloth hanging from x0 to x1 between y_top and y_bottom in the plane z = const, with
    `folds` vertical sinusoidal folds of amplitude `depth` and its bottom edge sagging by `sag`
    in the middle, cut into `nu` x `nv` cells; its normals face `facing` * z (+1 or -1).

    Raises:
        ValueError: x1 <= x0, y_bottom >= y_top, a negative fold count, depth or sag, a cell
            count below 1, or a `facing` other than +1 or -1.
    """

    x0: float
    x1: float
    y_top: float
    y_bottom: float
    z: float
    folds: int
    depth: float
    sag: float
    nu: int
    nv: int
    facing: float = 1.0

    def __post_init__(self):
        if not (self.x1 > self.x0 and self.y_top > self.y_bottom):
            raise ValueError(
                f"Cloth: need x1 > x0 and y_top > y_bottom, got x {self.x0}..{self.x1}, "
                f"y {self.y_bottom}..{self.y_top}"
            )
        if self.folds < 0 or self.depth < 0 or self.sag < 0:
            raise ValueError(
                f"Cloth: folds, depth and sag must be >= 0, got {self.folds}, {self.depth}, {self.sag}"
            )
        for name in ("nu", "nv"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ValueError(f"Cloth: {name} must be a whole number >= 1, got {value!r}")
        if self.facing not in (1.0, -1.0):
            raise ValueError(f"Cloth: facing must be +1 or -1, got {self.facing!r}")


def add_cloth(mb, cloth: Cloth, material):
    """The `Cloth`: a sheet, not a solid (cloth is thin)."""
    x0, x1, y_top, y_bottom, z = cloth.x0, cloth.x1, cloth.y_top, cloth.y_bottom, cloth.z
    folds, depth, sag, nu, nv, facing = cloth.folds, cloth.depth, cloth.sag, cloth.nu, cloth.nv, cloth.facing
    u = np.linspace(0.0, 1.0, nu + 1)
    v = np.linspace(0.0, 1.0, nv + 1)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    x = x0 + (x1 - x0) * uu
    bottom = y_bottom - sag * np.sin(np.pi * uu)
    y = y_top + (bottom - y_top) * vv
    # folds widen towards the bottom, as a cloth hung from a rod does
    amplitude = depth * (0.35 + 0.65 * vv)
    phase = 2 * np.pi * folds * uu
    zz = z + facing * amplitude * np.sin(phase)
    points = np.stack([x, y, zz], axis=-1)
    # normal = dP/du x dP/dv, analytic
    dx_du = (x1 - x0) * np.ones_like(uu)
    dy_du = (-sag * np.pi * np.cos(np.pi * uu)) * vv
    dz_du = facing * amplitude * 2 * np.pi * folds * np.cos(phase)
    dy_dv = bottom - y_top
    dz_dv = facing * depth * 0.65 * np.sin(phase)
    du = np.stack([dx_du, dy_du, dz_du], axis=-1)
    dv = np.stack([np.zeros_like(uu), dy_dv, dz_dv], axis=-1)
    normals = np.cross(du, dv)
    flip = bool(normals[..., 2].mean() * facing < 0)
    if flip:
        normals = -normals
    mb.add_grid(points, normals, material, flip=flip)


# --- ground plane ------------------------------------------------------------------------------


def add_floor(mb, x0, x1, z0, z1, y, nx, nz, material_of_cell):
    """A horizontal grid facing +y; `material_of_cell(xc, zc)` gives each cell's material, so
    strips of another material follow the grid lines. Cells are emitted per material."""
    xs, zs = np.linspace(x0, x1, nx + 1), np.linspace(z0, z1, nz + 1)
    xc, zc = np.meshgrid((xs[:-1] + xs[1:]) / 2, (zs[:-1] + zs[1:]) / 2, indexing="ij")
    cell_material = np.asarray(material_of_cell(xc, zc)).reshape(nx, nz)
    xx, zz = np.meshgrid(xs, zs, indexing="ij")
    points = np.stack([xx, np.full(xx.shape, float(y)), zz], axis=-1)  # (nx+1, nz+1, 3)
    vertices = points.reshape(-1, 3)
    faces = grid_faces(nx, nz)[:, [0, 2, 1]]  # d/dx x d/dz = -y, so flip to face +y
    cells = np.concatenate([np.arange(nx * nz), np.arange(nx * nz)])  # grid_faces: lower then upper
    face_material = cell_material.reshape(-1)[cells]
    normals = np.broadcast_to([0.0, 1.0, 0.0], vertices.shape)
    for m in np.unique(face_material):
        sel = faces[face_material == m]
        used, inverse = np.unique(sel, return_inverse=True)
        mb.add(vertices[used], inverse.reshape(-1, 3), normals[used], int(m))


def floor_count(nx: int, nz: int) -> int:
    return 2 * nx * nz


# --- icosphere ---------------------------------------------------------------------------------


@functools.lru_cache(maxsize=8)
def unit_icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (on the unit sphere) and outward-wound faces of a subdivided icosahedron
    (cached: read-only)."""
    t = (1.0 + 5.0**0.5) / 2.0
    vertices = np.array(
        [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
         (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)], np.float64
    )  # fmt: skip
    faces = np.array(
        [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)], np.int64
    )  # fmt: skip
    vertices /= np.linalg.norm(vertices, axis=1, keepdims=True)
    for _ in range(subdivisions):
        # one new vertex per edge, shared by the two faces on it
        edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        unique, inverse = np.unique(edges, axis=0, return_inverse=True)
        mid = vertices[unique].sum(axis=1)
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = inverse.reshape(-1, 3) + len(vertices)  # midpoints of edges 01, 12, 20
        a, b, c = faces.T
        faces = np.concatenate(
            [np.stack(f, axis=-1) for f in ((a, m[:, 0], m[:, 2]), (b, m[:, 1], m[:, 0]),
                                            (c, m[:, 2], m[:, 1]), (m[:, 0], m[:, 1], m[:, 2]))]
        )  # fmt: skip
        vertices = np.concatenate([vertices, mid])
    tri = vertices[faces]
    outward = (
        np.einsum("ij,ij->i", np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), tri.sum(axis=1)) > 0
    )
    faces = np.where(outward[:, None], faces, faces[:, ::-1])
    vertices.setflags(write=False)
    faces.setflags(write=False)
    return vertices, faces


def add_icosphere(mb, centre, radius, subdivisions, material):
    unit, faces = unit_icosphere(int(subdivisions))
    mb.add(unit * radius + np.asarray(centre, np.float64), faces, unit, material)


def icosphere_count(subdivisions: int) -> int:
    return 20 * 4**subdivisions
