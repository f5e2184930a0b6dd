"""Geometry level of detail per region (`Fidelity.lod`): the scene's levels merged into one BVH
and one set of scene arrays, and the level each region's rays are traced against.

**One traversal.** The levels a foveation uses (`fovjax.scene.lod_levels`; 0 is the scene itself)
are merged (`fovjax.trace.merge_bvhs`): one table holding every level's tree, one root per level,
the scene arrays concatenated the same way. Every ray carries its region's level (the renderer's
`ShadingClasses.level`, a table per region, as its reflection depth and shadow mode), and the
traversal starts it at that level's root: one traversal per batch whatever the mix of levels,
static shapes, nothing per ray on the host. Shadow rays and reflections inherit the level, so a
coarse surface is shadowed by coarse geometry (no self-shadowing acne between two levels), and
shading reads the level's own normals, UVs and materials (the hit's face indexes them).

**"auto".** A region at `lod="auto"` gets the coarsest level whose error stays invisible
everywhere in the region (`fovjax.scene.select_lod`):
- eccentricity: the region's *inner* edge (0 for the fovea, `fovea_deg` for the periphery,
  `periphery_deg` outside): acuity falls with eccentricity, so the finest detail the region can
  show is at its inner edge, and a level fine enough there is fine enough in all of it;
- distance: a lower bound of the distance from either eye to the nearest triangle of the finest
  level, every frame from the traced eye positions (the bound from the eyes' midpoint less half
  their separation). The level's error is its maximum (one-sided
  Hausdorff) anywhere in the scene, so the worst case is that error on the nearest surface, seen
  face on; that angle is compared. Conservative on purpose (no visible error anywhere, at the
  price of coarsening less than a per-pixel choice could). The bound: the triangles in BVH leaf
  order, in groups of `GROUP` rows, each group's box; for the `NEAREST` groups whose boxes are
  nearest, each triangle's own bound (the larger of the distances to its box and to its plane,
  both never above the distance to the triangle), and for every other triangle the next group's
  box distance. Cheap (a few thousand boxes) and never above the true distance;
- the resolvable angle: max(MAR(ω) = 1 / V(ω) arcmin of the foveation's acuity model (the
  thesis's V(ω) by default), one display pixel: 60 / pixels-per-degree arcmin at the display's
  centre, where a pixel subtends the most (the same figure `fovea_tile` sizes the tile with).
"""

from __future__ import annotations

import collections

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

GROUP = 16  # triangle rows per box of the "auto" distance bound
NEAREST = 16  # groups whose triangles are bounded one by one
_MERGED: collections.OrderedDict = collections.OrderedDict()  # merged levels, memoised (host copies)


class LODTables(eqx.Module):
    """What the foveated frame needs of the levels beyond the merged arrays and BVH: the boxes
    bounding the finest level's triangles (for "auto"), the finest level's vertex count (its
    `scene_scale` gives the ray offsets), each level's error and the display's pixels per degree."""

    boxes: Float[np.ndarray | Array, "G 2 3"]
    num_vertices: int = eqx.field(static=True)
    num_triangles: int = eqx.field(static=True)
    errors: tuple[float, ...] = eqx.field(static=True)
    pixels_per_degree: float = eqx.field(static=True)


def lod_needed(foveation) -> int | None:
    """The finest-to-coarsest levels a foveation needs: the highest level index (every level for
    "auto"; -1 stands for all), or None when every region traces the scene itself."""
    if foveation.fidelity is None:
        return None
    wanted = [f.lod for f in foveation.fidelity]
    if any(w == "auto" for w in wanted):
        return -1
    top = max((int(w) for w in wanted if w is not None), default=0)
    return top or None


