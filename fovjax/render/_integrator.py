"""The Whitted integrator: closest hit, Blinn–Phong (or Phong) with shadow rays, mirror reflections.

One depth level at a time, for every ray at once (the thesis's closest-hit program, section
4.4.3, iterated to a static maximum depth instead of recursing):

1. trace the level's rays (`closest_hit`; rays that are not alive get tmax = tmin and cost
   nothing in the traversal);
2. misses add weight × environment(direction) (the miss program, section 4.4.4);
3. hits add weight × (Ka·ambient + Ke + Σ_lights visible · (Kd·(n·l) + Ks·(n·h)^Ns) · light),
   where a shadow ray (any hit, `occluded`) is traced only where n·l > 0, and h = normalize(l − d)
   is the Blinn–Phong halfway vector (`RenderConfig.specular` "phong": (r·v)^Ns, eq. 1;
   `specular_payload`: the specular term times n·l too, §4.4.3's payload); point lights have
   infinite range and no falloff (the thesis's light), directional lights shine along
   −position, spot lights are point lights times their cone's factor (no shadow ray outside
   the cone);
4. where depth < max_depth and the hit material's Kr is not zero, a reflection ray continues
   with weight × Kr (`RenderConfig.min_contribution`: only while the luminance of that weight
   is at least the cut-off, §2.5.2).

Depth 0 runs band by band (rows of the image, so that packets keep their neighbouring
pixels): XLA:CPU materialises every intermediate of the shading, and a band's stay in cache.
Each band's reflection rays are compacted (O(band)) and appended to a queue; levels
1..max_depth read one queue and append to another, chunk by chunk, skipping chunks with no
rays (a `lax.cond` per chunk): static shapes, a cost that follows the rays actually spawned
rather than the screen, and a program whose size does not grow with max_depth (the levels are
a `lax.scan`). Every loop is a `lax.scan`, so `jax.grad` goes through.

Kd is multiplied by the material's diffuse texture (bilinear, wrapping) where it has one. The
shading normal n is the interpolated vertex normal where the mesh has them, else the face
normal; both are flipped to the side the ray came from (the side of the geometric normal, as
OptiX's faceforward). A light counts only when it is above both the shading and the geometric
surface (otherwise a smooth normal would let light through the back of a closed mesh).
Secondary rays start `config.ray_offset × scene size` off the surface along the geometric
normal. A sample whose radiance is NaN or inf becomes `config.bad_color` and is counted.

Gradients: the traversal is not differentiated; hit distances and barycentrics are recomputed
from the vertices (`hit_geometry`), so `jax.grad` reaches material colours, lights, the
environment map, vertex positions and the rays (camera pose) through shading; which triangle a
ray hits and whether a shadow ray is blocked (visibility) are taken as given.
"""

from __future__ import annotations

from typing import NamedTuple, cast

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ..native.internal import jvp_of, on_platforms
from ..scene import POINT_LIGHT, SPOT_LIGHT
from ..trace import BVH, Hit, closest_hit, occluded
from ..trace.internal import backend_geometry, lowering_platform
from ._arrays import SceneArrays, light_columns
from ._config import DEFAULT_CONFIG, LUMINANCE, RenderConfig
from ._envmap import envmap_lookup
from ._mips import lod_uv, mip_level, mip_lookup
from ._native import (
    SHADING_FIELDS,
    integrator_options,
    integrator_plan,
    native_shading_adjoint,
    native_whitted,
    shading_attributes,
    warp_integrator_plan,
    whitted_operands,
)
from ._replay import StoredPaths, replay_radiance, shading_tangent, split_tangents
from ._vec import all3, any3, cross, dot, interpolate, norm, normalize
from ._warp_whitted import warp_integrate


class RayCounts(NamedTuple):
    """Rays actually traced (queued for traversal), by kind, and samples that went bad
    (radiance NaN or inf, replaced by the bad colour). int32 scalars."""

    primary: Int[Array, ""]
    shadow: Int[Array, ""]
    reflection: Int[Array, ""]
    bad: Int[Array, ""]

    @property
    def total(self) -> Int[Array, ""]:
        """Every ray traced: primary, shadow and reflection."""
        return self.primary + self.shadow + self.reflection


# Shadow modes of `ShadingClasses.shadows`.
SHADOWS_ALL = 0  # a shadow ray to every light
SHADOWS_BRIGHTEST = 1  # only to the brightest light (largest R + G + B of its colour; ties: the first)
SHADOWS_NONE = 2  # none: every light shines unshadowed


class ShadingClasses(NamedTuple):
    """Shading fidelity per class of rays, for `radiance_in_chunks`: class k's rays spawn
    reflections only up to depth `max_depth[k]` (never beyond `config.max_depth`), and trace
    shadow rays per `shadows[k]` (`SHADOWS_ALL`, `SHADOWS_BRIGHTEST`, `SHADOWS_NONE`). A light
    whose shadow ray is not traced still lights the point, unshadowed (as if visible): dropping
    a shadow ray drops the occlusion test, not the light, so the level of detail keeps the
    energy and only loses the shadow. A reflection ray inherits the class of its sample.
    int32 arrays (K,); traced values, so new tables recompile nothing.

    `level` (geometry level of detail): None (every ray against the BVH's one tree), or the tree
    of a merged BVH (`fovjax.trace.merge_bvhs`; the scene arrays concatenated the same way) each
    class's rays, their shadow rays and their reflections are traced against; shading then
    reads that level's triangles, normals, UVs and materials (the hit's `prim` indexes them).

    Texture level of detail (None: every lookup bilinear at full resolution): class k's
    diffuse-texture lookups are trilinear in the scene's mip pyramids (`with_texture_mips`) at
    level `texture_level[k]`, plus, where `texture_cone[k]` > 0, the level of a ray cone of that
    spread angle (radians; `fovjax.render._mips`: λ = ½·log2(t_a / p_a) + log2(α·t / |n·d|),
    Akenine-Möller et al., Ray Tracing Gems ch. 20), at least 0. A reflection ray's cone is
    counted from its mirror (a lower bound of the cone's width: a finer level, never coarser).
    float32 arrays (K,)."""

    max_depth: Int[np.ndarray | Array, " K"]
    shadows: Int[np.ndarray | Array, " K"]
    level: Int[np.ndarray | Array, " K"] | None = None
    # ---- texture level of detail ----
    texture_level: Float[np.ndarray | Array, " K"] | None = None
    texture_cone: Float[np.ndarray | Array, " K"] | None = None
    # ---- end texture level of detail ----


def _tested_lights(scene, classes: ShadingClasses, cls):
    """Which lights each ray's class traces a shadow ray to: (lights, *batch) bool."""
    mode = jnp.asarray(classes.shadows, jnp.int32)[cls][None]
    index = jnp.arange(scene.num_lights).reshape((scene.num_lights,) + (1,) * cls.ndim)
    brightest = jnp.argmax(jnp.sum(jnp.asarray(scene.light_color, jnp.float32), axis=-1))
    return (mode == SHADOWS_ALL) | ((mode == SHADOWS_BRIGHTEST) & (index == brightest))


class Radiance(NamedTuple):
    """`radiance`'s result: linear RGB per sample (bad samples already `bad_color`, inactive
    ones 0), which samples were bad, and the ray counts."""

    rgb: Float[Array, "*batch 3"]
    bad: Bool[Array, "*batch"]
    counts: RayCounts


