"""Embree backend (CPU): Embree 4 through an XLA FFI call (`_embree_ffi.cc`, built on first use),
or, where that handler cannot be built, embreex's Python API through `jax.pure_callback`.

The FFI call runs on XLA's buffers and CPU thread pool inside the compiled program: rays in
16-ray packets (`rtcIntersect16` / `rtcOccluded16`) when they come in a coherent order (tiles,
sorted), one by one otherwise; `tmin` is Embree's `tnear`; a merged BVH's trees are one Embree
scene each, chosen per ray (`level=`). The fallback moves a ray with tmin > 0 to o + tmin * d and
shifts its distances back (embreex's rays start at 0) and supports no `level=`. Either way only
the face index leaves the backend: t, u, v are recomputed differentiably from it.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ._bvh import BVH, host_geometry

_SCENES: dict[str, object] = {}


def _require_embreex():
    try:
        from embreex import rtcore_scene  # noqa: F401
        from embreex.mesh_construction import TriangleMesh  # noqa: F401
    except ImportError as exc:
        raise ImportError("the Embree backend needs embreex: pip install 'fovjax[embree]'") from exc


def embree_scene(key: str, vertices: np.ndarray, faces: np.ndarray):
    """The committed embreex scene for a BVH key (built once per process)."""
    _require_embreex()
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    scene = _SCENES.get(key)
    if scene is None:
        # embreex's package __getattr__ returns a str, which the checker reads rtcore_scene as.
        scene = rtcore_scene.EmbreeScene()  # pyright: ignore[reportAttributeAccessIssue]
        TriangleMesh(
            scene=scene, vertices=np.asarray(vertices, np.float32), indices=np.asarray(faces, np.int32)
        )
        _SCENES[key] = scene
    return scene


def embree_trace_host(scene, o, d, tmin, tmax, any_hit):
    """Host-side Embree query on flat float32 arrays. Returns (t, prim), t = tmax on a miss."""
    o = np.asarray(o, np.float32)
    d = np.asarray(d, np.float32)
    tmin = np.asarray(tmin, np.float32)
    tmax = np.asarray(tmax, np.float32)
    valid = np.isfinite(o).all(1) & np.isfinite(d).all(1) & (d != 0).any(1) & (tmax > tmin)
    start = np.ascontiguousarray(np.where(valid[:, None], o + tmin[:, None] * d, 0.0), np.float32)
    dirs = np.ascontiguousarray(np.where(valid[:, None], d, 1.0), np.float32)
    far = np.ascontiguousarray(np.where(valid, np.minimum(tmax - tmin, 1e37), 0.0), np.float32)
    if any_hit:
        geom = scene.run(start, dirs, dists=far.copy(), query="OCCLUDED")
        prim = np.where(valid & (np.asarray(geom) != -1), 0, -1).astype(np.int32)
        return tmax, prim
    res = scene.run(start, dirs, dists=far.copy(), output=1)
    prim = np.where(valid & (res["geomID"] != -1), res["primID"], -1).astype(np.int32)
    t = np.where(prim >= 0, res["tfar"] + tmin, tmax).astype(np.float32)
    return t, prim


def embree_ffi_query(bvh: BVH, o, d, tmin, tmax, level, *, any_hit: bool, packets: int):
    """(t, prim, u, v) of flat rays through the Embree FFI handler (Embree's own distance and
    barycentrics of the hit; t = inf, prim = -1 and u = v = 0 on a miss; prim 0 for an occluded
    ray, whose t, u, v mean nothing).
    `packets`: 1 (every run of consecutive rays one packet of the CPU's native width: 8 with AVX2,
    16 with AVX-512), -1 (a packet where its rays are coherent, else one by one) or 0 (one by
    one)."""
    from ._native import embree_status

    status = embree_status()  # built, loaded and registered once per process
    if not status:
        raise RuntimeError(f"the Embree FFI handler is unavailable: {status.reason}")
    o, d, tmin, tmax = (jax.lax.stop_gradient(x) for x in (o, d, tmin, tmax))  # visibility only
    level = jnp.zeros((0,), jnp.int32) if level is None else jnp.asarray(level, jnp.int32)
    scene = (
        jnp.asarray(bvh.host_id, jnp.int32),
        jnp.asarray(bvh.vertices, jnp.float32),
        jnp.asarray(bvh.faces, jnp.int32),
        jnp.asarray(bvh.tree_faces(), jnp.int32),
    )
    return _ffi_call(bool(any_hit), int(packets), bool(bvh.watertight))(o, d, tmin, tmax, level, *scene)


@functools.cache
def _ffi_call(any_hit: bool, packets: int, robust: bool):
    """The FFI call for one query kind, with a batching rule: under vmap the frames' rays are
    broadcast to the batch and traced in one call against the one (unbatched) scene."""
    from ._native import TARGET

    @jax.custom_batching.custom_vmap
    def call(o, d, tmin, tmax, level, host_id, vertices, faces, first_face):
        n = tmin.shape[0]
        f32, i32 = jax.ShapeDtypeStruct((n,), jnp.float32), jax.ShapeDtypeStruct((n,), jnp.int32)
        out = (f32, i32, f32, f32)
        ffi = jax.ffi.ffi_call(TARGET, out)
        return ffi(
            o,
            d,
            tmin,
            tmax,
            level,
            host_id,
            vertices,
            faces,
            first_face,
            any_hit=np.int32(any_hit),
            packet=np.int32(packets),
            robust=np.int32(robust),
        )

    @call.def_vmap
    def _batched(axis_size, in_batched, o, d, tmin, tmax, level, *scene):
        if any(in_batched[5:]):
            # A batched scene (its own BVH per frame, or one broadcast by a batched lax.cond):
            # one call per frame, each against its own scene.
            args = [
                x if b else jnp.broadcast_to(x, (axis_size, *x.shape))
                for x, b in zip((o, d, tmin, tmax, level, *scene), in_batched, strict=True)
            ]
            return jax.lax.map(lambda a: call(*a), tuple(args)), (True,) * 4
        rays = [o, d, tmin, tmax] + ([level] if level.shape[0] else [])
        rays = [
            x if b else jnp.broadcast_to(x, (axis_size, *x.shape))
            for x, b in zip(rays, in_batched, strict=False)
        ]
        n = rays[2].shape[1]
        flat = [rays[0].reshape(-1, 3), rays[1].reshape(-1, 3), rays[2].reshape(-1), rays[3].reshape(-1)]
        flat.append(rays[4].reshape(-1) if level.shape[0] else level)
        out = call(*flat, *scene)
        return tuple(x.reshape(axis_size, n) for x in out), (True,) * 4

    return call


def whitted_operands(scene, bvh: BVH) -> tuple:
    """The scene operands of the Whitted handler (`embree_whitted`): the BVH (its host id,
    geometry and trees, for the Embree scene) and the scene's arrays in the handler's layout
    (materials as rows of 16, textures concatenated with their shapes, lights as rows of 6).
    Made once where many calls share a scene (the foveated frame's chunks)."""
    f32, i32 = jnp.float32, jnp.int32

    def flat(x, dtype):
        return jnp.zeros((0,), dtype) if x is None else jnp.asarray(x, dtype).reshape(-1)

    textures = tuple(jnp.asarray(t, f32).reshape(-1) for t in scene.textures)
    texels = jnp.concatenate(textures) if textures else jnp.zeros((0,), f32)
    shapes = np.asarray([np.shape(t)[:2] for t in scene.textures], np.int32).reshape(-1)
    materials = jnp.concatenate(
        [jnp.asarray(x, f32) for x in (scene.ka, scene.kd, scene.ks, scene.ke, scene.kr)]
        + [jnp.asarray(scene.ns, f32)[:, None]],
        axis=1,
    )
    lights = jnp.concatenate(
        [
            jnp.asarray(scene.light_position, f32).reshape(-1, 3),
            jnp.asarray(scene.light_color, f32).reshape(-1, 3),
        ],
        axis=1,
    )
    return jax.tree.map(
        jax.lax.stop_gradient,
        (
            jnp.asarray(bvh.host_id, i32),
            jnp.asarray(bvh.vertices, f32),
            jnp.asarray(bvh.faces, i32),
            jnp.asarray(bvh.tree_faces(), i32),
            jnp.asarray(scene.vertices, f32),
            jnp.asarray(scene.faces, i32),
            flat(scene.face_material, i32),
            flat(scene.normals, f32),
            flat(scene.uvs, f32),
            materials,
            flat(scene.texture, i32),
            texels,
            jnp.asarray(shapes, i32),
            lights,
            flat(scene.light_kind, i32),
            flat(scene.ambient, f32),
            jnp.asarray(scene.environment, f32),
        ),
    )


def embree_whitted(
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
):
    """The Whitted integrator's primal through the Embree FFI handler, on flat rays: (radiance
    (N, 3) with NaN/inf kept, rays traced per ray: shadow rays in bits 8 and up, reflection rays
    in bits 0-7). `operands`: the scene's (`whitted_operands`); `d` unit directions; `offset`
    the ray offset in scene units; `recompute`: u, v by Möller-Trumbore on the scene's vertices
    (`RenderConfig.hits` "recomputed"), else Embree's; `packets`: packets of the CPU's width
    where a run of rays is coherent; `tile_width`: the rays are images this wide (rows of it,
    one after another), traced in blocks of four rows, each packet a 4×4 tile of neighbouring
    pixels (0: a flat list); `robust`: the BVH's `watertight`. Not differentiable (the caller's
    custom JVP is)."""
    from ._native import WHITTED_TARGET, embree_status

    status = embree_status()
    if not status:
        raise RuntimeError(f"the Embree FFI handler is unavailable: {status.reason}")
    if not 0 <= max_depth < 256:
        raise ValueError(f"the native integrator counts at most 255 reflections, got max_depth {max_depth}")
    f32 = jnp.float32
    n = active.shape[0]
    rays = (
        jnp.asarray(o, f32).reshape(n, 3),
        jnp.asarray(d, f32).reshape(n, 3),
        jnp.asarray(active, bool).reshape(n),
    )
    rays = jax.tree.map(jax.lax.stop_gradient, rays)
    offset = jax.lax.stop_gradient(jnp.asarray(offset, f32).reshape(1))
    out = (jax.ShapeDtypeStruct((n, 3), f32), jax.ShapeDtypeStruct((n,), jnp.int32))
    call = jax.ffi.ffi_call(WHITTED_TARGET, out, vmap_method="sequential")
    return call(
        *rays,
        *operands,
        offset,
        max_depth=np.int32(max_depth),
        recompute=np.int32(recompute),
        packets=np.int32(packets),
        tile_width=np.int32(tile_width),
        robust=np.int32(robust),
    )


def native_whitted_slots(
    operands: tuple,
    order,
    n_live,
    key_data,
    locality,
    grid,
    cameras,
    *,
    spp: int,
    height: int,
    width: int,
    jitter: bool,
    max_depth: int,
    recompute: bool,
    packets: bool,
    robust: bool = True,
):
    """A foveated frame's live slots made into rays, traced through the Whitted integrator and
    summed into their pixels, in one call of the handler's `WhittedSlots` (CPU only): (sums
    (2·H·W, 3), bad pixel (2·H·W), [primary, shadow, reflection rays, bad samples]). `order`
    the slots in compaction order, the first `n_live` live; `key_data` the frame key's (2,)
    uint32 (threefry2x32; unused without `jitter`); `locality` each locality rank's pixel;
    `grid` the sub-samples' cell centres (S, 2); `cameras` (2, 16) per eye: position, rotation
    (row-major), tan(vfov / 2), aspect, offset. `operands`: the scene's (`whitted_operands`) with
    the ray offset last; `robust`: the BVH's `watertight`. What
    `fovjax.foveate._frame.trace_selection` with the native integrator and `sample_adder`
    compute, in their order. Not differentiable (the caller's custom JVP is)."""
    from ._native import SLOTS_TARGET, embree_status

    status = embree_status()
    if not status:
        raise RuntimeError(f"the native slots integrator needs the Embree FFI handler: {status.reason}")
    if not 0 <= max_depth < 256:
        raise ValueError(f"the native integrator counts at most 255 reflections, got max_depth {max_depth}")
    f32, i32 = jnp.float32, jnp.int32
    n_pixels = 2 * height * width
    out = (
        jax.ShapeDtypeStruct((n_pixels, 3), f32),
        jax.ShapeDtypeStruct((n_pixels,), jnp.bool_),
        jax.ShapeDtypeStruct((4,), i32),
    )
    call = jax.ffi.ffi_call(SLOTS_TARGET, out, vmap_method="sequential")
    return call(
        jnp.asarray(order, i32).reshape(-1),
        jnp.asarray(n_live, i32).reshape(1),
        jnp.asarray(key_data, jnp.uint32).reshape(2),
        jnp.asarray(locality, i32).reshape(-1),
        jnp.asarray(grid, f32).reshape(spp, 2),
        jax.lax.stop_gradient(jnp.asarray(cameras, f32).reshape(2, 16)),
        *operands,
        spp=np.int32(spp),
        height=np.int32(height),
        width=np.int32(width),
        jitter=np.int32(jitter),
        max_depth=np.int32(max_depth),
        recompute=np.int32(recompute),
        packets=np.int32(packets),
        robust=np.int32(robust),
    )


def native_select_samples(
    region,
    probability,
    key_data,
    locality,
    per_region_spp,
    subsample_rank,
    *,
    spp: int,
    rule: int,
    blocks: tuple[int, int],
    budget: int,
):
    """The foveated frame's sample selection through the handler's `SelectSamples` (CPU only):
    (classes int8 (2, S, H, W), compaction order (2·H·W·S), count per class (3), traced mask
    (2, S, H, W), traced samples per pixel (2, H, W), traced samples per region (3)); see
    `fovjax.foveate._frame.selection_with_mask` for what each operand is. `rule`: 0 either,
    1 strict, 2 thesis-measured."""
    from ._native import SELECT_TARGET, embree_status

    status = embree_status()  # builds and registers the handler
    if not status:
        raise RuntimeError(f"the native sample selection needs the Embree FFI handler: {status.reason}")
    _, h, w = region.shape
    out = (
        jax.ShapeDtypeStruct((2, spp, h, w), jnp.int8),
        jax.ShapeDtypeStruct((2 * spp * h * w,), jnp.int32),
        jax.ShapeDtypeStruct((3,), jnp.int32),
        jax.ShapeDtypeStruct((2, spp, h, w), jnp.bool_),
        jax.ShapeDtypeStruct((2, h, w), jnp.int32),
        jax.ShapeDtypeStruct((3,), jnp.int32),
    )
    call = jax.ffi.ffi_call(SELECT_TARGET, out, vmap_method="sequential")
    return call(
        jnp.asarray(region, jnp.int32),
        jax.lax.stop_gradient(jnp.asarray(probability, jnp.float32)),
        jnp.asarray(key_data, jnp.uint32).reshape(2, 2),
        jnp.asarray(locality, jnp.int32),
        jnp.asarray(per_region_spp, jnp.int32),
        jnp.asarray(subsample_rank, jnp.int32),
        spp=np.int32(spp),
        rule=np.int32(rule),
        block_periphery=np.int32(blocks[0]),
        block_outside=np.int32(blocks[1]),
        budget=np.int64(budget),
    )


def native_fill_and_blur(
    sums, n, bad_pixel, region, ecc, bad_color, taps, fovea_deg, *, blocks, blend_deg, blur_fovea
):
    """The foveated frame's reconstruction through the handler's `FillAndBlur` (CPU only): each
    pixel's mean of its traced samples (`sums` (2·H·W, 3) over `n` (2, H, W); `bad_pixel`
    (2·H·W) in `bad_color`), every blank pixel filled from its block's top-left, the 5×5
    Gaussian (`taps`) blended in beyond `fovea_deg` over `blend_deg` (or everywhere with
    `blur_fovea`), both eyes side by side: (image (H, 2W, 3), whether every blank pixel's block
    top-left was traced; where not, the image is not the JAX path's and the caller runs that).
    The arithmetic of `fovjax.foveate._frame.pixel_means`, `fovjax.foveate._fill.fill_blanks` and
    `blur_and_blend` in their order: equal to float rounding. Not differentiable (the caller's
    custom JVP is)."""
    from ._native import FILL_TARGET, embree_status

    status = embree_status()
    if not status:
        raise RuntimeError(f"the native fill and blur needs the Embree FFI handler: {status.reason}")
    _, h, w = region.shape
    out = (jax.ShapeDtypeStruct((h, 2 * w, 3), jnp.float32), jax.ShapeDtypeStruct((1,), jnp.bool_))
    call = jax.ffi.ffi_call(FILL_TARGET, out, vmap_method="sequential")
    f32 = jnp.float32
    image, complete = call(
        jax.lax.stop_gradient(jnp.asarray(sums, f32).reshape(2 * h * w, 3)),
        jnp.asarray(n, jnp.int32),
        jnp.asarray(bad_pixel, bool).reshape(2 * h * w),
        jnp.asarray(region, jnp.int32),
        jax.lax.stop_gradient(jnp.asarray(ecc, f32)),
        jnp.broadcast_to(jnp.asarray(bad_color, f32), (3,)),
        jnp.asarray(taps, f32),
        jax.lax.stop_gradient(jnp.asarray(fovea_deg, f32).reshape(1)),
        block_periphery=np.int32(blocks[0]),
        block_outside=np.int32(blocks[1]),
        blend_deg=np.float32(blend_deg),
        blur_fovea=np.int32(blur_fovea),
    )
    return image, complete[0]


def embree_query(bvh: BVH, o, d, tmin, tmax, *, any_hit: bool):
    """(t, prim) through embreex's Python API and `jax.pure_callback` (the fallback)."""

    def host(host_id, o, d, tmin, tmax):
        key, vertices, faces = host_geometry(host_id)
        scene = embree_scene(key, vertices, faces)
        t, prim = embree_trace_host(scene, o, d, tmin, tmax, any_hit)
        return np.asarray(t, np.float32), np.asarray(prim, np.int32)

    n = o.shape[0]
    shapes = (jax.ShapeDtypeStruct((n,), jnp.float32), jax.ShapeDtypeStruct((n,), jnp.int32))
    return jax.pure_callback(host, shapes, bvh.host_id, o, d, tmin, tmax, vmap_method="sequential")
