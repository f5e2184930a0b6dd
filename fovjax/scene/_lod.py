"""Geometry level of detail: quadric decimation, a chain of levels with measured error, and the
choice of level from the acuity model.

- `decimate(scene, ratio=…)` or `decimate(scene, target_triangles=…)`: a `Scene` with fewer
  triangles, by quadric edge collapse (`fast-simplification`, the library behind trimesh's
  `simplify_quadric_decimation`; the `[lod]` extra).
- `lod_levels(scene, ratios=…)`: the levels (the scene itself first), each with its measured
  geometric error, cached on disk; every level is an ordinary `Scene` with its own content hash, so
  `fovjax.trace.build_bvh(level)` builds and caches its BVH exactly as for the main scene.
- `select_lod(errors, eccentricity_deg, distance, acuity, pixels_per_degree)`: per region, the
  coarsest level whose projected error stays below what the eye (or the display) can resolve.

**Per-material decimation.** Each material's triangles are decimated on their own, to the same
ratio. Every triangle of a level therefore has exactly the material it had (a mirror never turns
into stone at a boundary, which a nearest-triangle transfer after decimating the whole mesh would
do along every material border), and texture coordinates and normals are taken from vertices of
the same material, so UVs are never read from another material's texture space. By default
(`preserve_border=True`) no edge touching an open border is collapsed, so the seam between two
materials stays where it is on both sides: no cracks open between them, and a wall's outline does
not erode (without it, a decimated flat square loses its corners: measured in tests/test_lod.py).
Vertices at the same position are welded for the decimator first (`_weld`): meshes built from
separate face grids (a box's six faces, the Cornell box's quads) would otherwise be all border,
pinned, and decimate into fans of slivers or not at all.

**Shape.** Quadric decimation still leaves flat regions as fans of long thin triangles, whose
large overlapping boxes cost a BVH many more tests per ray. `flip_coplanar` then turns coplanar
neighbours into a Delaunay triangulation (the surface does not change).

**Attributes carried over.** The decimator moves vertices to the quadric optimum, so a new vertex
is generally not an original one. Each triangle corner's normal and UV come from the nearest
original vertex of its material; where several original vertices sit within a hair of the
nearest (a sharp edge or a UV seam duplicates vertices), the one whose normal agrees best with
that triangle's own normal is taken, and a vertex whose corners take different originals is split
into one per original, so a flat-shaded box keeps each face's normal and its sharp edges.

**Error.** `LODLevels.errors[i]` is the one-sided Hausdorff distance (scene units) from the
original vertices to level i's surface (`geometric_error`: the bounds below, then exact
brute-force distances for the vertices with the largest bounds until the maximum is settled).
`surface_distance` gives each vertex's distance as an upper bound: the exact point-to-triangle
distance to the nearest of the candidate triangles that own the point's `CANDIDATES` nearest
samples of level i's surface (its vertices, centroids, points along its long edges and
area-weighted random points). A minimum over a subset of triangles is never below the minimum
over all, so a bound never under-reports; the refinement then makes the maximum exact. Missing
geometry (a part decimated away) shows as a large error, which is what `select_lod` needs.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path

import equinox as eqx
import numpy as np
from jaxtyping import Array, ArrayLike, Int

from .. import _environment
from ._scene import Scene, Textures, drop_degenerate, geometry_hash, make_scene

FORMAT_VERSION = 4  # 3: welded before decimating, coplanar flips after; 4: normals per corner
DEFAULT_RATIOS = (1.0, 0.5, 0.25, 0.1)
CANDIDATES = 16  # nearest surface samples whose triangles are checked exactly per original point
AGGRESSION = 7.0  # fast-simplification's default; lower is slower and closer to the target
WELD = 1e-6  # coincident-vertex tolerance, relative to the scene's extent (see `_weld`)
FLAT = 1e-6  # coplanarity tolerance of `flip_coplanar`, relative to the scene's extent
MIN_SHARE = 0.01  # a flip never makes a triangle with less than this share of its pair's area
FLIP_ROUNDS = 16  # most rounds of `flip_coplanar` (the atrium's levels settle within 8)
_SAMPLES_PER_TRIANGLE = 1  # area-weighted random samples on a level, per triangle on average


def _fast_simplification():
    try:
        import fast_simplification
    except ImportError:
        raise ImportError(
            "fovjax level of detail needs fast-simplification: pip install 'fovjax[lod]'"
        ) from None
    return fast_simplification


def _resolve(scene, where: str) -> Scene:
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, str):
        from . import BUILTIN  # the package's table; imported late, it imports this module

        if scene not in BUILTIN:
            raise ValueError(
                f"{where}: unknown scene {scene!r}; expected a Scene or one of {sorted(BUILTIN)}"
            )
        return BUILTIN[scene]()
    raise ValueError(f"{where}: scene must be a Scene or a built-in scene's name, got {type(scene).__name__}")


def _check_ratio(ratio, where: str) -> float:
    try:
        r = float(ratio)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: ratio must be a number in (0, 1], got {ratio!r}") from None
    if not (0.0 < r <= 1.0):
        raise ValueError(f"{where}: ratio must be in (0, 1], got {ratio!r}")
    return r


def _targets(face_material: np.ndarray, num_materials: int, ratio: float) -> np.ndarray:
    """Triangles to keep per material: the ratio of its count, at least one where it has any."""
    counts = np.bincount(face_material, minlength=num_materials)
    return np.where(counts > 0, np.maximum(1, np.rint(ratio * counts).astype(np.int64)), 0)


def _face_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Area-weighted (unnormalised) face normals, float64."""
    tri = v[f].astype(np.float64)
    return np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])