def bilinear_wrap(texture: Float[Array, "Ht Wt 3"], uv: Float[Array, "*batch 2"]) -> Float[Array, "*batch 3"]:
    """Bilinear texture lookup with wrapping in both directions. Row 0 of `texture` is v = 0
    and texel [row, col] is centred on ((col + 0.5) / Wt, (row + 0.5) / Ht) (see `fovjax.Scene`)."""
    h, w = texture.shape[0], texture.shape[1]
    uv = jnp.where(jnp.isfinite(uv), uv, 0.0)
    x = uv[..., 0] * w - 0.5
    y = uv[..., 1] * h - 0.5
    x0 = jnp.floor(x)
    y0 = jnp.floor(y)
    fx = (x - x0)[..., None]
    fy = (y - y0)[..., None]
    i0 = jnp.mod(x0.astype(jnp.int32), w)
    j0 = jnp.mod(y0.astype(jnp.int32), h)
    i1 = jnp.mod(i0 + 1, w)
    j1 = jnp.mod(j0 + 1, h)
    row0 = texture[j0, i0] * (1 - fx) + texture[j0, i1] * fx
    row1 = texture[j1, i0] * (1 - fx) + texture[j1, i1] * fx
    return row0 * (1 - fy) + row1 * fy


class Surface(NamedTuple):
    """What a ray hit: `found`, the point, the geometric and shading normals (unit, facing the
    incoming ray), the material index and the texture coordinates."""

    found: Bool[Array, "*batch"]
    point: Float[Array, "*batch 3"]
    geometric_normal: Float[Array, "*batch 3"]
    shading_normal: Float[Array, "*batch 3"]
    material: Int[Array, "*batch"]
    uv: Float[Array, "*batch 2"]


def surface_at(scene: SceneArrays, hit: Hit, directions: Float[Array, "*batch 3"]) -> Surface:
    """The surface at each hit (anything, but finite, on a miss)."""
    found = hit.prim >= 0
    prim = jnp.maximum(hit.prim, 0)
    face = scene.faces[prim]
    b = jnp.stack([1.0 - hit.u - hit.v, hit.u, hit.v], axis=-1)
    corners = scene.vertices[face]  # (..., 3, 3)
    point = interpolate(b, corners)
    n_geo = normalize(cross(corners[..., 1, :] - corners[..., 0, :], corners[..., 2, :] - corners[..., 0, :]))
    sign = jnp.where(dot(n_geo, directions) > 0, -1.0, 1.0)[..., None]
    n_geo = n_geo * sign
    if scene.normals is None:
        n_shade = n_geo
    else:
        n_interp = normalize(interpolate(b, scene.normals[face]))
        degenerate = all3(n_interp == 0)[..., None]
        n_shade = jnp.where(degenerate, n_geo, n_interp * sign)
    if scene.uvs is None:
        uv = jnp.zeros(found.shape + (2,), jnp.float32)
    else:
        uv = interpolate(b, scene.uvs[face])
    return Surface(found, point, n_geo, n_shade, scene.face_material[prim], uv)


def diffuse_color(scene: SceneArrays, material, uv, lod=None):
    """Kd, times the material's texture at `uv` where it has one. `lod` (texture level of
    detail): None (level 0, bilinear), or (fixed level, auto, λ without the texture size) per
    ray, looked up trilinearly in `scene.texture_mips` (see `ShadingClasses`)."""
    kd = scene.kd[material]
    if not scene.textures:
        return kd
    index = scene.texture[material]
    factor = jnp.ones_like(kd)
    for i, texture in enumerate(scene.textures):
        if lod is None:
            value = bilinear_wrap(jnp.asarray(texture, jnp.float32), uv)
        else:  # a level of detail per ray
            if scene.texture_mips is None:
                raise ValueError("a texture level of detail needs the scene's mips (with_texture_mips)")
            level = mip_level(np.shape(texture), *lod)
            value = mip_lookup(jnp.asarray(scene.texture_mips[i], jnp.float32), np.shape(texture), level, uv)
        factor = jnp.where((index == i)[..., None], value, factor)
    return kd * factor


def scene_scale(scene: SceneArrays):
    """The length `RenderConfig.ray_offset` is relative to: the larger of the bounding-box
    diagonal and the largest absolute coordinate (float32 rounding grows with both)."""
    v = jax.lax.stop_gradient(jnp.asarray(scene.vertices, jnp.float32))
    # Per coordinate, as whole-column reductions (XLA:CPU's kernel for a reduction over the
    # vertex axis of (V, 3) is slower); the largest |coordinate| is that of the box's corners:
    # the same values.
    lo = jnp.stack([jnp.min(v[:, i]) for i in range(3)])
    hi = jnp.stack([jnp.max(v[:, i]) for i in range(3)])
    return jnp.maximum(norm(hi - lo), jnp.maximum(jnp.max(jnp.abs(lo)), jnp.max(jnp.abs(hi))))


def _usable_packet(packet, batch_ndim: int):
    if isinstance(packet, tuple) and batch_ndim < 2:
        return None
    return packet


class Shading(NamedTuple):
    """The shading options of a `RenderConfig` (static): `specular` ("blinn-phong" or "phong"),
    `payload` (`specular_payload`) and `min_contribution`."""

    specular: str = "blinn-phong"
    payload: bool = False
    min_contribution: float = 0.0


DEFAULT_SHADING = Shading()


def shading_of(config: RenderConfig) -> Shading:
    """`config`'s shading options."""
    return Shading(config.specular, config.specular_payload, config.min_contribution)


class ShadowRays(NamedTuple):
    """The shadow rays of a batch of surface points, one per light: (lights, *batch)."""

    origin: jax.Array  # (lights, *batch, 3)
    direction: jax.Array  # (lights, *batch, 3), unit
    tmax: jax.Array  # (lights, *batch); 0 where no ray is wanted
    wanted: jax.Array  # (lights, *batch) bool
    n_dot_l: jax.Array  # (lights, *batch)
    spot: jax.Array  # (lights, *batch): a spot light's cone factor, 1 for the other kinds


def spot_factor(axis, l_dir, cos_inner, cos_outer):
    """How much of a spot light reaches a point whose direction towards the light is `l_dir`:
    1 within the inner half-angle of its unit `axis`, 0 beyond the outer, linear in the cosine
    of the angle between (`fovjax.Lights`)."""
    c = -dot(axis, l_dir)
    width = cos_inner - cos_outer
    ramp = (c - cos_outer) / jnp.where(width > 0, width, 1.0)
    return jnp.where(c >= cos_inner, 1.0, jnp.where(c > cos_outer, ramp, 0.0))


def _shadow_rays(scene, surface, lit, offset) -> ShadowRays:
    """Towards every light, from every lit surface point where the light is above both normals
    (and, for a spot light, within its cone)."""
    batch = surface.found.shape
    lead = (scene.num_lights,) + (1,) * len(batch)
    position = jnp.reshape(scene.light_position, lead + (3,))
    kind = jnp.reshape(scene.light_kind, lead)
    positional = (kind == POINT_LIGHT) | (kind == SPOT_LIGHT)
    p, n_geo, n = surface.point[None], surface.geometric_normal[None], surface.shading_normal[None]
    to_light = jnp.where(positional[..., None], position - p, position)
    distance = norm(to_light)
    l_dir = normalize(to_light)
    n_dot_l = dot(n, l_dir)
    if scene.light_direction is None and scene.light_cone is None:  # no spot light
        spot = jnp.ones(n_dot_l.shape, jnp.float32)
    else:
        axis, cone = light_columns(scene)
        cone = jnp.reshape(cone, lead + (2,))
        spot = spot_factor(jnp.reshape(axis, lead + (3,)), l_dir, cone[..., 0], cone[..., 1])
        spot = jnp.where(kind == SPOT_LIGHT, spot, 1.0)
    wanted = lit[None] & (n_dot_l > 0) & (dot(n_geo, l_dir) > 0) & (spot > 0)
    origin = jnp.broadcast_to(p + offset * n_geo, wanted.shape + (3,))
    tmax = jnp.where(positional, distance, jnp.inf)
    return ShadowRays(
        origin,
        jnp.broadcast_to(l_dir, origin.shape),
        jnp.where(wanted, tmax, 0.0),
        wanted,
        n_dot_l,
        jnp.broadcast_to(spot, wanted.shape),
    )


