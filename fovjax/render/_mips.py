"""Texture level of detail : box-filtered mip pyramids and lookups at a mip level.

A texture of H x W texels has levels l = 0 .. L-1 of max(1, H >> l) x max(1, W >> l) texels
(L: down to 1 x 1). Level l is the box filter of level 0 over the UV footprint of each of its
texels: level-0 texel (row, col), centred on ((col + 0.5) / W, (row + 0.5) / H), belongs to the
level-l texel whose cell holds that centre, and a level-l texel is the mean of the level-0
texels that belong to it (for power-of-two sizes: the mean of 2^l x 2^l texels, the classic 2x2
box pyramid). Computed once per texture on the host (`with_texture_mips`, cached), outside the
frame; all levels are concatenated in one (N, 3) array per texture, so a lookup at a traced level
is a fixed number of gathers (static shapes) whatever the level.

Ray-cone level of detail (Akenine-Möller et al., "Texture Level of Detail Strategies for
Real-Time Ray Tracing", Ray Tracing Gems, ch. 20, 2019, the ray-cone section; the same as
Falcor's `computeRayConeTriangleLODValue` / `RayCone.computeLOD`): a ray whose
cone spreads by the angle α hits a triangle at distance t with a cone of width W = α·t; its
level is

    λ = Δ + log2(W / |n·d|),   Δ = ½·log2(t_a / p_a),

with t_a = W_tex·H_tex·|(t1 - t0) × (t2 - t0)| the triangle's area in texels, p_a =
|(p1 - p0) × (p2 - p0)| its area in the world, n the geometric normal and d the ray direction:
one texel per footprint. `lod_uv` is λ without the texture's size (½·log2(W_tex·H_tex), added
per texture in `mip_level`). For a pinhole camera a pixel's spread is α = atan(2·tan(fov_y / 2) /
H) (the same chapter).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ._vec import cross, dot, norm


def mip_shapes(h: int, w: int) -> tuple[tuple[int, int], ...]:
    """(rows, cols) of each level of an h x w texture's pyramid, down to 1 x 1."""
    shapes, level = [], 0
    while True:
        shapes.append((max(1, h >> level), max(1, w >> level)))
        if shapes[-1] == (1, 1):
            return tuple(shapes)
        level += 1


def _box_axis(x: np.ndarray, n: int, axis: int) -> np.ndarray:
    """Box-filter `x` along `axis` down to n cells: each source cell into the target cell that
    holds its centre, the mean of those."""
    size = x.shape[axis]
    target = np.floor((np.arange(size) + 0.5) * n / size).astype(np.int64)
    summed = np.zeros(x.shape[:axis] + (n,) + x.shape[axis + 1 :], np.float64)
    # numpy's stubs reject a tuple of slices and an index array, which np.add.at takes.
    np.add.at(summed, (slice(None),) * axis + (target,), x)  # pyright: ignore[reportArgumentType]
    count = np.bincount(target, minlength=n).reshape((1,) * axis + (n,) + (1,) * (x.ndim - axis - 1))
    return summed / count


def texture_mips(texture) -> np.ndarray:
    """The box-filtered mip pyramid of an (H, W, 3) texture, every level's texels row by row,
    level after level: (N, 3) float32 (level 0 first, equal to the texture)."""
    t = np.asarray(texture, np.float64)
    levels = [np.asarray(texture, np.float32).reshape(-1, 3)]
    for h, w in mip_shapes(t.shape[0], t.shape[1])[1:]:
        levels.append(_box_axis(_box_axis(t, h, 0), w, 1).astype(np.float32).reshape(-1, 3))
    return np.concatenate(levels)


_CACHE: dict = {}


def _cached_mips(texture) -> np.ndarray:
    key = id(texture)
    hit = _CACHE.get(key)
    if hit is not None and hit[0] is texture:
        return hit[1]
    mips = texture_mips(texture)
    if len(_CACHE) >= 32:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = (texture, mips)  # the texture is held so that its id stays its own
    return mips


def with_texture_mips(arrays):
    """`arrays` (`SceneArrays`) with `texture_mips`, the mip pyramid of each texture
    (`texture_mips`), computed on the host once per texture object (cached) and never inside a
    frame. Needed by `ShadingClasses` with texture levels; unchanged if already there."""
    if arrays.texture_mips is not None or not arrays.textures:
        return arrays
    return dataclasses.replace(arrays, texture_mips=tuple(_cached_mips(t) for t in arrays.textures))


