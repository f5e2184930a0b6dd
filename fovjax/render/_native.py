"""The Whitted integrator's native sides: the handler `render/_whitted.cc` (the primal of
`radiance` on a CPU) and the Warp kernel `render/_warp_whitted.py` (on an NVIDIA GPU), the scene
operands in the handlers' layout, and the plans that say whether a configuration runs them. Their
oracle and their derivatives are the JAX integrator (`_integrator.py`)."""

from __future__ import annotations

import dataclasses
import functools
import importlib.util

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..native.internal import NativePlan, handler, layout, plan_native
from ..trace import BVH
from ._arrays import light_columns

WHITTED_TARGET = "fovjax_embree_whitted"
ADJOINT_TARGET = "fovjax_whitted_adjoint"
FRAME_TARGET = "fovjax_camera_frame"
# The scene fields whose gradient the native adjoint computes (`native_shading_adjoint`): the
# materials' columns, the lights' colours and the ambient colour.
SHADING_FIELDS = tuple(name for name, _ in layout.MATERIAL_COLUMNS) + ("light_color", "ambient")
assert set(SHADING_FIELDS) == set(layout.ADJOINT_FIELDS)
# The most reflections the handler counts per ray (its counts are 8 bits).
MAX_NATIVE_DEPTH = 255


def native_why_not(config) -> str:
    """Why `config` cannot run the native integrator whatever the handlers' state ("" where it
    can, once they are loaded)."""
    if config.backend not in ("auto", "embree"):
        return f"the ray backend is {config.backend!r} (the native integrator traces with Embree)"
    if config.max_depth > MAX_NATIVE_DEPTH:
        return f"max_depth {config.max_depth} is above the native integrator's {MAX_NATIVE_DEPTH}"
    return ""


@functools.cache
def integrator_plan(config) -> NativePlan:
    """Whether `config` runs its integrator natively on a CPU (`RenderConfig.integrator` "auto":
    where the handlers built and the ray backend is "auto" or "embree"; "native": those or an
    error naming why not; "jax": never), resolved once per configuration."""
    why_not = native_why_not(config)
    what = f"RenderConfig.integrator {config.integrator!r}"
    return plan_native(config.integrator, allowed=not why_not, why_not=why_not, what=what)


@dataclasses.dataclass(frozen=True)
class WarpPlan:
    """Whether a configuration's integrator runs in Warp on an NVIDIA GPU (`warp_integrator_plan`):
    `cuda`, and `reason`: what runs there, or why the JAX integrator does."""

    cuda: bool
    reason: str


@functools.cache
def warp_integrator_plan(config) -> WarpPlan:
    """Whether `config` runs its integrator's primal in the Warp kernel on CUDA
    (`RenderConfig.integrator` "auto", where Warp is installed and the ray backend is "auto" or
    "warp"), resolved once per configuration. Elsewhere the CUDA side is the JAX integrator:
    "jax" asks for it, "native" builds a program for the CPU alone, another ray backend
    (the JAX traversal, a registered one) keeps the JAX integrator on it."""
    if config.integrator == "jax":
        return WarpPlan(False, "RenderConfig.integrator 'jax'")
    if config.integrator == "native":
        return WarpPlan(False, "RenderConfig.integrator 'native' builds a program for the CPU alone")
    if config.backend not in ("auto", "warp"):
        why = f"the ray backend is {config.backend!r} (the Warp integrator traces with Warp)"
        return WarpPlan(False, why)
    if importlib.util.find_spec("warp") is None:
        return WarpPlan(False, "Warp is not installed: pip install 'fovjax[gpu]'")
    return WarpPlan(True, "the Whitted loop in one Warp kernel launch per call; derivatives in JAX")


def whitted_operands(scene, bvh: BVH) -> tuple:
    """The scene operands of the Whitted handlers, in `layout.SCENE_OPERANDS` order without the
    ray offset (the caller appends it): the BVH (its host id, geometry and trees, for the Embree
    scene) and the scene's arrays in the handler's layout (materials and lights as rows of
    `layout.MATERIAL_COLUMNS` and `layout.LIGHT_COLUMNS`, textures concatenated with their
    shapes). Made once where many calls share a scene (the foveated frame's chunks)."""
    f32, i32 = jnp.float32, jnp.int32

    def flat(x, dtype):
        return jnp.zeros((0,), dtype) if x is None else jnp.asarray(x, dtype).reshape(-1)

    def rows(columns, arrays):
        return jnp.concatenate(
            [jnp.asarray(arrays[name], f32).reshape(-1, width) for name, width in columns], axis=1
        )

    textures = tuple(jnp.asarray(t, f32).reshape(-1) for t in scene.textures)
    texels = jnp.concatenate(textures) if textures else jnp.zeros((0,), f32)
    shapes = np.asarray([np.shape(t)[:2] for t in scene.textures], np.int32).reshape(-1)
    material = {name: getattr(scene, name) for name, _ in layout.MATERIAL_COLUMNS}
    direction, cone = light_columns(scene)
    light = {
        "position": scene.light_position,
        "color": scene.light_color,
        "direction": direction,
        "cone": cone,
    }
    operands = (
        jnp.asarray(bvh.host_id, i32),
        jnp.asarray(bvh.vertices, f32),
        jnp.asarray(bvh.faces, i32),
        jnp.asarray(bvh.tree_faces(), i32),
        jnp.asarray(scene.vertices, f32),
        jnp.asarray(scene.faces, i32),
        flat(scene.face_material, i32),
        flat(scene.normals, f32),
        flat(scene.uvs, f32),
        rows(layout.MATERIAL_COLUMNS, material),
        flat(scene.texture, i32),
        texels,
        jnp.asarray(shapes, i32),
        rows(layout.LIGHT_COLUMNS, light),
        flat(scene.light_kind, i32),
        flat(scene.ambient, f32),
        jnp.asarray(scene.environment, f32),
    )
    assert len(operands) == len(layout.SCENE_OPERANDS) - 1  # the offset comes last, from the caller
    return jax.tree.map(jax.lax.stop_gradient, operands)