def _trace_shadows(bvh, rays: ShadowRays, packet, backend, level=None):
    """Which shadow rays are blocked. Visibility is not differentiated: tangents stay out of
    the traversal's while loop."""
    return occluded(
        bvh,
        jax.lax.stop_gradient(rays.origin),
        jax.lax.stop_gradient(rays.direction),
        jax.lax.stop_gradient(rays.tmax),
        tmin=0.0,
        packet=_usable_packet(packet, rays.wanted.ndim),
        backend=backend,
        level=level,
    )


def _light_sum(scene, surface, d, rays: ShadowRays, blocked, kd, ks, ns, shading: Shading = DEFAULT_SHADING):
    """Σ over lights of visible · (Kd·(n·l) + Ks·(n·h)^Ns) · colour · spot (`shading`: Phong's
    (r·v)^Ns for (n·h)^Ns, the specular times n·l too)."""
    batch = surface.found.shape
    color = jnp.reshape(scene.light_color, (scene.num_lights,) + (1,) * len(batch) + (3,))
    color = color * rays.spot[..., None]
    n = surface.shading_normal[None]
    visible = rays.wanted & ~blocked
    n_dot_l = jnp.where(rays.wanted, rays.n_dot_l, 0.0)
    if shading.specular == "phong":  # eq. 1: r the light's direction mirrored about n, v = -d
        mirrored = 2.0 * rays.n_dot_l[..., None] * n - rays.direction
        cosine = -dot(mirrored, d[None])
    else:
        cosine = dot(n, normalize(rays.direction - d[None]))
    # (n·h)^Ns as 2^(Ns·log2(n·h)): XLA:CPU's general `pow` is an order of magnitude slower
    # over a frame's hits; the two agree to float rounding of the exponent.
    safe = jnp.where(cosine > 0, cosine, 1.0)
    specular = jnp.where(cosine > 0, jnp.exp2(ns[None] * jnp.log2(safe)), 0.0)
    if shading.payload:  # §4.4.3: the specular times the shadow ray's payload, n·l
        specular = specular * n_dot_l
    contribution = (kd[None] * n_dot_l[..., None] + ks[None] * specular[..., None]) * color
    lit_terms = jnp.where(visible[..., None], contribution, 0.0)
    shaded = lit_terms[0]
    for i in range(1, scene.num_lights):
        shaded = shaded + lit_terms[i]
    return shaded


def _trace_primary(scene, bvh, o, d, alive, *, packet, backend, level=None, hits="recomputed") -> Hit:
    """Closest hits; t, u, v as `RenderConfig.hits` says, derivatives through `scene.vertices`
    either way."""
    tmax = jnp.where(alive, jnp.inf, 0.0)
    if hits == "recomputed":
        vertices = scene.vertices
        return closest_hit(
            bvh, o, d, 0.0, tmax, packet=packet, vertices=vertices, backend=backend, level=level
        )
    hit = closest_hit(bvh, o, d, 0.0, tmax, packet=packet, backend=backend, level=level)
    t, u, v = backend_geometry(scene.vertices, bvh.faces, hit.prim, o, d, hit.t, hit.u, hit.v)
    return Hit(t, hit.prim, u, v)


def _surface_and_shadow_rays(scene, hit, d, alive, offset):
    """The surfaces the rays hit and the shadow rays they need (None without lights)."""
    surface = surface_at(scene, hit, d)
    lit = alive & surface.found
    rays = _shadow_rays(scene, surface, lit, offset) if scene.num_lights else None
    return surface, rays


def _finish_shading(
    scene,
    surface,
    d,
    alive,
    weight,
    rays,
    blocked,
    *,
    offset,
    spawn,
    lod=None,
    shading: Shading = DEFAULT_SHADING,
):
    """What the rays see (weighted) given the shadow rays' visibility, and the reflection rays
    they spawn where `spawn` (and, with `shading.min_contribution`, where the luminance of
    their weight reaches it): (contribution, (o, d, weight, alive) of the next level)."""
    lit = alive & surface.found
    missed = alive & ~surface.found
    m = surface.material
    local = scene.ka[m] * jnp.asarray(scene.ambient, jnp.float32) + scene.ke[m]
    if rays is not None:
        kd = diffuse_color(scene, m, surface.uv, lod)
        local = local + _light_sum(scene, surface, d, rays, blocked, kd, scene.ks[m], scene.ns[m], shading)
    contribution = jnp.where(missed[..., None], weight * envmap_lookup(scene.environment, d), 0.0)
    contribution = contribution + jnp.where(lit[..., None], weight * local, 0.0)

    weight = weight * scene.kr[m]
    alive = lit & any3(weight != 0) & spawn
    if shading.min_contribution > 0:  # §2.5.2's contribution cut-off
        r, g, b = LUMINANCE
        luminance = r * weight[..., 0] + g * weight[..., 1] + b * weight[..., 2]
        alive = alive & (luminance >= shading.min_contribution)
    n_s, n_g = surface.shading_normal, surface.geometric_normal
    reflected = d - 2.0 * dot(d, n_s)[..., None] * n_s
    # A smooth normal can send the mirror direction into the surface: mirror about the
    # geometric normal there instead.
    into = dot(reflected, n_g) <= 0
    reflected = jnp.where(into[..., None], d - 2.0 * dot(d, n_g)[..., None] * n_g, reflected)
    return contribution, (surface.point + offset * n_g, normalize(reflected), weight, alive)


def _trace_and_shade(
    scene,
    bvh,
    o,
    d,
    alive,
    weight,
    *,
    packet,
    offset,
    backend,
    spawn,
    fidelity=None,
    hits="recomputed",
    shading: Shading = DEFAULT_SHADING,
):
    """One depth level: trace `alive` rays (unit directions `d`), add what they see (weighted),
    and the reflection rays they spawn where `spawn`. `fidelity`: None, or (ShadingClasses,
    class per ray, this level's depth) limiting reflections and shadow rays per ray. Returns
    (contribution, (o, d, weight, alive) of the next level, shadow rays traced)."""
    level = None
    if fidelity is not None:
        classes, cls, depth = fidelity
        spawn = spawn & (depth < jnp.asarray(classes.max_depth, jnp.int32)[cls])
        if classes.level is not None:
            level = jnp.asarray(classes.level, jnp.int32)[cls]
    hit = _trace_primary(scene, bvh, o, d, alive, packet=packet, backend=backend, level=level, hits=hits)
    surface, rays = _surface_and_shadow_rays(scene, hit, d, alive, offset)
    blocked, n_shadow = None, jnp.int32(0)
    if rays is not None:
        traced = rays
        if fidelity is not None:  # untested lights: no ray (tmax 0), never blocked
            tested = _tested_lights(scene, classes, cls)
            traced = rays._replace(tmax=jnp.where(tested, rays.tmax, 0.0), wanted=rays.wanted & tested)
        blocked = _trace_shadows(bvh, traced, packet, backend, None if level is None else level[None])
        if fidelity is not None:
            blocked = blocked & tested
        n_shadow = jnp.sum(traced.wanted, dtype=jnp.int32)
    lod = None
    if fidelity is not None and classes.texture_level is not None and scene.textures:
        lod = _texture_lod(scene, classes, cls, hit, d, surface)
    contribution, nxt = _finish_shading(
        scene, surface, d, alive, weight, rays, blocked, offset=offset, spawn=spawn, lod=lod, shading=shading
    )
    return contribution, nxt, n_shadow


