"""Misses: a latitude-longitude environment map, looked up as the thesis's miss program does.

For a unit direction d (y up):

    theta = atan2(d.x, d.z)            u = (theta + pi) / (2 pi)
    phi   = pi/2 - acos(d.y)           v = (1 + sin(phi)) / 2  (= (1 + d.y) / 2)

so u runs 0 → 0.25 → 0.5 → 0.75 → 1 for directions -z → -x → +z → +x → -z, and v is 1 straight
up, 0.5 on the horizon and 0 straight down. The image's top row is v = 1 (the zenith), its
bottom row v = 0, its left column u = 0: an equirectangular panorama as usually stored, with
the view along +z in the middle. Texels are looked up bilinearly, wrapping in u and clamping in
v. Without a map, misses see a constant background colour (a 1 x 1 map).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TypeAlias

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Real

from ..files import load_image
from ._vec import dot


def latlong_uv(directions: Float[np.ndarray | Array, "*batch 3"]) -> Float[Array, "*batch 2"]:
    """(u, v) of directions (any length) in the lat-long parametrisation above."""
    d = jnp.asarray(directions, jnp.float32)
    norm2 = dot(d, d)
    ok = norm2 > 0
    inv = jnp.where(ok, 1.0 / jnp.sqrt(jnp.where(ok, norm2, 1.0)), 0.0)
    dx, dy, dz = d[..., 0] * inv, d[..., 1] * inv, d[..., 2] * inv
    # atan2 at the poles (dx = dz = 0) has an undefined gradient: pick theta = 0 there.
    pole = (dx == 0) & (dz == 0)
    theta = jnp.arctan2(jnp.where(pole, 0.0, dx), jnp.where(pole, 1.0, dz))
    u = (theta + jnp.pi) / (2 * jnp.pi)
    v = 0.5 * (1.0 + jnp.clip(dy, -1.0, 1.0))
    return jnp.stack([u, v], axis=-1)


def envmap_lookup(
    image: Float[np.ndarray | Array, "He We 3"], directions: Float[np.ndarray | Array, "*batch 3"]
) -> Float[Array, "*batch 3"]:
    """Bilinear lookup of lat-long `image` (row 0 = top = v 1) along `directions`."""
    h, w = image.shape[0], image.shape[1]
    if h == 1 and w == 1:  # a constant background: no lookup
        shape = jnp.shape(directions)[:-1] + (3,)
        finite = jnp.isfinite(directions[..., 0] + directions[..., 1] + directions[..., 2])
        return jnp.where(finite[..., None], jnp.broadcast_to(image[0, 0], shape), jnp.nan)
    uv = latlong_uv(directions)
    x = uv[..., 0] * w - 0.5
    y = (1.0 - uv[..., 1]) * h - 0.5
    x0 = jnp.floor(x)
    y0 = jnp.floor(y)
    fx = (x - x0)[..., None]
    fy = (y - y0)[..., None]
    i0 = jnp.mod(x0.astype(jnp.int32), w)
    i1 = jnp.mod(i0 + 1, w)
    j0 = jnp.clip(y0.astype(jnp.int32), 0, h - 1)
    j1 = jnp.clip(y0.astype(jnp.int32) + 1, 0, h - 1)
    top = image[j0, i0] * (1 - fx) + image[j0, i1] * fx
    bottom = image[j1, i0] * (1 - fx) + image[j1, i1] * fx
    return top * (1 - fy) + bottom * fy


# An environment map as the entry points take it: a path to a lat-long image, an (He, We, 3)
# linear-RGB array, or None for the render config's constant background.
EnvmapLike: TypeAlias = str | os.PathLike | Float[ArrayLike, "He We 3"] | None
# A linear-RGB colour: 3 numbers.
ColorLike: TypeAlias = Real[ArrayLike, " 3"] | Sequence[float]


def constant_envmap(color: ColorLike) -> Float[np.ndarray, "1 1 3"]:
    """A 1 x 1 map of one colour: the background for misses without an environment map."""
    return np.asarray(color, np.float32).reshape(1, 1, 3)


def load_envmap(path: str | os.PathLike) -> Float[np.ndarray, "He We 3"]:
    """A lat-long environment map from an image file, as linear-RGB float32 (He, We, 3).

    `.hdr` and `.exr` are read as linear radiance; LDR images (PNG, JPEG, ...) are
    sRGB-decoded. The width should be twice the height (360 x 180 degrees); other aspect ratios
    are accepted and stretched."""
    path = Path(path)
    image = load_image(path)
    if image.shape[0] < 1 or image.shape[1] < 1:
        raise ValueError(f"load_envmap: {path}: empty image")
    if np.any(image < 0):
        raise ValueError(f"load_envmap: {path}: negative radiance in the map")
    return image