def lod_uv(scene, prim, t, d, geometric_normal, cone):
    """λ of each hit without the texture's size term (see the module docstring): ½·log2 of the
    triangle's UV area over its world area, plus log2(cone·t / |n·d|). Not differentiated."""
    face = scene.faces[prim]
    p = scene.vertices[face]
    uv = scene.uvs[face]
    e1, e2 = uv[..., 1, :] - uv[..., 0, :], uv[..., 2, :] - uv[..., 0, :]
    uv_area = jnp.abs(e1[..., 0] * e2[..., 1] - e2[..., 0] * e1[..., 1])
    world_area = norm(cross(p[..., 1, :] - p[..., 0, :], p[..., 2, :] - p[..., 0, :]))
    width = cone * t / jnp.abs(dot(geometric_normal, d))
    return jax.lax.stop_gradient(0.5 * jnp.log2(uv_area / world_area) + jnp.log2(width))


def mip_level(shape, fixed, auto, lam_uv):
    """The (continuous) level of a texture of `shape` (H, W, 3): `fixed` plus, where `auto`,
    the ray cone's λ (`lam_uv` + ½·log2(H·W), at least 0). Clamped to the pyramid; 0 where not
    finite (a degenerate triangle)."""
    h, w = shape[0], shape[1]
    top = len(mip_shapes(h, w)) - 1
    cone = jnp.maximum(lam_uv + 0.5 * float(np.log2(h * w)), 0.0)
    level = fixed + jnp.where(auto, cone, 0.0)
    level = jnp.where(jnp.isnan(level), 0.0, level)
    return jnp.clip(level, 0.0, float(top))


@functools.lru_cache(maxsize=64)
def _level_table(h: int, w: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    shapes = np.asarray(mip_shapes(h, w), np.int32)
    sizes = shapes[:, 0] * shapes[:, 1]
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int32)
    return offsets, shapes[:, 0], shapes[:, 1]


def _wrap(x, n):
    """floor-valued float `x` modulo the traced int `n`, as an index in [0, n): the integers of
    `jnp.mod(x.astype(int32), n)` (exact for |x| well below 2^24), through a float division,
    which vectorises where an integer remainder by a traced divisor does not."""
    nf = n.astype(jnp.float32)
    return jnp.clip((x - nf * jnp.floor(x / nf)).astype(jnp.int32), 0, n - 1)


def _bilinear_level(mips, offset, h, w, uv):
    """Bilinear lookup with wrapping in the level stored at `offset` of `mips` (h x w texels,
    traced per ray): the arithmetic of `bilinear_wrap`, on the flat pyramid."""
    uv = jnp.where(jnp.isfinite(uv), uv, 0.0)
    x = uv[..., 0] * w.astype(jnp.float32) - 0.5
    y = uv[..., 1] * h.astype(jnp.float32) - 0.5
    x0 = jnp.floor(x)
    y0 = jnp.floor(y)
    fx = (x - x0)[..., None]
    fy = (y - y0)[..., None]
    i0 = _wrap(x0, w)
    j0 = _wrap(y0, h)
    i1 = jnp.where(i0 + 1 >= w, 0, i0 + 1)
    j1 = jnp.where(j0 + 1 >= h, 0, j0 + 1)

    def at(j, i):
        return mips[offset + j * w + i]

    row0 = at(j0, i0) * (1 - fx) + at(j0, i1) * fx
    row1 = at(j1, i0) * (1 - fx) + at(j1, i1) * fx
    return row0 * (1 - fy) + row1 * fy


def mip_lookup(mips, shape, level, uv):
    """Trilinear lookup of a texture of `shape` in its pyramid `mips` at the continuous `level`
    (per ray, within the pyramid): bilinear in the two levels around it, blended linearly. At a
    whole level it is that level's bilinear lookup."""
    offsets, rows, cols = (jnp.asarray(a) for a in _level_table(int(shape[0]), int(shape[1])))
    top = rows.shape[0] - 1
    l0 = jnp.floor(level).astype(jnp.int32)
    l1 = jnp.minimum(l0 + 1, top)
    f = (level - l0.astype(jnp.float32))[..., None]
    c0 = _bilinear_level(mips, offsets[l0], rows[l0], cols[l0], uv)
    c1 = _bilinear_level(mips, offsets[l1], rows[l1], cols[l1], uv)
    return c0 * (1 - f) + c1 * f


def pixel_spread_angle(vfov_deg, height: int):
    """α = atan(2·tan(fov_y / 2) / H): the spread angle of one pixel's ray cone (Ray Tracing Gems ch. 20)."""
    half = jnp.deg2rad(jnp.asarray(vfov_deg, jnp.float32)) / 2
    return jnp.arctan(2 * jnp.tan(half) / height)