def _texture_lod(scene, classes: ShadingClasses, cls, hit, d, surface):
    """Each ray's texture level of detail from its class: (fixed level, auto, λ
    without the texture size), for `diffuse_color`."""
    if scene.texture_mips is None:
        raise ValueError("texture levels of detail need the scene's mip pyramids: with_texture_mips(arrays)")
    fixed = jnp.asarray(classes.texture_level, jnp.float32)[cls]
    cone = jnp.asarray(classes.texture_cone, jnp.float32)[cls]
    if scene.uvs is None:
        return fixed, jnp.zeros(fixed.shape, bool), jnp.zeros_like(fixed)  # no UVs: uv 0 everywhere
    prim = jnp.maximum(hit.prim, 0)
    lam = lod_uv(scene, prim, jnp.where(hit.prim >= 0, hit.t, 1.0), d, surface.geometric_normal, cone)
    return fixed, cone > 0, lam


def _live_first(alive):
    """(number alive, a stable permutation that puts the alive entries first). O(n)."""
    live = alive.astype(jnp.int32)
    n_live = jnp.sum(live)
    index = jnp.arange(live.shape[0], dtype=jnp.int32)
    before = jnp.cumsum(live)  # live entries up to each, itself included
    rank = jnp.where(alive, before - 1, n_live + index - before)
    return n_live, jnp.zeros_like(rank).at[rank].set(index, unique_indices=True)


def _reflection_level(scene, bvh, total, source, n_queued, queue, depth, *, offset, config, size):
    """One reflection level over the first `n_queued` rays of `source`: each chunk of `size`
    that holds any is traced and shaded (a `lax.cond` skips the rest, so the level costs what
    its rays do, not the screen), its contribution added to its pixels and its reflection rays
    compacted (O(chunk)) and appended to `queue`. Returns (total, queue, rays queued, shadow
    rays traced)."""
    lanes = jnp.arange(size, dtype=jnp.int32)
    spawn = depth < config.max_depth

    def chunk(inner, c):
        first = c * size

        def work(inner):
            total, queue, n_next, n_shadow = inner
            o, d, weight, pixel = (jax.lax.dynamic_slice_in_dim(q, first, size) for q in source)
            contribution, (o2, d2, w2, alive2), traced = _trace_and_shade(
                scene,
                bvh,
                o,
                d,
                first + lanes < n_queued,
                weight,
                packet=None,
                offset=offset,
                backend=config.backend,
                hits=config.hits,
                shading=shading_of(config),
                spawn=spawn,
            )
            total = total.at[pixel].add(contribution)
            queue, n_next = _append(queue, n_next, (o2, d2, w2, pixel), alive2)
            return total, queue, n_next, n_shadow + traced

        return jax.lax.cond(first < n_queued, work, lambda inner: inner, inner), None

    count = source[0].shape[0] // size - 1
    zero = jnp.int32(0)
    (total, queue, n_next, n_shadow), _ = jax.lax.scan(chunk, (total, queue, zero, zero), jnp.arange(count))
    return total, queue, n_next, n_shadow