def check_levels(foveation, levels) -> None:
    """ValueError for a level index beyond the scene's levels or "auto" without an acuity model."""
    from ..acuity import AcuityModel

    for name, f in zip(("fovea", "periphery", "outside"), foveation.fidelity, strict=True):
        if f.lod == "auto" and not isinstance(foveation.acuity, AcuityModel):
            raise ValueError(
                f"Foveation.fidelity ({name}): lod='auto' chooses levels from the acuity model V(ω), "
                f"but Foveation.acuity is {type(foveation.acuity).__name__}, not a fovjax.acuity model"
            )
        if f.lod not in (None, "auto") and int(f.lod) >= len(levels):
            raise ValueError(
                f"Foveation.fidelity ({name}): lod {f.lod} is out of range: the scene has "
                f"{len(levels)} levels of detail (ratios {levels.ratios}), indices 0..{len(levels) - 1}"
            )


def _merged_geometry(scenes) -> dict:
    """The geometry of every level concatenated (faces re-indexed), as `merge_bvhs` concatenates
    the trees: the `SceneArrays` fields to replace."""
    present = {k: [getattr(s, k) is None for s in scenes] for k in ("normals", "uvs")}
    for k, none in present.items():
        if any(none) and not all(none):
            raise ValueError(f"levels of detail: some levels have {k} and some do not")
    offsets = np.cumsum([0, *(s.vertices.shape[0] for s in scenes[:-1])])
    cat = {
        "vertices": np.concatenate([np.asarray(s.vertices, np.float32) for s in scenes]),
        "faces": np.concatenate(
            [np.asarray(s.faces) + o for s, o in zip(scenes, offsets, strict=True)]
        ).astype(np.int32),
        "face_material": np.concatenate([np.asarray(s.face_material) for s in scenes]).astype(np.int32),
    }
    for k in ("normals", "uvs"):
        if not present[k][0]:
            cat[k] = np.concatenate([np.asarray(getattr(s, k), np.float32) for s in scenes])
    return cat


def _with_geometry(arrays, cat: dict):
    names = tuple(cat)
    return eqx.tree_at(lambda a: tuple(getattr(a, k) for k in names), arrays, tuple(cat[k] for k in names))


def _group_boxes(bvh) -> np.ndarray:
    """(G, 2, 3) boxes of `GROUP` consecutive triangle rows of `bvh` (leaf order: near triangles
    share a group, so the boxes stay small)."""
    table = np.asarray(bvh.table)
    corners = table[int(bvh.num_nodes) :, :9].copy().view(np.float32).reshape(-1, 3, 3)
    pad = (-corners.shape[0]) % GROUP
    corners = np.concatenate([corners, np.repeat(corners[-1:], pad, axis=0)])
    groups = corners.reshape(-1, GROUP * 3, 3)
    return np.stack([groups.min(axis=1), groups.max(axis=1)], axis=1).astype(np.float32)


def prepare_levels(scene, arrays, bvh, levels, top: int, pixels_per_degree: float):
    """(merged scene arrays, merged BVH, `LODTables`) for levels 0..top of `levels` (every level
    for top -1), `bvh` being level 0's. Memoised per levels and arrays (a frame after the first
    merges nothing; the scene arrays' materials, lights and environment are this call's)."""
    from ..render.internal import bvh_for
    from ..trace import merge_bvhs

    scenes = levels.scenes if top < 0 else levels.scenes[: top + 1]
    key = (bvh.key, tuple(s.content_hash for s in scenes), pixels_per_degree)
    hit = _MERGED.get(key)
    if hit is None:
        bvhs = [bvh] + [bvh_for(s, None) for s in scenes[1:]]
        tables = LODTables(
            boxes=_group_boxes(bvh),
            num_vertices=int(np.shape(scenes[0].vertices)[0]),
            num_triangles=int(np.shape(scenes[0].faces)[0]),
            errors=tuple(float(e) for e in levels.errors[: len(scenes)]),
            pixels_per_degree=float(pixels_per_degree),
        )
        hit = _MERGED[key] = (_merged_geometry(scenes), merge_bvhs(bvhs), tables)
        while len(_MERGED) > 2:
            _MERGED.popitem(last=False)
    cat, merged, tables = hit
    return _with_geometry(arrays, cat), merged, tables


