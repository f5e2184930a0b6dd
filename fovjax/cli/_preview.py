"""A geometry preview: primary rays only, coloured by surface normal and darkened with depth.

This is what `fovjax render --preview` draws; it exercises the scene, the BVH and the traversal
without any lighting model.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..scene import Camera
from ..trace import BVH, closest_hit


def normal_depth_image(bvh: BVH, camera: Camera, *, packet=(8, 8)) -> Float[Array, "H W 3"]:
    """Linear RGB: (n + 1) / 2 for the geometric normal n facing the camera, times a depth
    falloff 1 / (1 + t / t_median); black where nothing is hit."""
    o, d = camera.primary_rays()
    hit = closest_hit(bvh, o, d, packet=packet)
    found = hit.prim >= 0
    tri = bvh.vertices[bvh.faces[jnp.maximum(hit.prim, 0)]]
    n = jnp.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :])
    n = n / jnp.maximum(jnp.linalg.norm(n, axis=-1, keepdims=True), 1e-30)
    n = jnp.where(jnp.sum(n * d, -1, keepdims=True) > 0, -n, n)
    t = jnp.where(found, hit.t, jnp.nan)
    scale = jnp.nanmedian(t)
    shade = 1.0 / (1.0 + jnp.where(found, hit.t, 0.0) / scale)
    return jnp.where(found[..., None], 0.5 * (n + 1.0) * shade[..., None], 0.0)


normal_depth_image_jit = jax.jit(normal_depth_image, static_argnames=("packet",))