def shading_attributes(config) -> dict:
    """`config`'s shading options as the Whitted and slots handlers' attributes: `specular`
    (`layout.SPECULARS`' code), `specular_payload` and `min_contribution`."""
    return {
        "specular": np.int32(layout.SPECULARS[config.specular]),
        "specular_payload": np.int32(config.specular_payload),
        "min_contribution": np.float32(config.min_contribution),
    }


def integrator_options(config, bvh: BVH) -> dict:
    """`config`'s integrator options as the native integrator's callers pass them
    (`native_whitted`, `native_camera_frame`, the foveated frame's slots): the depth, the hits
    recomputed or Embree's, packets, the BVH's watertight mode and the shading attributes."""
    return {
        "max_depth": config.max_depth,
        "recompute": config.hits == "recomputed",
        "packets": config.packet is not None,
        "robust": bvh.watertight,
        "shading": shading_attributes(config),
    }


def native_whitted(
    operands: tuple,
    o,
    d,
    active,
    offset,
    *,
    max_depth: int,
    recompute: bool,
    packets: bool,
    tile_width: int = 0,
    robust: bool = True,
    shading: dict | None = None,
    store_paths: bool = False,
):
    """The Whitted integrator's primal through the native handler, on flat rays: (radiance
    (N, 3) with NaN/inf kept, rays traced per ray: shadow rays in bits 8 and up, reflection rays
    in bits 0-7), and each ray's path, with `store_paths` (else empty): (max_depth + 1, N) the face hit at
    each level (-1 a miss, `layout.PATH_NOT_TRACED` no ray there) and (max_depth + 1, N) uint32
    the lights whose shadow rays were unblocked there (bit l: light l; at most 32 lights), what
    `_replay.replay_radiance` differentiates.

    `operands`: the scene's (`whitted_operands`); `d` unit directions; `offset` the ray offset
    in scene units; `recompute`: u, v by Möller-Trumbore on the scene's vertices
    (`RenderConfig.hits` "recomputed"), else Embree's; `packets`: packets of the CPU's width
    where a run of rays is coherent; `tile_width`: the rays are images this wide (rows of it,
    one after another), traced in blocks of four rows, each packet a 4×4 tile of neighbouring
    pixels (0: a flat list); `robust`: the BVH's `watertight`; `shading`: the shading options'
    attributes (`shading_attributes`; None: the defaults of `RenderConfig`). Not
    differentiable (the caller's custom JVP is)."""
    if not 0 <= max_depth <= MAX_NATIVE_DEPTH:
        raise ValueError(
            f"the native integrator counts at most {MAX_NATIVE_DEPTH} reflections, got max_depth {max_depth}"
        )
    f32 = jnp.float32
    n = active.shape[0]
    rays = (
        jnp.asarray(o, f32).reshape(n, 3),
        jnp.asarray(d, f32).reshape(n, 3),
        jnp.asarray(active, bool).reshape(n),
    )
    rays = jax.tree.map(jax.lax.stop_gradient, rays)
    offset = jax.lax.stop_gradient(jnp.asarray(offset, f32).reshape(1))
    stored = (max_depth + 1) * n if store_paths else 0
    out = (
        jax.ShapeDtypeStruct((n, 3), f32),
        jax.ShapeDtypeStruct((n,), jnp.int32),
        jax.ShapeDtypeStruct((stored,), jnp.int32),
        jax.ShapeDtypeStruct((stored,), jnp.uint32),
    )
    call = handler(WHITTED_TARGET, out, what="the native integrator", vmap_method="sequential")
    if shading is None:
        from ._config import DEFAULT_CONFIG

        shading = shading_attributes(DEFAULT_CONFIG)
    total, traced, prim, visible = call(
        *rays,
        *operands,
        offset,
        max_depth=np.int32(max_depth),
        recompute=np.int32(recompute),
        packets=np.int32(packets),
        tile_width=np.int32(tile_width),
        robust=np.int32(robust),
        **shading,
    )
    if not store_paths:
        return total, traced, prim, visible  # the paths empty
    return total, traced, prim.reshape(max_depth + 1, n), visible.reshape(max_depth + 1, n)