def _box_distance(boxes, p):
    """Distance from a point p (3,) to boxes (..., 2, 3); 0 inside."""
    gap = jnp.maximum(jnp.maximum(boxes[..., 0, :] - p, p - boxes[..., 1, :]), 0.0)
    return jnp.sqrt(jnp.sum(gap * gap, axis=-1))


def nearest_distance(tables: LODTables, bvh, eye):
    """A lower bound of the distance from `eye` (3,) to the finest level's nearest triangle (see
    the module docstring); `bvh` the merged BVH (the finest level's triangle rows come first)."""
    from jax import lax

    boxes = jnp.asarray(tables.boxes, jnp.float32)
    d_box = _box_distance(boxes, eye)
    k = min(NEAREST, boxes.shape[0])
    neg, groups = lax.top_k(-d_box, min(k + 1, boxes.shape[0]))
    rest = -neg[k] if boxes.shape[0] > k else jnp.float32(jnp.inf)
    rows = groups[:k, None] * GROUP + jnp.arange(GROUP)[None, :]
    rows = jnp.minimum(rows, tables.num_triangles - 1).reshape(-1)
    tri = lax.bitcast_convert_type(jnp.asarray(bvh.table)[bvh.num_nodes + rows, :9], jnp.float32)
    tri = tri.reshape(-1, 3, 3)
    box = jnp.stack([tri.min(axis=1), tri.max(axis=1)], axis=1)
    n = jnp.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = jnp.sqrt(jnp.sum(n * n, axis=-1))
    plane = jnp.where(
        length > 0, jnp.abs(jnp.sum((eye - tri[:, 0]) * n, axis=-1)) / jnp.where(length > 0, length, 1.0), 0.0
    )
    per_triangle = jnp.maximum(_box_distance(box, eye), plane)
    return jnp.minimum(jnp.min(per_triangle), rest)


def region_levels(foveation, tables: LODTables, bvh, cameras):
    """(3,) int32: the level of each region (fovea, periphery, outside); traced (gaze, head pose
    and thresholds move it without a recompile). See the module docstring for "auto"."""
    from ..scene import select_lod

    fixed = [0 if f.lod in (None, "auto") else int(f.lod) for f in foveation.fidelity]
    levels = jnp.asarray(fixed, jnp.int32)
    auto = np.array([f.lod == "auto" for f in foveation.fidelity])
    if not auto.any():
        return levels
    # One bound for both eyes: from their midpoint, less the farthest eye's offset from it
    # (triangle inequality), half the work of one bound per eye.
    eyes = jnp.stack([jnp.asarray(c.position, jnp.float32) for c in cameras])
    mid = jnp.mean(eyes, axis=0)
    spread = jnp.max(jnp.sqrt(jnp.sum((eyes - mid) ** 2, axis=-1)))
    distance = jnp.maximum(nearest_distance(tables, bvh, mid) - spread, 0.0)
    inner = jnp.stack(
        [
            jnp.float32(0.0),
            jnp.asarray(foveation.fovea_deg, jnp.float32),
            jnp.asarray(foveation.periphery_deg, jnp.float32),
        ]
    )
    chosen = select_lod(tables.errors, inner, distance, foveation.acuity, tables.pixels_per_degree)
    return jnp.where(jnp.asarray(auto), chosen, levels)


def with_levels(classes, foveation, config, tables: LODTables, bvh, cameras):
    """The renderer's `ShadingClasses` with each region's level (full shading where `classes`
    is None)."""
    from ..render.internal import SHADOWS_ALL, ShadingClasses

    if classes is None:
        classes = ShadingClasses(np.full(3, config.max_depth, np.int32), np.full(3, SHADOWS_ALL, np.int32))
    return classes._replace(level=region_levels(foveation, tables, bvh, cameras))