def _carry_attributes(
    new_v: np.ndarray, new_f: np.ndarray, old_v: np.ndarray, pool: np.ndarray, normals, extent: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices, faces, src): per triangle corner, the original vertex (one of `pool`, the
    material's) whose normal/UV it takes: the nearest one, near-ties (the copies of a corner of a
    flat-shaded box, a UV seam) broken by agreement with that triangle's own normal. A new vertex
    whose corners take different originals is split into one vertex per original, so a crease
    the decimator sees as one vertex (the mesh is welded for it) stays a sharp crease."""
    from scipy.spatial import KDTree

    tree = KDTree(old_v[pool].astype(np.float64))
    k = min(4, len(pool))
    dist, idx = tree.query(new_v.astype(np.float64), k=k)
    dist, idx = dist.reshape(len(new_v), k), idx.reshape(len(new_v), k)
    if normals is None or k == 1:
        return new_v, new_f, pool[idx[:, 0]]
    near = dist <= dist[:, :1] * (1 + 1e-4) + 1e-6 * extent
    fn = _face_normals(new_v, new_f)
    corner = np.empty(new_f.shape, np.int64)
    for c in range(3):
        vert = new_f[:, c]
        agree = np.einsum("fkc,fc->fk", normals[pool[idx[vert]]].astype(np.float64), fn)
        agree = np.where(near[vert], agree, -np.inf)
        corner[:, c] = pool[idx[vert, np.argmax(agree, axis=1)]]
    key = new_f.reshape(-1).astype(np.int64) * len(old_v) + corner.reshape(-1)
    unique, inverse = np.unique(key, return_inverse=True)
    return new_v[unique // len(old_v)], inverse.reshape(-1, 3).astype(np.int32), unique % len(old_v)


def _weld(points: np.ndarray, faces: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices closer than about `tol` (same rounded coordinates) into one, for the
    decimator only: a box built from six separate face grids (the atrium's walls) becomes one
    closed mesh, so its edges are creases the quadrics keep, not open borders that
    `preserve_border` pins (fans of slivers from every kept border vertex). Triangles that
    collapse onto an edge are dropped."""
    keys = np.round(points / max(tol, 1e-30)).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    out = inverse.reshape(-1)[faces]
    keep = (out[:, 0] != out[:, 1]) & (out[:, 1] != out[:, 2]) & (out[:, 2] != out[:, 0])
    return points[first], out[keep].astype(np.int32)


def _angle(u: np.ndarray, w: np.ndarray) -> np.ndarray:
    return np.arctan2(np.linalg.norm(np.cross(u, w), axis=1), np.einsum("ij,ij->i", u, w))