def native_shading_adjoint(
    operands: tuple, o, d, offset, prim, visible, cotangent, *, shading: dict, moving=SHADING_FIELDS
) -> dict:
    """The gradient of Σ cotangent · radiance with respect to `SHADING_FIELDS`, along the paths a
    native forward stored (`native_whitted(..., store_paths=True)`'s `prim` and `visible`, for
    the flat rays `o`, `d`): the transpose of the replay's derivative in those fields
    (`_replay.replay_radiance`, its oracle), computed by the handler `render/_whitted_adjoint.cc`
    with no ray traced. `operands`: the scene's (`whitted_operands`); `shading`:
    `shading_attributes`; `moving`: the fields whose gradient is read (the others' may be
    left out of the work). A dict of the fields' gradients, each of its field's shape."""
    bits = 0
    for name in moving:
        bits |= 1 << layout.ADJOINT_FIELDS[name]
    f32 = jnp.float32
    n = cotangent.shape[0]
    materials, lights = operands[9], operands[13]
    out = (
        jax.ShapeDtypeStruct((materials.shape[0], layout.MATERIAL_STRIDE), f32),
        jax.ShapeDtypeStruct((lights.shape[0], 3), f32),
        jax.ShapeDtypeStruct((3,), f32),
    )
    call = handler(ADJOINT_TARGET, out, what="the native integrator's adjoint", vmap_method="sequential")
    d_materials, d_lights, d_ambient = call(
        jnp.asarray(o, f32).reshape(n, 3),
        jnp.asarray(d, f32).reshape(n, 3),
        jnp.asarray(prim, jnp.int32).reshape(-1),
        jnp.asarray(visible, jnp.uint32).reshape(-1),
        jnp.asarray(cotangent, f32).reshape(n, 3),
        *operands,
        jnp.asarray(offset, f32).reshape(1),
        specular=shading["specular"],
        specular_payload=shading["specular_payload"],
        moving=np.int32(bits),
    )
    grads, start = {}, 0
    for name, width in layout.MATERIAL_COLUMNS:
        block = d_materials[:, start : start + width]
        grads[name] = block[:, 0] if width == 1 else block
        start += width
    grads["light_color"] = d_lights
    grads["ambient"] = d_ambient
    return grads


def camera_rows(cameras) -> Float[Array, "E stride"]:
    """Cameras as the camera frame and slots handlers read them (`layout.CAMERA_COLUMNS`), a row
    each: position, rotation (row-major), tan(vfov / 2), aspect, offset (what
    `Camera.ray_direction_components` uses)."""
    rows = []
    for cam in cameras:
        columns = {
            "position": cam.position,
            "rotation": cam.rotation,
            "tan_half_vfov": jnp.tan(jnp.deg2rad(cam.vfov_deg) / 2),
            "aspect": cam.width / cam.height,
            "offset": cam.offset,
        }
        rows.append(
            jnp.concatenate(
                [
                    jnp.asarray(columns[name], jnp.float32).reshape(width)
                    for name, width in layout.CAMERA_COLUMNS
                ]
            )
        )
    return jnp.stack(rows)


def native_camera_frame(
    operands: tuple,
    key_data,
    grid,
    cameras,
    bad_color,
    *,
    spp: int,
    height: int,
    width: int,
    jitter: bool,
    max_depth: int,
    recompute: bool,
    packets: bool,
    robust: bool,
    shading: dict,
):
    """The full frame of one or two cameras through the handler `render/_frame.cc`: their
    sub-samples' rays (`grid` the cell centres (spp, 2); with `jitter`, the threefry2x32 draws of
    the key `key_data` (2,) uint32), their Whitted radiance and each pixel's mean. `operands`: the
    scene's (`whitted_operands`) with the ray offset; `cameras`: (E, `layout.CAMERA_STRIDE`) rows
    (`camera_rows`), E 1 or 2. Returns the image (height, E·width, 3), the eyes side by side,
    and (5,) int32: primary, shadow and reflection rays, bad samples, bad pixels. Not
    differentiable (the caller's custom JVP is)."""
    f32 = jnp.float32
    eyes = cameras.shape[0]
    out = (
        jax.ShapeDtypeStruct((height, eyes * width, 3), f32),
        jax.ShapeDtypeStruct((5,), jnp.int32),
    )
    call = handler(FRAME_TARGET, out, what="the native camera frame", vmap_method="sequential")
    inputs = (
        jnp.asarray(key_data, jnp.uint32).reshape(2),
        jnp.asarray(grid, f32).reshape(spp, 2),
        jnp.asarray(cameras, f32).reshape(eyes, layout.CAMERA_STRIDE),
        jnp.asarray(bad_color, f32).reshape(3),
    )
    return call(
        *jax.tree.map(jax.lax.stop_gradient, inputs),
        *operands,
        spp=np.int32(spp),
        height=np.int32(height),
        width=np.int32(width),
        jitter=np.int32(jitter),
        max_depth=np.int32(max_depth),
        recompute=np.int32(recompute),
        packets=np.int32(packets),
        robust=np.int32(robust),
        **shading,
    )