def _bands(batch: tuple[int, ...], config) -> tuple[tuple[int, ...], int]:
    """How depth 0 splits a batch of rays: (one band's shape, number of bands). An image (a
    tile packet and two or more axes) goes in bands of whole rows, a multiple of the packet's
    height where it fits, so that packets keep their neighbouring pixels; other batches in
    flat chunks. A band holds about `config.chunk_size` rays."""
    n = int(np.prod(batch))
    if isinstance(config.packet, tuple) and len(batch) >= 2:
        rows, width = n // batch[-1], batch[-1]
        r = min(max(1, config.chunk_size // width), rows)
        step = config.packet[0] if r >= config.packet[0] else 1
        r -= r % step
        # A band height that divides the rows (down to half the target) needs no padding, so
        # the rays are bands without a copy.
        whole = [q for q in range(r, max(step, r // 2) - 1, -step) if rows % q == 0]
        r = whole[0] if whole else r
        return (r, width), -(-rows // r)
    size = min(config.chunk_size, n)
    return (size,), -(-n // size)


def _depth0(scene, bvh, o, d, active, *, offset, config):
    """Depth 0 band by band (`_bands`, a `lax.scan`): each band traced (packets as
    `config.packet`) and shaded, its reflection rays compacted (O(band)) and appended to a
    queue. Band by band because XLA:CPU materialises every intermediate of the shading: a
    band's stay in cache (`benchmarks/profile_frame.py` shows where a frame's time goes).
    Returns (total (bands x band, 3),
    queue (o, d, weight, pixel) with a band of room, rays queued, shadow rays traced, band
    size)."""
    batch = active.shape
    n = int(np.prod(batch))
    band, count = _bands(batch, config)
    size = int(np.prod(band))
    padded = count * size

    def split(x, fill):
        x = x.reshape((n,) + x.shape[len(batch) :])
        if padded > n:
            x = jnp.concatenate([x, jnp.full((padded - n,) + x.shape[1:], fill, x.dtype)])
        return x.reshape((count,) + band + x.shape[1:])

    lanes = jnp.arange(size, dtype=jnp.int32)
    spawn = config.max_depth > 0
    packet = _usable_packet(config.packet, len(band))

    def body(carry, xs):
        queue, n_q, n_shadow = carry
        o, d, alive, first = xs
        contribution, nxt, traced = _trace_and_shade(
            scene,
            bvh,
            o,
            d,
            alive,
            jnp.ones(band + (3,), jnp.float32),
            packet=packet,
            offset=offset,
            backend=config.backend,
            hits=config.hits,
            shading=shading_of(config),
            spawn=spawn,
        )
        if spawn:
            o2, d2, w2, alive2 = (x.reshape((size,) + x.shape[len(band) :]) for x in nxt)
            queue, n_q = _append(queue, n_q, (o2, d2, w2, first + lanes), alive2)
        return (queue, n_q, n_shadow + traced), contribution.reshape(size, 3)

    queue = _queue_of(padded + size if spawn else 0)  # `_append` writes a band whole
    xs = (split(o, 0.0), split(d, 1.0), split(active, False), jnp.arange(count, dtype=jnp.int32) * size)
    zero = jnp.int32(0)
    (queue, n_q, n_shadow), total = jax.lax.scan(body, (queue, zero, zero), xs)
    return total.reshape(padded, 3), queue, n_q, n_shadow, size


def _reflection_levels(scene, bvh, total, queue_a, n_a, *, offset, config, size):
    """Depth levels 1..max_depth over two queues of reflection rays, each level reading one and
    appending its rays to the other, chunk by chunk (`_reflection_level`): no level touches
    the whole screen. Pairs of levels are one `lax.scan` (the queues never swap places in its
    carry, which would copy them), the chunks `lax.scan`s of `lax.cond`s: the program does not
    grow with max_depth and `jax.grad` goes through. Returns (total, reflection rays, shadow
    rays)."""
    queue_b = tuple(jnp.zeros_like(q) for q in queue_a)
    kw = {"offset": offset, "config": config, "size": size}

    def two_levels(carry, depth):
        total, queue_a, n_a, queue_b = carry
        total, queue_b, n_b, shadow_1 = _reflection_level(
            scene, bvh, total, queue_a, n_a, queue_b, depth, **kw
        )
        n_b = jnp.where(depth < config.max_depth, n_b, 0)  # an odd max_depth: no last level
        total, queue_a, n_a2, shadow_2 = _reflection_level(
            scene, bvh, total, queue_b, n_b, queue_a, depth + 1, **kw
        )
        return (total, queue_a, n_a2, queue_b), (n_a + n_b, shadow_1 + shadow_2)

    (total, *_), (n_reflection, n_shadow) = jax.lax.scan(
        two_levels, (total, queue_a, n_a, queue_b), jnp.arange(1, config.max_depth + 1, 2)
    )
    return total, jnp.sum(n_reflection), jnp.sum(n_shadow)


def radiance(
    scene: SceneArrays,
    bvh: BVH,
    origins: Float[ArrayLike, "*batch 3"],
    directions: Float[ArrayLike, "*batch 3"],
    active: Bool[ArrayLike, "*batch"] | None = None,
    *,
    config: RenderConfig = DEFAULT_CONFIG,
) -> Radiance:
    """Whitted radiance along rays; only `active` rays (all when None) are traced and shaded.

    `origins`, `directions`: any batch shape (directions need not be unit length). Inactive rays
    cost nothing in the traversal, spawn no shadow or reflection rays, return 0 and are not
    counted. With `config.packet` a tile, the last two batch axes must be an image (the tile
    pads ragged edges). Pure and jittable; differentiable as the module docstring says.

    Depth 0 (the given rays) runs band by band, traced as `config.packet` (`_depth0`); the
    reflection levels run on a queue of the live rays (`_reflection_levels`).

    Returns `Radiance(rgb (*batch, 3), bad (*batch), counts)`.
    """
    scene = jax.tree.map(jnp.asarray, scene)  # host NumPy leaves cannot be indexed by traced rays
    origins = jnp.asarray(origins, jnp.float32)
    directions = jnp.asarray(directions, jnp.float32)
    batch = jnp.broadcast_shapes(origins.shape[:-1], directions.shape[:-1])
    o = jnp.broadcast_to(origins, batch + (3,))
    d = normalize(jnp.broadcast_to(directions, batch + (3,)))
    valid = all3(jnp.isfinite(o)) & all3(jnp.isfinite(directions)) & any3(d != 0)
    valid = jnp.broadcast_to(valid, batch)
    active = jnp.ones(batch, bool) if active is None else jnp.broadcast_to(jnp.asarray(active, bool), batch)
    offset = config.ray_offset * scene_scale(scene)

    total, n_shadow, n_reflection = _integrate(scene, bvh, o, d, active, offset, config)
    return _finish_radiance(total, active, valid, config, n_shadow, n_reflection)


def _jax_integrate(scene, bvh, o, d, active, offset, config):
    """The integrator in JAX: (radiance (*batch, 3), shadow rays, reflection rays)."""
    batch = active.shape
    total, queue, n_queued, n_shadow, size = _depth0(scene, bvh, o, d, active, offset=offset, config=config)
    n_reflection = jnp.int32(0)
    if config.max_depth > 0:
        total, n_reflection, more_shadow = _reflection_levels(
            scene, bvh, total, queue, n_queued, offset=offset, config=config, size=size
        )
        n_shadow = n_shadow + more_shadow
    return total[: int(np.prod(batch))].reshape(batch + (3,)), n_shadow, n_reflection


def native_integrator(config: RenderConfig) -> bool:
    """Whether `radiance` runs its primal in the native integrator on a CPU (`integrator_plan`):
    `config.integrator` "native", or "auto" with an Embree-capable ray backend ("auto" or
    "embree") where the native handlers are built. "native" where it cannot is an error naming
    why."""
    return integrator_plan(config).cpu


def describe_integrator(config: RenderConfig, platform: str) -> str:
    """One line naming the integrator `config` runs on `platform` and, where it is the JAX one
    on a CPU or an NVIDIA GPU, why."""
    if lowering_platform(platform) == "cuda":
        gpu = warp_integrator_plan(config)
        if gpu.cuda:
            return f"warp ({gpu.reason})"
        return f"jax ({gpu.reason})"
    if platform != "cpu":
        return f"jax (no native integrator for {platform})"
    try:
        plan = integrator_plan(config)
    except (ValueError, RuntimeError) as exc:
        return f"unavailable ({exc})"
    if plan.cpu:
        return "native (the Whitted loop in the native handlers; derivatives in JAX)"
    if config.integrator == "jax":
        return "jax (RenderConfig.integrator 'jax')"
    return f"jax ({plan.reason})"


def _tile_width(batch: tuple[int, ...], config) -> int:
    """The image width the native integrator tiles its packets over (0: a flat list of rays):
    rays laid out as images (`config.packet` a tile, two or more batch axes) whose width and
    rows come in fours."""
    if not isinstance(config.packet, tuple) or len(batch) < 2:
        return 0
    width, rows = batch[-1], int(np.prod(batch[:-1]))
    return width if width % 4 == 0 and rows % 4 == 0 else 0


def _integrate(scene, bvh, o, d, active, offset, config, *, cpu_only=False, operands=None):
    """(radiance (*batch, 3), shadow rays, reflection rays) of unit-direction rays. With the
    native integrator (`integrator_plan`) the primal runs in the native handler on a CPU and in
    JAX elsewhere (`on_platforms`; `cpu_only`: inside a CPU-only branch already; `operands`: the
    handler's scene operands made once by the caller, `whitted_operands`); its derivatives are
    always the JAX integrator's, so gradients do not depend on where the primal ran. On an
    NVIDIA GPU the primal is the Warp kernel's (`warp_integrator_plan`), its derivatives the
    JAX integrator's."""
    plan = integrator_plan(config)

    def in_jax(scene, o, d, active, offset):
        return _jax_integrate(scene, bvh, o, d, active, offset, config)

    def on_cuda(scene, o, d, active, offset):
        return warp_integrate(scene, bvh, o, d, active, offset, config)

    on_gpu = warp_integrator_plan(config).cuda and not (plan.cpu_only or cpu_only)
    cuda = on_cuda if on_gpu else None
    if not plan.cpu:
        if cuda is not None:
            return on_platforms(in_jax, cuda=cuda)(scene, o, d, active, offset)
        return in_jax(scene, o, d, active, offset)
    batch = active.shape

    def call_native(scene, o, d, active, offset, store_paths=False):
        return native_whitted(
            whitted_operands(scene, bvh) if operands is None else operands,
            o.reshape(-1, 3),
            d.reshape(-1, 3),
            active.reshape(-1),
            offset,
            tile_width=_tile_width(batch, config),
            store_paths=store_paths,
            **integrator_options(config, bvh),
        )

    def native(scene, o, d, active, offset):
        total, traced, _, _ = call_native(scene, o, d, active, offset)
        return (total.reshape(batch + (3,)), *_traced_counts(traced))

    def native_jvp(primals, tangents):
        # The forward stores each ray's path; the derivatives are those of its replay.
        scene, o, d, active, offset = primals
        total, traced, prim, visible = call_native(scene, o, d, active, offset, store_paths=True)
        counts = _traced_counts(traced)
        paths = StoredPaths(prim, visible)

        def replayed(scene, o, d, active, offset):
            del active  # the paths say which rays were traced
            rgb = replay_radiance(scene, bvh, o.reshape(-1, 3), d.reshape(-1, 3), offset, paths, shading)
            return (rgb.reshape(batch + (3,)), *counts)

        def adjoint(primals, stored, cotangent, moving):  # what it reads comes in its operands (traced later)
            _, o, d, _, offset = primals
            ops, prim, visible = stored
            rays = (o.reshape(-1, 3), d.reshape(-1, 3), offset)
            g = cotangent.reshape(-1, 3)
            attributes = shading_attributes(config)
            return native_shading_adjoint(ops, *rays, prim, visible, g, shading=attributes, moving=moving)

        # The shading parameters' derivatives through the native adjoint, the rest (geometry,
        # textures, rays) through the replay's: each only where something moves.
        rest, moving = split_tangents(primals, tangents, SHADING_FIELDS)
        rgb = None
        if rest is not None:
            _, (rgb, *_) = jvp_of(replayed, primals, rest)
        if moving is not None:
            ops = whitted_operands(scene, bvh) if operands is None else operands
            stored = (ops, prim, visible)
            by_adjoint = shading_tangent(replayed, adjoint, primals, stored, moving, SHADING_FIELDS)
            rgb = by_adjoint if rgb is None else rgb + by_adjoint
        if rgb is None:
            rgb = jnp.zeros(batch + (3,), jnp.float32)
        no_counts = tuple(np.zeros((), jax.dtypes.float0) for _ in counts)
        return (total.reshape(batch + (3,)), *counts), (rgb, *no_counts)

    shading = shading_of(config)
    replays = scene.num_lights <= 32  # the paths' visibility bits
    stage = on_platforms(
        in_jax,
        cpu=native,
        cuda=cuda,
        cpu_only=plan.cpu_only or cpu_only,
        cpu_jvp=native_jvp if replays else None,
    )
    return stage(scene, o, d, active, offset)


def _traced_counts(traced):
    """(shadow rays, reflection rays) from the native integrator's per-ray counts."""
    n_shadow = jnp.sum(jnp.right_shift(traced, 8), dtype=jnp.int32)
    n_reflection = jnp.sum(jnp.bitwise_and(traced, 255), dtype=jnp.int32)
    return n_shadow, n_reflection


def _finish_radiance(total, active, valid, config, n_shadow, n_reflection):
    bad = active & ~all3(jnp.isfinite(total))
    bad_color = jnp.asarray(config.bad_color, jnp.float32)
    rgb = jnp.where(bad[..., None], bad_color, jnp.where(active[..., None], total, 0.0))
    counts = RayCounts(
        primary=jnp.sum(active & valid, dtype=jnp.int32),
        shadow=n_shadow,
        reflection=n_reflection,
        bad=jnp.sum(bad, dtype=jnp.int32),
    )
    return Radiance(rgb, bad, counts)


# ---- rays made chunk by chunk: a cost that follows the live rays, not the slots -------------


class ChunkedRadiance(NamedTuple):
    """`radiance_in_chunks`'s result: the radiance of every slot (padded to whole chunks; slots
    beyond the live ones are 0), of every ray of each image tile (its own shape; inactive rays
    0), and the rays traced."""

    total: Float[Array, "P 3"] | None
    primary: Int[Array, ""]
    shadow: Int[Array, ""]
    reflection: Int[Array, ""]
    tiles: tuple[Array, ...] = ()
    consumed: tuple = ()  # `radiance_in_chunks(consume=)`'s last carry


class ImageTile(NamedTuple):
    """Rays laid out as images, `(..., h, w)`: traced like the full frame's camera rays
    (`config.packet`, tiles of neighbouring pixels sharing one traversal), only where `active`;
    `shading_class`: each ray's class in `radiance_in_chunks`'s `classes` (needed with them)."""

    origins: Float[Array, "*batch 3"]
    directions: Float[Array, "*batch 3"]
    active: Bool[Array, "*batch"]
    shading_class: Int[Array, "*batch"] | None = None


def chunk_loop(n_chunks: int, size: int, n_live, body, init, start=0):
    """`body(carry, first)` for the chunks of `size` from `start` (traced or static) whose first
    index is below `n_live` (at most `n_chunks`), one after another: a `lax.while_loop` whose
    trip count is the number of live chunks, so the others cost nothing (no skipped iterations
    carrying the buffers)."""
    start = jnp.asarray(start, jnp.int32)
    left = jnp.maximum(jnp.asarray(n_live, jnp.int32) - start, 0)
    live = jnp.minimum((left + size - 1) // size, n_chunks)

    def step(state):
        c, carry = state
        return c + 1, body(carry, start + c * size)

    return jax.lax.while_loop(lambda state: state[0] < live, step, (jnp.int32(0), init))[1]


def _chunk_rays(rays_at, first, size):
    """A chunk's rays from `rays_at`: (origins, unit directions, which are valid: finite with a
    nonzero direction, as `radiance` counts primary rays)."""
    o, d = rays_at(first, size)
    o = jnp.asarray(o, jnp.float32)
    d_raw = jnp.asarray(d, jnp.float32)
    d = normalize(d_raw)
    return o, d, all3(jnp.isfinite(o)) & all3(jnp.isfinite(d_raw)) & any3(d != 0)


def _append(queue, n, rays, alive):
    """Move the `alive` entries of a chunk's `rays` to the front and write the chunk into
    `queue` at `n`: the first `n + alive.sum()` queue entries are then live. The queue must
    have a chunk of room beyond its capacity (the chunk is written whole)."""
    k, order = _live_first(alive)
    queue = tuple(
        jax.lax.dynamic_update_slice_in_dim(q, x[order], n, 0) for q, x in zip(queue, rays, strict=True)
    )
    return queue, n + k


class _Chunks(NamedTuple):
    size: int
    count: int
    extra: int = 0  # rays of image tiles, held after the slots

    @property
    def padded(self) -> int:
        return self.size * self.count

    @property
    def capacity(self) -> int:
        """Queue entries: every slot and tile ray, plus a chunk of room (a chunk is appended
        whole), rounded up to whole reflection chunks."""
        return self.padded + self.extra + self.size


def _chunks(n_slots: int, config, extra: int = 0) -> _Chunks:
    size = min(config.chunk_size, n_slots)
    return _Chunks(size, -(-n_slots // size), extra)


def _batch(chunks: _Chunks, config) -> _Chunks:
    """The slot chunks of one depth batch (`config.depth_batch_size`, in whole chunks; the
    image tiles' rays go with the first batch): what the reflection queue is sized to."""
    limit = config.depth_batch_size
    count = chunks.count if limit is None else min(chunks.count, max(1, -(-limit // chunks.size)))
    return _Chunks(chunks.size, count, chunks.extra)


def _empty_queue(chunks: _Chunks, config, classes=None):
    """(origins, directions, weights, target slots[, shading classes]) with a chunk of room
    beyond the slots and tile rays, in whole reflection chunks."""
    return _queue_of(_queue_chunks(chunks, config).padded, with_classes=classes is not None)


def _queue_of(capacity: int, *, with_classes: bool = False):
    """An empty queue of rays: (origins, directions, weights, target slots[, shading classes])."""
    queue = (
        jnp.zeros((capacity, 3), jnp.float32),
        jnp.ones((capacity, 3), jnp.float32),
        jnp.zeros((capacity, 3), jnp.float32),
        jnp.zeros((capacity,), jnp.int32),
    )
    return queue + (jnp.zeros((capacity,), jnp.int32),) if with_classes else queue


def _packet_of(config):
    """Packets of consecutive slots where `config.packet` is an int; a tile (the default, made
    for image-shaped batches) means one by one here: over the foveated frame's
    locality-ordered slots (mostly block top-lefts at stride 2 and 4), 64-ray packets measured
    1.7x slower than one by one at SPP 1 and no faster at SPP 4 (benchmarks/foveation.py)."""
    return config.packet if isinstance(config.packet, int) else None


def _primary_level(
    scene,
    bvh,
    rays_at,
    n_live,
    chunks: _Chunks,
    *,
    offset,
    config,
    init=None,
    classes=None,
    class_at=None,
    start=0,
    count=None,
):
    """Depth 0 of `radiance_in_chunks` on the live slots of at most `count` chunks (None: all)
    from slot `start`: (total (padded + extra, 3), queue, queued, primary, shadow), starting
    from `init` (the carry of the image tiles or of the previous batch) or empty (a queue of
    one depth batch, `_batch`)."""
    size = chunks.size
    lanes = jnp.arange(size, dtype=jnp.int32)
    spawn = config.max_depth > 0
    packet = _packet_of(config)

    def body(carry, first):
        total, queue, n_q, n_primary, n_shadow = carry
        o, d, valid = _chunk_rays(rays_at, first, size)
        active = first + lanes < n_live
        weight = jnp.ones((size, 3), jnp.float32)
        fidelity, extra = None, ()
        if classes is not None and class_at is not None:  # classes come with class_at (checked)
            cls = jnp.asarray(class_at(first, size), jnp.int32)
            fidelity, extra = (classes, cls, 0), (cls,)
        contribution, (o2, d2, w2, alive2), traced = _trace_and_shade(
            scene,
            bvh,
            o,
            d,
            active,
            weight,
            packet=packet,
            offset=offset,
            backend=config.backend,
            hits=config.hits,
            shading=shading_of(config),
            spawn=spawn,
            fidelity=fidelity,
        )
        total = jax.lax.dynamic_update_slice_in_dim(total, contribution, first, 0)
        if spawn:
            queue, n_q = _append(queue, n_q, (o2, d2, w2, first + lanes) + extra, alive2)
        n_primary = n_primary + jnp.sum(active & valid, dtype=jnp.int32)
        return total, queue, n_q, n_primary, n_shadow + traced

    if init is None:
        zero = jnp.int32(0)
        total = jnp.zeros((chunks.padded + chunks.extra, 3), jnp.float32)
        init = (total, _empty_queue(_batch(chunks, config), config, classes), zero, zero, zero)
    return chunk_loop(chunks.count if count is None else count, size, n_live, body, init, start)


def _tile_level(scene, bvh, tiles, chunks: _Chunks, *, offset, config, classes=None):
    """Depth 0 of the image tiles, each traced and shaded whole as the full frame's camera rays
    are (`config.packet`; shadow rays in the same packets), written after the slots in `total`,
    their reflection rays queued (compacted) like the slots'. Returns the `_primary_level` carry."""
    zero = jnp.int32(0)
    total = jnp.zeros((chunks.padded + chunks.extra, 3), jnp.float32)
    queue, n_q, n_primary, n_shadow = _empty_queue(_batch(chunks, config), config, classes), zero, zero, zero
    spawn = config.max_depth > 0
    base = chunks.padded
    for tile in tiles:
        batch = tile.active.shape
        n = int(np.prod(batch))
        o = jnp.asarray(tile.origins, jnp.float32)
        d_raw = jnp.asarray(tile.directions, jnp.float32)
        d = normalize(d_raw)
        valid = all3(jnp.isfinite(o)) & all3(jnp.isfinite(d_raw)) & any3(d != 0)
        fidelity, extra = None, ()
        if classes is not None:
            cls = jnp.broadcast_to(jnp.asarray(tile.shading_class, jnp.int32), batch)
            fidelity, extra = (classes, cls, 0), (cls.reshape(n),)
        contribution, nxt, traced = _trace_and_shade(
            scene,
            bvh,
            o,
            d,
            tile.active,
            jnp.ones(batch + (3,), jnp.float32),
            packet=_usable_packet(config.packet, len(batch)),
            offset=offset,
            backend=config.backend,
            hits=config.hits,
            shading=shading_of(config),
            spawn=spawn,
            fidelity=fidelity,
        )
        total = jax.lax.dynamic_update_slice_in_dim(total, contribution.reshape(n, 3), base, 0)
        if spawn:
            o2, d2, w2, alive2 = (x.reshape((n,) + x.shape[len(batch) :]) for x in nxt)
            target = base + jnp.arange(n, dtype=jnp.int32)
            queue, n_q = _append(queue, n_q, (o2, d2, w2, target) + extra, alive2)
        n_primary = n_primary + jnp.sum(tile.active & valid, dtype=jnp.int32)
        n_shadow = n_shadow + traced
        base += n
    return total, queue, n_q, n_primary, n_shadow


def _level_sizes(chunks: _Chunks, config) -> tuple[int, int]:
    """Chunk sizes of the first reflection level and of the later ones."""
    rest = min(config.queue_chunk_size, chunks.size)
    first = config.first_bounce_chunk_size
    return (rest if first is None else min(first, chunks.size)), rest


def _queue_chunks(chunks: _Chunks, config, size=None) -> _Chunks:
    """The reflection levels' chunks over the queue (capacity: the slots and tile rays plus
    one chunk, in whole chunks of every level's size)."""
    first, rest = _level_sizes(chunks, config)
    size = size or rest
    whole = max(first, rest)
    capacity = -(-chunks.capacity // whole) * whole
    return _Chunks(size, capacity // size)


def _queue_level(
    scene, bvh, total, queue, n_q, depth, chunks: _Chunks, *, offset, config, size=None, classes=None
):
    """One reflection level over the queue's first `n_q` rays, in place, in chunks of
    `_queue_chunks` (of one depth batch of `chunks`): (total, queue, the next level's queued
    rays, shadow rays traced)."""
    chunks = _queue_chunks(_batch(chunks, config), config, size)
    size = chunks.size
    lanes = jnp.arange(size, dtype=jnp.int32)
    spawn = depth < config.max_depth

    def body(inner, first):
        total, queue, n_next, n_shadow = inner
        o, d, weight, target, *extra = (jax.lax.dynamic_slice_in_dim(q, first, size) for q in queue)
        alive = first + lanes < n_q
        fidelity = None if classes is None else (classes, extra[0], depth)
        contribution, (o2, d2, w2, alive2), traced = _trace_and_shade(
            scene,
            bvh,
            o,
            d,
            alive,
            weight,
            packet=None,
            offset=offset,
            backend=config.backend,
            hits=config.hits,
            shading=shading_of(config),
            spawn=spawn,
            fidelity=fidelity,
        )
        total = total.at[target].add(contribution)
        queue, n_next = _append(queue, n_next, (o2, d2, w2, target, *extra), alive2)
        return total, queue, n_next, n_shadow + traced

    # Chunks past the queued rays are skipped; the writes of a chunk go to the queue's front,
    # never past the chunk just read (a level appends at most as many rays as it reads).
    zero = jnp.int32(0)
    return chunk_loop(chunks.count, size, n_q, body, (total, queue, zero, zero))


def radiance_in_chunks(
    scene: SceneArrays,
    bvh: BVH,
    rays_at,
    n_live,
    *,
    n_slots: int,
    config: RenderConfig = DEFAULT_CONFIG,
    tiles: tuple[ImageTile, ...] = (),
    classes: ShadingClasses | None = None,
    class_at=None,
    scale=None,
    consume=None,
) -> ChunkedRadiance:
    """Whitted radiance of up to `n_slots` rays of which the first `n_live` are live, made and
    traced chunk by chunk (`config.chunk_size`): `rays_at(first, size)` returns the
    `(origins, directions)` of slots first..first+size. Chunks past `n_live` cost nothing.

    Every depth level runs over chunks of a queue: a chunk's reflection rays are compacted
    (O(chunk)) and appended to the queue in place, so no pass over all slots ever happens
    after the primary rays, and reflection rays stay in the order of the slots that spawned
    them (spatially coherent when the slots are). The slots go through every level a depth
    batch at a time (`config.depth_batch_size` slots, whole chunks; a `lax.while_loop` over
    the live batches), so the queue holds one batch's rays: the program's memory follows the
    batch, not `n_slots` (on a CPU every page of it is fresh memory, faulted in and zeroed on
    every call: `benchmarks/foveation.py --variants --which batch` prints the page faults of a
    frame with one batch of every slot and with the default). Primary rays and their shadow
    rays are traced
    in packets of `config.packet` consecutive rays where that is an int, else one by one (a
    chunk is a flat list, not an image); later levels one by one. Pure and jittable; the chunk
    loops are `lax.while_loop`s, so forward-mode derivatives only (`radiance` takes `jax.grad`).

    `tiles`: rays laid out as images (`ImageTile`), traced first, whole, as the full frame's
    camera rays are (dense packets of neighbouring pixels, for rays that are coherent: a
    foveated frame's fovea); their reflection rays join the slots' in the same queue. Their
    radiance is returned in `tiles` (each the tile's shape + (3,)).

    `classes` (`ShadingClasses`): shading fidelity per class of rays, `class_at(first, size)`
    the class of each of those slots (int32, traced) and each tile's `shading_class` that of
    its rays; reflection rays carry their sample's class. None: every ray at full fidelity
    (`config`), the program without classes.

    `scale`: the length `config.ray_offset` is relative to (None: `scene_scale(scene)`); a scene
    whose arrays hold several levels of detail passes its finest level's, so that the offsets,
    and the finest level's rays, are those of the scene alone.

    `consume`: None, or `(init, fn)`: each live chunk's radiance is handed to
    `carry = fn(carry, first, radiance (size, 3))`, starting from `init`, in slot order, and the
    result's `consumed` is the last carry and its `total` None. The native integrator hands each
    chunk over as it is traced (no array of every slot's radiance); the JAX one after its last
    depth level.
    """
    if classes is not None and (class_at is None or any(t.shading_class is None for t in tiles)):
        raise ValueError("radiance_in_chunks: classes need class_at and every tile's shading_class")
    scene = jax.tree.map(jnp.asarray, scene)
    extra = sum(int(np.prod(t.active.shape)) for t in tiles)
    chunks = _chunks(n_slots, config, extra)
    offset = config.ray_offset * (scene_scale(scene) if scale is None else jnp.asarray(scale, jnp.float32))

    def in_jax():
        out = _chunks_in_jax(scene, bvh, rays_at, n_live, chunks, offset, config, tiles, classes, class_at)
        if consume is None:
            return out
        init, fn = consume
        total = cast(Array, out.total)  # the JAX integrator always returns every slot's

        def body(carry, first):
            return fn(carry, first, jax.lax.dynamic_slice_in_dim(total, first, chunks.size))

        consumed = chunk_loop(chunks.count, chunks.size, n_live, body, init)
        return out._replace(total=None, consumed=consumed)

    plan = integrator_plan(config)
    if tiles or classes is not None or not plan.cpu:
        return in_jax()

    def in_native():
        return _chunks_native(scene, bvh, rays_at, n_live, chunks, offset, config, consume)

    # No derivatives here: the integrator inside the native chunks has its own (`_integrate`).
    return on_platforms(in_jax, cpu=in_native, cpu_only=plan.cpu_only, derivatives=False)()


def _chunks_native(
    scene, bvh, rays_at, n_live, chunks: _Chunks, offset, config, consume=None
) -> ChunkedRadiance:
    """`radiance_in_chunks` through the native integrator (`_integrate`): each live chunk of
    slots made (`rays_at`) and traced through every depth level in one call, its radiance
    written to its slots (or handed to `consume`'s function). The handler's scene operands are
    made once, outside the loop over the chunks."""
    size = chunks.size
    lanes = jnp.arange(size, dtype=jnp.int32)
    operands = whitted_operands(scene, bvh)

    def body(carry, first):
        total, n_primary, n_shadow, n_reflection = carry
        o, d, valid = _chunk_rays(rays_at, first, size)
        active = first + lanes < n_live
        contribution, shadow, reflection = _integrate(
            scene, bvh, o, d, active, offset, config, cpu_only=True, operands=operands
        )
        if consume is None:
            total = jax.lax.dynamic_update_slice_in_dim(total, contribution, first, 0)
        else:
            total = consume[1](total, first, contribution)
        n_primary = n_primary + jnp.sum(active & valid, dtype=jnp.int32)
        return total, n_primary, n_shadow + shadow, n_reflection + reflection

    zero = jnp.int32(0)
    start = jnp.zeros((chunks.padded, 3), jnp.float32) if consume is None else consume[0]
    total, n_primary, n_shadow, n_reflection = chunk_loop(
        chunks.count, size, n_live, body, (start, zero, zero, zero)
    )
    if consume is None:
        return ChunkedRadiance(total, n_primary, n_shadow, n_reflection, ())
    return ChunkedRadiance(None, n_primary, n_shadow, n_reflection, (), cast(tuple, total))


def _chunks_in_jax(scene, bvh, rays_at, n_live, chunks: _Chunks, offset, config, tiles, classes, class_at):
    """`radiance_in_chunks` in JAX: the queues of every depth level (see its docstring)."""
    batch = _batch(chunks, config)
    zero = jnp.int32(0)
    if tiles:
        init = _tile_level(scene, bvh, tiles, chunks, offset=offset, config=config, classes=classes)
    else:
        total = jnp.zeros((chunks.padded + chunks.extra, 3), jnp.float32)
        init = (total, _empty_queue(batch, config, classes), zero, zero, zero)
    first, rest = _level_sizes(chunks, config)

    def levels(total, queue, n_q, n_shadow):
        """Every reflection level of the queued rays: (total, queue, shadow, reflection rays)."""

        def level(carry, depth):
            total, queue, n_q, n_shadow = carry
            total, queue, n_next, traced = _queue_level(
                scene, bvh, total, queue, n_q, depth, chunks, offset=offset, config=config, classes=classes
            )
            return (total, queue, n_next, n_shadow + traced), n_q

        n_reflection = zero
        start = 1
        if config.max_depth > 0 and first != rest:
            n_reflection = n_q
            total, queue, n_q, traced = _queue_level(
                scene,
                bvh,
                total,
                queue,
                n_q,
                1,
                chunks,
                offset=offset,
                config=config,
                size=first,
                classes=classes,
            )
            n_shadow = n_shadow + traced
            start = 2
        if config.max_depth >= start:
            (total, queue, _, n_shadow), per_level = jax.lax.scan(
                level, (total, queue, n_q, n_shadow), jnp.arange(start, config.max_depth + 1)
            )
            n_reflection = n_reflection + jnp.sum(per_level)
        return total, queue, n_shadow, n_reflection

    def one_batch(state):
        b, (total, queue, n_q, n_primary, n_shadow, n_reflection) = state
        total, queue, n_q, n_primary, n_shadow = _primary_level(
            scene,
            bvh,
            rays_at,
            n_live,
            chunks,
            offset=offset,
            config=config,
            init=(total, queue, n_q, n_primary, n_shadow),
            classes=classes,
            class_at=class_at,
            start=b * batch.padded,
            count=batch.count,
        )
        total, queue, n_shadow, traced = levels(total, queue, n_q, n_shadow)
        return b + 1, (total, queue, zero, n_primary, n_shadow, n_reflection + traced)

    # Batches of slots through every level, the live ones only (the tiles' rays, queued before
    # the first batch's, go with it): the queue holds one batch.
    n_batches = -(-jnp.asarray(n_live, jnp.int32) // batch.padded)
    n_batches = jnp.minimum(n_batches, -(-chunks.count // batch.count))
    if tiles:
        n_batches = jnp.maximum(n_batches, 1)
    _, carry = jax.lax.while_loop(lambda state: state[0] < n_batches, one_batch, (zero, init + (zero,)))
    # The carry's arrays (the checker reads while_loop's carry as one type for every element).
    total, _, _, n_primary, n_shadow, n_reflection = cast(tuple[Array, ...], carry)
    parts, base = [], chunks.padded
    for tile in tiles:
        n = int(np.prod(tile.active.shape))
        parts.append(total[base : base + n].reshape(tile.active.shape + (3,)))
        base += n
    return ChunkedRadiance(total[: chunks.padded], n_primary, n_shadow, n_reflection, tuple(parts))