def flip_coplanar(points, faces, tol: float, rounds: int = FLIP_ROUNDS) -> np.ndarray:
    """Faces with the shared edge of coplanar neighbours flipped to a Delaunay triangulation
    (Lawson: where the two angles facing the edge sum to over pi), until no flip is left or
    after `rounds` rounds. Only pairs whose fourth vertex lies within `tol` of the other
    triangle's plane (both ways), that share the edge in opposite directions (consistent
    winding) and form a convex quad are flipped, so the surface and its orientation are
    unchanged. Each round flips an independent set (no triangle twice): per triangle the pair of
    largest gain, taken where both triangles agree.

    Why: quadric decimation leaves flat regions as fans of long slivers (every border vertex
    connected across the face), whose overlapping boxes cost a ray many more leaf tests; the
    flips turn a fan over a rectangle back into few triangles with small boxes."""
    v = np.asarray(points, np.float64)
    f = np.array(faces, np.int64).reshape(-1, 3)
    if len(f) < 2:
        return f
    sub = np.arange(len(f))  # the faces in play: after the first round, those of coplanar pairs
    for i in range(rounds):
        g = f[sub]
        a = g.reshape(-1)
        b = np.roll(g, -1, axis=1).reshape(-1)
        c = np.roll(g, -2, axis=1).reshape(-1)
        face = np.repeat(np.arange(len(g)), 3)
        key = np.minimum(a, b) * len(v) + np.maximum(a, b)
        order = np.argsort(key, kind="stable")
        ks = key[order]
        same = ks[1:] == ks[:-1]
        # edges of exactly two triangles: equal neighbours in the sorted keys, no third
        pair = same & np.concatenate([[True], ~same[:-1]]) & np.concatenate([~same[1:], [True]])
        h1, h2 = order[:-1][pair], order[1:][pair]
        ok = (a[h1] == b[h2]) & (b[h1] == a[h2])
        h1, h2 = h1[ok], h2[ok]
        f1, f2 = face[h1], face[h2]
        pa, pb, pc, pd = v[a[h1]], v[b[h1]], v[c[h1]], v[c[h2]]
        n1 = np.cross(pb - pa, pc - pa)
        n2 = np.cross(pa - pb, pd - pb)
        l1, l2 = np.linalg.norm(n1, axis=1), np.linalg.norm(n2, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            flat = (np.abs(np.einsum("ij,ij->i", pd - pa, n1)) <= tol * l1) & (
                np.abs(np.einsum("ij,ij->i", pc - pb, n2)) <= tol * l2
            )
        flat &= (l1 > 0) & (l2 > 0) & (np.einsum("ij,ij->i", n1, n2) > 0)
        if i == 0:  # a flip keeps every edge's coplanarity, so only these faces ever flip
            keep = np.unique(np.concatenate([f1[flat], f2[flat]]))
            sub, f1, f2 = sub[keep], np.searchsorted(keep, f1), np.searchsorted(keep, f2)
            g = g[keep]
            inside = np.isin(face[h1], keep) & np.isin(face[h2], keep)
            h1, h2, f1, f2, flat = h1[inside], h2[inside], f1[inside], f2[inside], flat[inside]
            pa, pb, pc, pd, n1, n2, l1, l2 = (x[inside] for x in (pa, pb, pc, pd, n1, n2, l1, l2))
        # new triangles (a, d, c) and (b, c, d): both must face the old way (a convex quad)
        m1 = np.cross(pd - pa, pc - pa)
        m2 = np.cross(pc - pb, pd - pb)
        # ... and neither may be a needle (under MIN_SHARE of the pair's area)
        quad = l1 + l2
        least = MIN_SHARE * quad * np.linalg.norm(n1, axis=1)
        convex = (np.einsum("ij,ij->i", m1, n1) > least) & (np.einsum("ij,ij->i", m2, n1) > least)
        # Lawson: the angles facing the edge sum to over pi
        gain = _angle(pa - pc, pb - pc) + _angle(pa - pd, pb - pd) - np.pi
        gain = np.where(flat & convex, gain, 0.0)
        cand = np.flatnonzero(gain > 1e-9)
        if len(cand) == 0:
            break
        # rank candidates by gain (ties by index); keep those that are the best of both triangles
        rank = np.empty(len(cand), np.int64)
        rank[np.lexsort((cand, -gain[cand]))] = np.arange(len(cand))
        best = np.full(len(g), len(cand), np.int64)
        np.minimum.at(best, f1[cand], rank)
        np.minimum.at(best, f2[cand], rank)
        take = cand[(best[f1[cand]] == rank) & (best[f2[cand]] == rank)]
        ia, ib, ic, id_ = a[h1[take]], b[h1[take]], c[h1[take]], c[h2[take]]
        g[f1[take]] = np.stack([ia, id_, ic], 1)
        g[f2[take]] = np.stack([ib, ic, id_], 1)
        f[sub] = g
    return f


def _decimate_arrays(scene: Scene, ratio: float, preserve_border: bool = True) -> dict:
    """Per-material decimation; host arrays of the new mesh (vertices, faces, face_material,
    normals, uvs)."""
    fs = _fast_simplification()
    v = np.asarray(scene.vertices, np.float32)
    f = np.asarray(scene.faces, np.int32)
    fm = np.asarray(scene.face_material, np.int32)
    normals = None if scene.normals is None else np.asarray(scene.normals, np.float32)
    uvs = None if scene.uvs is None else np.asarray(scene.uvs, np.float32)
    targets = _targets(fm, len(scene.materials), ratio)
    extent = float(np.ptp(v, axis=0).max()) or 1.0
    out_v, out_f, out_m, out_n, out_uv = [], [], [], [], []
    offset = 0
    for m in np.flatnonzero(targets):
        faces_m = f[fm == m]
        used, local = np.unique(faces_m, return_inverse=True)
        local = local.reshape(-1, 3).astype(np.int32)
        if targets[m] < len(faces_m):
            pts, tris = _weld(v[used].astype(np.float64), local, WELD * extent)
            simplified = fs.simplify(
                pts, tris, target_count=int(targets[m]), agg=AGGRESSION, preserve_border=preserve_border
            )
            pts, tris = simplified[0], simplified[1]
            pts, tris = np.asarray(pts, np.float64), np.asarray(tris, np.int64)
            tris = flip_coplanar(pts, tris, FLAT * extent, FLIP_ROUNDS)
            pts = pts.astype(np.float32)
            keep = drop_degenerate(pts, tris) if len(tris) else np.zeros(0, bool)
            tris = tris[keep]
            if len(tris) == 0:
                continue  # the material's parts collapsed entirely; the error shows it
            live, tris = np.unique(tris, return_inverse=True)
            pts, tris = pts[live], tris.reshape(-1, 3).astype(np.int32)
            pts, tris, src = _carry_attributes(pts, tris, v, used, normals, extent)
        else:  # nothing to remove (a material of a single triangle at a small ratio)
            pts, tris, src = v[used], local, used
        out_v.append(pts)
        out_f.append(tris + offset)
        out_m.append(np.full(len(tris), m, np.int32))
        if normals is not None:
            out_n.append(normals[src])
        if uvs is not None:
            out_uv.append(uvs[src])
        offset += len(pts)
    if not out_f:
        raise ValueError(f"decimate: {scene.name!r} at ratio {ratio} kept no triangle")
    return {
        "vertices": np.concatenate(out_v),
        "faces": np.concatenate(out_f),
        "face_material": np.concatenate(out_m),
        "normals": np.concatenate(out_n) if normals is not None else None,
        "uvs": np.concatenate(out_uv) if uvs is not None else None,
    }


def _build(scene: Scene, ratio: float, arrays: dict) -> Scene:
    return make_scene(
        arrays["vertices"],
        arrays["faces"],
        face_material=arrays["face_material"],
        materials=scene.materials,
        lights=scene.lights,
        normals=arrays["normals"],
        uvs=arrays["uvs"],
        textures=Textures(scene.textures, scene.texture_paths),
        ambient=scene.ambient,
        name=f"{scene.name}@lod{ratio:g}",
    )


def decimate(
    scene: Scene | str,
    ratio: float | None = None,
    *,
    target_triangles: int | None = None,
    preserve_border: bool = True,
) -> Scene:
    """A `Scene` with about `ratio` of the triangles (or `target_triangles` of them), by quadric
    decimation of each material's triangles (module docstring: why per material, how normals
    and UVs are carried over). Materials, lights, textures and the ambient term are the scene's
    own; every triangle keeps its material. Ratio 1 (or every triangle) returns `scene` itself.

    `preserve_border` (default) never collapses an edge touching an open border of a material's
    mesh: a wall's outline and the seam between two materials stay where they are (no cracks, no
    eroded edges), at the price of not reaching the ratio where most triangles touch a border
    (vertices at one position are welded first, so separate quads that share corners are not
    border there). The result may therefore keep more triangles than asked; `num_triangles`
    says how many.

    `scene` is a `Scene` or a built-in scene's name (`fovjax.scenes.BUILTIN`). Raises ValueError
    for a ratio outside (0, 1], a target outside [1, number of triangles], both or neither, or an
    unknown scene; ImportError naming the `[lod]` extra when fast-simplification is missing.
    """
    if (ratio is None) == (target_triangles is None):
        raise ValueError("decimate: pass exactly one of ratio and target_triangles")
    scene = _resolve(scene, "decimate")
    n = scene.num_triangles
    if target_triangles is not None:
        if isinstance(target_triangles, bool) or not isinstance(target_triangles, int | np.integer):
            raise ValueError(f"decimate: target_triangles must be an integer, got {target_triangles!r}")
        if not 1 <= target_triangles <= n:
            raise ValueError(
                f"decimate: target_triangles must be in [1, {n}] for {scene.name!r}, got {target_triangles}"
            )
        ratio = target_triangles / n
    ratio = _check_ratio(ratio, "decimate")
    if round(ratio * n) >= n:
        return scene
    return _build(scene, ratio, _decimate_arrays(scene, ratio, preserve_border))


# --- geometric error ------------------------------------------------------------------------


def _point_triangle_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Exact Euclidean distance from points p (N, 3) to triangles abc (N, 3) each (Ericson,
    Real-Time Collision Detection, 5.1.5: the closest point by Voronoi region). Float32, as the
    scene is: rounding is ~1e-7 of the coordinates, far below any error worth a level."""
    p, a, b, c = (np.asarray(x, np.float32) for x in (p, a, b, c))
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_in, w_in = vb / denom, vc / denom
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    q = a + v_in[:, None] * ab + w_in[:, None] * ac  # inside the face
    region = [
        ((d1 <= 0) & (d2 <= 0), a),
        ((d3 >= 0) & (d4 <= d3), b),
        ((d6 >= 0) & (d5 <= d6), c),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + t_ab[:, None] * ab),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + t_ac[:, None] * ac),
        ((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), b + t_bc[:, None] * (c - b)),
    ]
    for mask, point in reversed(region):  # the first region that applies wins
        q = np.where(mask[:, None], point, q)
    return np.linalg.norm(p - q, axis=1)


def surface_distance(
    points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, seed: int = 0
) -> np.ndarray:
    """Per point, an upper bound on its distance to the triangle surface (vertices, faces): the
    exact distance to the nearest of the triangles owning its `CANDIDATES` nearest surface samples
    (module docstring)."""
    from scipy.spatial import KDTree

    v = np.asarray(vertices, np.float32)
    f = np.asarray(faces, np.int64)
    tri = v[f]
    rng = np.random.default_rng(seed)
    area = 0.5 * np.linalg.norm(_face_normals(v, f), axis=1)
    ids = np.arange(len(f))
    # Samples of the surface, each owned by one triangle: every vertex (owned by one face using
    # it), every centroid, and area-weighted random points (big triangles get many).
    vertex_owner = np.zeros(len(v), np.int64)
    vertex_owner[f.reshape(-1)] = np.repeat(ids, 3)
    used = np.unique(f)
    n_random = _SAMPLES_PER_TRIANGLE * len(f)
    owner_r = rng.choice(len(f), n_random, p=area / area.sum()) if area.sum() > 0 else ids[:0]
    w = rng.dirichlet(np.ones(3), len(owner_r))
    # Points along each long edge (at 1/4, 1/2, 3/4; long: over twice the median edge): a long
    # thin triangle is found from any point beside it, not only from near its centroid. Short
    # edges are covered by their vertices.
    ends = np.roll(tri, -1, axis=1)
    length = np.linalg.norm(ends - tri, axis=2)
    long_f, long_e = np.nonzero(length > 2 * np.median(length))
    a, b = tri[long_f, long_e], ends[long_f, long_e]
    samples = np.concatenate(
        [
            v[used],
            tri.mean(axis=1),
            *(a + s * (b - a) for s in (0.25, 0.5, 0.75)),
            np.einsum("nk,nkc->nc", w, tri[owner_r]),
        ]
    )
    owners = np.concatenate([vertex_owner[used], ids, long_f, long_f, long_f, owner_r])
    tree = KDTree(samples)
    p = np.asarray(points, np.float32)
    # First the triangle owning the nearest sample: most points of a decimated scene lie on the
    # new surface (flat regions keep their plane), and an upper bound of ~0 needs no more work.
    _, nearest = tree.query(p, k=1, workers=-1)
    t = tri[owners[nearest]]
    best = _point_triangle_distance(p, t[:, 0], t[:, 1], t[:, 2])
    extent = float(np.ptp(v, axis=0).max()) if len(v) else 1.0
    rest = np.flatnonzero(best > 1e-6 * extent)
    k = min(CANDIDATES, len(owners))
    if len(rest) and k > 1:
        _, nearest = tree.query(p[rest], k=k, workers=-1)
        cand = np.sort(owners[np.asarray(nearest).reshape(len(rest), k)], axis=1)
        fresh = np.ones(cand.shape, bool)
        fresh[:, 1:] = cand[:, 1:] != cand[:, :-1]  # each candidate triangle once per point
        rows, cols = np.nonzero(fresh)
        t = tri[cand[rows, cols]]
        dist = np.full(cand.shape, np.inf)
        dist[rows, cols] = _point_triangle_distance(p[rest][rows], t[:, 0], t[:, 1], t[:, 2])
        best[rest] = np.minimum(best[rest], dist.min(axis=1))
    return best


def _original_points(original: Scene) -> np.ndarray:
    v = np.asarray(original.vertices, np.float32)
    return v[np.unique(np.asarray(original.faces))]


def _exact_distance(points: np.ndarray, tri: np.ndarray, bound: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest of all triangles, given an upper bound per point:
    only triangles whose bounding box lies within the bound can be nearer, and only those get
    the exact test (the result is exact, the pruning only saves work)."""
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    out = np.asarray(bound, np.float32).copy()
    block = max(1, 4_000_000 // max(len(tri), 1))
    for i in range(0, len(points), block):
        p = points[i : i + block]
        reach = out[i : i + block, None] * (1 + 1e-5) + 1e-7
        # A triangle can be nearer than the bound only if its box overlaps the cube of half-side
        # `reach` around the point (a superset of the sphere: nothing nearer is skipped).
        near = np.ones((len(p), len(tri)), bool)
        for c in range(3):
            near &= lo[None, :, c] <= p[:, None, c] + reach
            near &= hi[None, :, c] >= p[:, None, c] - reach
        rows, cols = np.nonzero(near)
        t = tri[cols]
        d = _point_triangle_distance(p[rows], t[:, 0], t[:, 1], t[:, 2])
        part = out[i : i + block]
        np.minimum.at(part, rows, d)
        out[i : i + block] = part
    return out


def geometric_error(
    original: Scene, level: Scene, _points: np.ndarray | None = None, max_exact: int = 512
) -> float:
    """One-sided Hausdorff distance (scene units) from the original scene's vertices to
    `level`'s surface; 0 when `level` is `original`.

    Each vertex's `surface_distance` bound is computed first; then the vertices with the largest
    bounds get their exact distance (every triangle of the level whose bounding box lies within
    the bound is tested), in order,
    until the largest exact distance found is at least every remaining bound: that is the exact
    maximum. If `max_exact` vertices do not settle it, the result is the larger of the exact
    maximum so far and the largest remaining bound, still never below the true distance."""
    if level is original or level.content_hash == original.content_hash:
        return 0.0
    points = _original_points(original) if _points is None else _points
    bound = surface_distance(points, np.asarray(level.vertices), np.asarray(level.faces))
    order = np.argsort(-bound, kind="stable")
    tri = level.triangles()
    exact_max, step = 0.0, 32
    for start in range(0, min(len(order), max_exact), step):
        if bound[order[start]] <= exact_max:
            return exact_max
        idx = order[start : start + step]
        exact_max = max(exact_max, float(_exact_distance(points[idx], tri, bound[idx]).max()))
    rest = order[max_exact:]
    return max(exact_max, float(bound[rest].max()) if len(rest) else 0.0)


# --- the chain of levels, cached --------------------------------------------------------------


class LODLevels(eqx.Module):
    """Levels of detail of one scene, finest first: `scenes[0]` is the scene itself.

    `ratios[i]` is the requested share of triangles, `errors[i]` the measured geometric error of
    level i (scene units; `geometric_error`), `triangles[i]` its triangle count."""

    scenes: tuple[Scene, ...]
    ratios: tuple[float, ...] = eqx.field(static=True)
    errors: tuple[float, ...] = eqx.field(static=True)
    triangles: tuple[int, ...] = eqx.field(static=True)
    seconds: float = eqx.field(static=True, default=0.0)
    from_cache: bool = eqx.field(static=True, default=False)

    def __len__(self) -> int:
        return len(self.scenes)


def _cache_dir(cache_dir) -> Path:
    return Path(cache_dir) if cache_dir is not None else _environment.cache_dir("lod")


def _cache_key(scene: Scene, ratio: float, preserve_border: bool) -> str:
    ghash = scene.content_hash or geometry_hash(np.asarray(scene.vertices), np.asarray(scene.faces))
    h = hashlib.sha256()
    for a in (scene.face_material, scene.normals, scene.uvs):
        h.update(b"-" if a is None else np.ascontiguousarray(a).tobytes())
    meta = {
        "g": ghash,
        "attr": h.hexdigest(),
        "r": ratio,
        "border": preserve_border,
        "agg": AGGRESSION,
        "weld": WELD,
        "flat": FLAT,
        "flips": FLIP_ROUNDS,
        "rule": "delaunay",
        "share": MIN_SHARE,
        "k": CANDIDATES,
        "v": FORMAT_VERSION,
    }
    return hashlib.sha256(json.dumps(meta, sort_keys=True).encode()).hexdigest()[:32]


def _load_level(path: Path):
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {
                k: (np.array(z[k]) if k in z.files else None)
                for k in ("vertices", "faces", "face_material", "normals", "uvs")
            }
        if meta.get("v") != FORMAT_VERSION:
            return None
        return arrays, float(meta["error"])
    except Exception:  # unreadable or partial: rebuild, never trust
        return None


def _save_level(path: Path, arrays: dict, error: float) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
        present = {k: a for k, a in arrays.items() if a is not None}
        np.savez(tmp, meta=np.array(json.dumps({"v": FORMAT_VERSION, "error": error})), **present)
        os.replace(tmp, path)
    except OSError:
        pass  # a read-only cache only costs the rebuild next time


def lod_levels(
    scene: Scene | str,
    ratios=DEFAULT_RATIOS,
    *,
    cache: bool = True,
    cache_dir: str | os.PathLike | None = None,
    preserve_border: bool = True,
) -> LODLevels:
    """Decimate `scene` to each ratio (finest first; 1 is the scene itself) and measure each
    level's geometric error. Levels and errors are cached on disk (`$FOVJAX_CACHE_DIR/lod`, else
    `~/.cache/fovjax/lod`) keyed by the scene's geometry, attributes and ratio, so a second call
    loads them. Each level is a `Scene`: `fovjax.trace.build_bvh(level)` builds and caches its BVH
    under the level's own content hash, as for any scene. `preserve_border` as in `decimate`."""
    scene = _resolve(scene, "lod_levels")
    try:
        ratios = tuple(ratios)
    except TypeError:
        raise ValueError(
            f"lod_levels: ratios must be a sequence of numbers in (0, 1], got {ratios!r}"
        ) from None
    if not ratios:
        raise ValueError("lod_levels: need at least one ratio")
    ratios = tuple(_check_ratio(r, "lod_levels") for r in ratios)
    if list(ratios) != sorted(set(ratios), reverse=True):
        raise ValueError(f"lod_levels: ratios must be strictly decreasing (finest first), got {ratios}")
    t0 = time.perf_counter()
    scenes, errors, all_cached, points = [], [], True, None
    for r in ratios:
        if round(r * scene.num_triangles) >= scene.num_triangles:
            scenes.append(scene)
            errors.append(0.0)
            continue
        path = _cache_dir(cache_dir) / f"{_cache_key(scene, r, preserve_border)}.npz"
        hit = _load_level(path) if cache else None
        if hit is None:
            all_cached = False
            arrays = _decimate_arrays(scene, r, preserve_border)
            level = _build(scene, r, arrays)
            points = _original_points(scene) if points is None else points
            error = geometric_error(scene, level, points)
            if cache:
                _save_level(path, arrays, error)
        else:
            arrays, error = hit
            level = _build(scene, r, arrays)
        scenes.append(level)
        errors.append(error)
    return LODLevels(
        scenes=tuple(scenes),
        ratios=ratios,
        errors=tuple(errors),
        triangles=tuple(s.num_triangles for s in scenes),
        seconds=time.perf_counter() - t0,
        from_cache=all_cached,
    )


# --- choosing a level -------------------------------------------------------------------------


def select_lod(
    errors,
    eccentricity_deg: ArrayLike,
    distance: ArrayLike,
    acuity,
    pixels_per_degree: float,
) -> Int[Array, "*batch"]:
    """Per region, the index of the coarsest level whose geometric error, seen from `distance`
    (scene units, the same as `errors`) at retinal eccentricity `eccentricity_deg`, subtends no
    more than the resolvable angle there: the acuity model's minimum angle of resolution
    MAR(ω) = 1/V(ω) arcmin (V decimal acuity, as `fovjax.acuity` fits it), but never finer than
    one display pixel (60 / `pixels_per_degree` arcmin). Where V(ω) <= 0 the eye resolves nothing
    and the display's pixel alone decides.

    `errors` (L,) are a `LODLevels`'s errors (finest first); `acuity` is any callable V(ω), e.g.
    `fovjax.acuity.THESIS_MODEL`. `eccentricity_deg` and `distance` broadcast; the result is an
    int32 array of their shape. Pure jax.numpy: runs under `jax.jit` with traced eccentricities
    and distances. The choice never gets finer as eccentricity grows (V falls with ω).
    """
    import jax.numpy as jnp

    err = np.asarray(errors, np.float64)
    if err.ndim != 1 or err.size == 0 or not np.isfinite(err).all() or (err < 0).any():
        raise ValueError(
            f"select_lod: errors must be a non-empty 1-D sequence of finite values >= 0, got {errors!r}"
        )
    ppd = float(pixels_per_degree)
    if not (np.isfinite(ppd) and ppd > 0):
        raise ValueError(
            f"select_lod: pixels_per_degree must be a positive number, got {pixels_per_degree!r}"
        )
    if not callable(acuity):
        raise ValueError(f"select_lod: acuity must be an acuity model V(omega), got {type(acuity).__name__}")
    omega = jnp.asarray(eccentricity_deg, jnp.float32)
    dist = jnp.asarray(distance, jnp.float32)
    v = jnp.asarray(acuity(omega), jnp.float32)
    mar = jnp.where(v > 0, 1.0 / jnp.where(v > 0, v, 1.0), jnp.inf)  # arcmin
    threshold = jnp.maximum(mar, 60.0 / ppd)
    # Angle (arcmin) each level's error subtends at the distance; a distance <= 0 resolves all.
    e = jnp.asarray(err, jnp.float32)
    angle = jnp.degrees(jnp.arctan2(e, jnp.maximum(dist, 0.0)[..., None])) * 60.0
    ok = angle <= threshold[..., None]
    level = jnp.arange(len(err), dtype=jnp.int32)
    return jnp.max(jnp.where(ok, level, 0), axis=-1).astype(jnp.int32)
