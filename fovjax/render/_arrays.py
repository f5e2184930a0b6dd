"""`SceneArrays`: the arrays of a `Scene` that the integrator reads, and nothing static.

A `Scene` carries static metadata (its name, texture paths, a content hash) that would make every
new scene, and every edited copy of one, a new compiled program. `SceneArrays` keeps only arrays,
so one compiled renderer serves every scene of the same array shapes, and `jax.grad` can be taken
with respect to any of its leaves (vertices, material colours, lights, the environment map).
"""

from __future__ import annotations

import os
from typing import cast

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ..scene import Scene
from ._envmap import ColorLike, EnvmapLike, constant_envmap, load_envmap


class SceneArrays(eqx.Module):
    """Geometry, materials (one row per material, see `fovjax.Materials`), lights (see
    `fovjax.Lights`), the ambient light colour and the lat-long environment map seen by rays
    that miss (a 1 x 1 map for a constant background)."""

    vertices: Float[np.ndarray | Array, "V 3"]
    faces: Int[np.ndarray | Array, "F 3"]
    face_material: Int[np.ndarray | Array, " F"]
    normals: Float[np.ndarray | Array, "V 3"] | None
    uvs: Float[np.ndarray | Array, "V 2"] | None
    ka: Float[np.ndarray | Array, "M 3"]
    kd: Float[np.ndarray | Array, "M 3"]
    ks: Float[np.ndarray | Array, "M 3"]
    ke: Float[np.ndarray | Array, "M 3"]
    kr: Float[np.ndarray | Array, "M 3"]
    ns: Float[np.ndarray | Array, " M"]
    texture: Int[np.ndarray | Array, " M"]
    textures: tuple
    light_position: Float[np.ndarray | Array, "L 3"]
    light_color: Float[np.ndarray | Array, "L 3"]
    light_kind: Int[np.ndarray | Array, " L"]
    ambient: Float[np.ndarray | Array, " 3"]
    environment: Float[np.ndarray | Array, "He We 3"]
    # each texture's mip pyramid (`with_texture_mips`), for texture level of detail.
    texture_mips: tuple | None = None
    # Spot lights (`fovjax.Lights`): each light's unit axis and the cosines of its (inner,
    # outer) half-angles, one row per light; None where no light is a spot (`scene_arrays`
    # leaves them None then, so that the other light arrays can be replaced alone).
    light_direction: Float[np.ndarray | Array, "L 3"] | None = None
    light_cone: Float[np.ndarray | Array, "L 2"] | None = None

    @property
    def num_lights(self) -> int:
        return int(np.shape(self.light_kind)[0])


def scene_arrays(
    scene: Scene, *, envmap: EnvmapLike = None, background: ColorLike = (0.34, 0.55, 0.85)
) -> SceneArrays:
    """The `SceneArrays` of `scene`. `envmap`: a path to a lat-long image, an (He, We, 3) array,
    or None for a constant `background` colour. Works on traced scenes too (no host copies),
    except for loading an `envmap` path."""
    if isinstance(envmap, str | os.PathLike):
        environment = load_envmap(envmap)
    elif envmap is None:
        environment = constant_envmap(background)
    else:  # an array: its shape is checked here
        environment = cast(np.ndarray | Array, envmap)
        shape = np.shape(environment)
        if len(shape) != 3 or shape[-1] != 3 or shape[0] < 1 or shape[1] < 1:
            raise ValueError(f"scene_arrays: envmap must be an (He, We, 3) image, got shape {shape}")
    m, lights = scene.materials, scene.lights
    direction, cone = _spot_columns(lights)
    return SceneArrays(
        vertices=scene.vertices,
        faces=scene.faces,
        face_material=scene.face_material,
        normals=scene.normals,
        uvs=scene.uvs,
        ka=m.ka,
        kd=m.kd,
        ks=m.ks,
        ke=m.ke,
        kr=m.kr,
        ns=m.ns,
        texture=m.texture,
        textures=tuple(scene.textures),
        light_position=lights.position,
        light_color=lights.color,
        light_kind=lights.kind,
        ambient=scene.ambient,
        environment=environment,
        light_direction=direction,
        light_cone=cone,
    )


def _spot_columns(lights):
    """(unit axis (L, 3), cos of the (inner, outer) half-angles (L, 2)) of `lights`: NumPy for
    host arrays, JAX for traced ones (differentiable in the axis and the angles); (None, None)
    where the kinds are host values and none is a spot light."""
    from ..scene import SPOT_LIGHT

    if isinstance(lights.kind, np.ndarray) and not np.any(lights.kind == SPOT_LIGHT):
        return None, None
    n = len(lights)
    direction = np.zeros((n, 3), np.float32) if lights.direction is None else lights.direction
    cone = np.full((n, 2), 180.0, np.float32) if lights.cone_deg is None else lights.cone_deg
    host = isinstance(direction, np.ndarray) and isinstance(cone, np.ndarray)
    xp = np if host else jnp
    direction = xp.asarray(direction, xp.float32)
    length = xp.sqrt(xp.sum(direction * direction, axis=-1, keepdims=True))
    unit = direction / xp.where(length > 0, length, 1.0)
    cos = xp.cos(xp.deg2rad(xp.asarray(cone, xp.float32)))
    return unit.astype(np.float32), cos.astype(np.float32)


def light_columns(scene: SceneArrays):
    """Each light's spot columns as the integrators read them: (unit axis (L, 3), cos of the
    (inner, outer) half-angles (L, 2)); zeros and cos 180° where the arrays carry none (a spot
    light then shines everywhere, as a point light)."""
    n = scene.num_lights
    direction = jnp.zeros((n, 3), jnp.float32) if scene.light_direction is None else scene.light_direction
    cone = jnp.full((n, 2), -1.0, jnp.float32) if scene.light_cone is None else scene.light_cone
    return jnp.asarray(direction, jnp.float32), jnp.asarray(cone, jnp.float32)
