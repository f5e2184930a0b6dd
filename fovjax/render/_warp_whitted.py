"""The Whitted integrator in NVIDIA Warp: the primal of `radiance` on a CUDA device; its oracle
and its derivatives are the JAX integrator (`_integrator.py`), as for the CPU's native one.

One kernel launch per call, one thread per ray: each thread follows its ray through every depth
level (closest hit on the BVH's Warp mesh, the miss colour or the local shading with one shadow
ray per light, then the mirror ray), the same arithmetic as `_integrator.py` and
`_whitted.cc`, per ray: Blinn–Phong or Phong (`RenderConfig.specular`, `specular_payload`),
point, directional and spot lights, diffuse textures (bilinear, wrapping) through per-vertex
UVs, vertex normals, the lat-long environment map, reflections while the weight is nonzero (and
its luminance at least `min_contribution`), `RenderConfig.hits` (u, v by Möller–Trumbore on the
scene's vertices, or on the BVH's for "backend", as the JAX integrator reads them from a Warp
query). A sample's radiance keeps NaN/inf (the caller paints bad samples); a hit face whose
vertices or material are out of range makes its sample NaN, so it is painted and counted as bad
(the kernel cannot raise, and a check on the host would be a sync).

Through XLA's FFI, two calls: `warp_mesh_words` (fovjax.trace: Warp's `jax_callable`, whose
Python side runs on every call, builds the mesh on the device on first use and hands over its
id) and the kernel (Warp's `jax_kernel`: a plain launch, marked command-buffer compatible on
CUDA, so XLA may capture it in a CUDA graph and replay it with no Python). Both register for
XLA's CPU as well: the same kernel runs on Warp's CPU device (one thread, no SIMD), which is how
the suite tests it against the JAX integrator (tests/test_render_warp.py). Warp compiles the
kernel's module on its first launch on a device and keeps it in its kernel cache
(`warp.config.kernel_cache_dir`, `WARP_CACHE_PATH`); `compile_ahead(arch)` fills that cache for
a GPU architecture on a machine without one.
"""

# Warp kernels are Warp's language, not Python's: their parameters are annotated with
# `wp.array(dtype=...)` calls and their values are Warp's types, which the type checker reads as
# Python. No `from __future__ import annotations` here: Warp evaluates the annotations.
# pyright: reportInvalidTypeForm=false, reportArgumentType=false, reportAttributeAccessIssue=false
# pyright: reportCallIssue=false, reportOperatorIssue=false

import functools
import typing

import jax
import jax.numpy as jnp
import numpy as np

from ..native.internal import layout
from ..trace.internal import compile_warp_ahead, mesh_id_target, require_warp, warp_mesh_words
from ._config import LUMINANCE
from ._native import whitted_operands


# Not type-checked by the tests' jaxtyping/beartype import hook (see fovjax/trace/_warp.py).
@functools.cache
@typing.no_type_check
def _kernel():
    """The Whitted kernel as an FFI call (`jax_kernel`), made once per process on first use."""
    wp = require_warp()
    # Codes and weights the kernel reads as constants (Warp captures them from this scope).
    layout_point = layout.LIGHT_KINDS["point"]
    layout_spot = layout.LIGHT_KINDS["spot"]
    layout_phong = layout.SPECULARS["phong"]
    luminance_r, luminance_g, luminance_b = LUMINANCE

    @wp.func
    def unit(v: wp.vec3):
        # `_vec.normalize`: v / |v|, and 0 where v = 0
        n2 = wp.dot(v, v)
        s = 0.0
        if n2 > 0.0:
            s = 1.0 / wp.sqrt(n2)
        return v * s

    @wp.func
    def wrap(a: int, m: int):
        r = a % m
        if r < 0:
            r = r + m
        return r

    @wp.func
    def to_index(x: float):
        # float to int with huge values clamped (no overflow), as the native integrator
        return int(wp.min(wp.max(x, -1.0e9), 1.0e9))

    @wp.func
    def texel(texels: wp.array(dtype=wp.float32), start: int, w: int, row: int, col: int):
        k = start + 3 * (row * w + col)
        return wp.vec3(texels[k], texels[k + 1], texels[k + 2])

    @wp.func
    def bilinear(texels: wp.array(dtype=wp.float32), info: wp.vec3i, uv: wp.vec2):
        # `bilinear_wrap`: texel [row, col] centred on ((col + 0.5) / w, (row + 0.5) / h)
        start = info[0]
        h = info[1]
        w = info[2]
        u = uv[0]
        v = uv[1]
        if not wp.isfinite(u):
            u = 0.0
        if not wp.isfinite(v):
            v = 0.0
        x = u * float(w) - 0.5
        y = v * float(h) - 0.5
        x0 = wp.floor(x)
        y0 = wp.floor(y)
        fx = x - x0
        fy = y - y0
        i0 = wrap(to_index(x0), w)
        j0 = wrap(to_index(y0), h)
        i1 = wrap(i0 + 1, w)
        j1 = wrap(j0 + 1, h)
        row0 = texel(texels, start, w, j0, i0) * (1.0 - fx) + texel(texels, start, w, j0, i1) * fx
        row1 = texel(texels, start, w, j1, i0) * (1.0 - fx) + texel(texels, start, w, j1, i1) * fx
        return row0 * (1.0 - fy) + row1 * fy

    @wp.func
    def environment_at(env: wp.array2d(dtype=wp.vec3), d: wp.vec3):
        # `envmap_lookup`: lat-long, bilinear, wrapping in u and clamping in v
        h = env.shape[0]
        w = env.shape[1]
        bad = wp.vec3(wp.nan, wp.nan, wp.nan)
        if h == 1 and w == 1:
            if not wp.isfinite(d[0] + d[1] + d[2]):
                return bad
            return env[0, 0]
        if not wp.isfinite(d):
            return bad
        n2 = wp.dot(d, d)
        inv = 0.0
        if n2 > 0.0:
            inv = 1.0 / wp.sqrt(n2)
        dx = d[0] * inv
        dy = d[1] * inv
        dz = d[2] * inv
        ax = dx
        az = dz
        if dx == 0.0 and dz == 0.0:  # the poles: theta 0
            ax = 0.0
            az = 1.0
        theta = wp.atan2(ax, az)
        u = (theta + wp.pi) / (2.0 * wp.pi)
        v = 0.5 * (1.0 + wp.min(wp.max(dy, -1.0), 1.0))
        x = u * float(w) - 0.5
        y = (1.0 - v) * float(h) - 0.5
        x0 = wp.floor(x)
        y0 = wp.floor(y)
        fx = x - x0
        fy = y - y0
        i0 = wrap(to_index(x0), w)
        i1 = wrap(i0 + 1, w)
        row = to_index(y0)
        j0 = wp.min(wp.max(row, 0), h - 1)
        j1 = wp.min(wp.max(row + 1, 0), h - 1)
        top = env[j0, i0] * (1.0 - fx) + env[j0, i1] * fx
        bottom = env[j1, i0] * (1.0 - fx) + env[j1, i1] * fx
        return top * (1.0 - fy) + bottom * fy

    @wp.func
    def in_range(face: wp.vec3i, n: int):
        return face[0] >= 0 and face[0] < n and face[1] >= 0 and face[1] < n and face[2] >= 0 and face[2] < n

    @wp.func
    def row3(table: wp.array2d(dtype=wp.float32), r: int, c: int):
        return wp.vec3(table[r, c], table[r, c + 1], table[r, c + 2])

    def fovjax_warp_whitted(
        mesh_words: wp.array(dtype=wp.int32),
        root_group: int,
        origins: wp.array(dtype=wp.vec3),
        directions: wp.array(dtype=wp.vec3),
        active: wp.array(dtype=wp.bool),
        vertices: wp.array(dtype=wp.vec3),
        hit_vertices: wp.array(dtype=wp.vec3),
        faces: wp.array(dtype=wp.vec3i),
        hit_faces: wp.array(dtype=wp.vec3i),
        face_material: wp.array(dtype=wp.int32),
        normals: wp.array(dtype=wp.vec3),
        uvs: wp.array(dtype=wp.vec2),
        materials: wp.array2d(dtype=wp.float32),
        texture: wp.array(dtype=wp.int32),
        texels: wp.array(dtype=wp.float32),
        texture_info: wp.array(dtype=wp.vec3i),
        lights: wp.array2d(dtype=wp.float32),
        light_kind: wp.array(dtype=wp.int32),
        ambient_in: wp.array(dtype=wp.vec3),
        environment: wp.array2d(dtype=wp.vec3),
        offset_in: wp.array(dtype=wp.float32),
        max_depth: int,
        specular: int,
        payload: int,
        min_contribution: float,
        total: wp.array(dtype=wp.vec3),
        shadow_rays: wp.array(dtype=wp.int32),
        reflection_rays: wp.array(dtype=wp.int32),
    ):
        i = wp.tid()
        total[i] = wp.vec3(0.0)
        shadow_rays[i] = 0
        reflection_rays[i] = 0
        if not active[i]:
            return
        mesh = wp.uint64(wp.uint32(mesh_words[0])) | (wp.uint64(wp.uint32(mesh_words[1])) << wp.uint64(32))
        root = -1
        if mesh != wp.uint64(0) and root_group >= 0:
            root = wp.mesh_get_group_root(mesh, root_group)
        offset = offset_in[0]
        ambient = ambient_in[0]
        n_lights = light_kind.shape[0]
        n_faces = faces.shape[0]
        n_materials = texture.shape[0]
        n_textures = texture_info.shape[0]
        has_normals = normals.shape[0] > 0
        has_uvs = uvs.shape[0] > 0
        nan3 = wp.vec3(wp.nan, wp.nan, wp.nan)

        o = origins[i]
        d = directions[i]
        weight = wp.vec3(1.0)
        radiance = wp.vec3(0.0)
        # Counters the depth loop carries: Warp needs them declared as variables, not constants.
        n_shadow = int(0)  # noqa: UP018
        n_reflection = int(0)  # noqa: UP018
        for depth in range(max_depth + 1):
            # The closest hit (a ray with a NaN/inf component or a zero direction misses).
            face = -1
            if mesh != wp.uint64(0) and wp.isfinite(o) and wp.isfinite(d) and wp.length_sq(d) > 0.0:
                query = wp.mesh_query_ray(mesh, o, d, 1.0e37, root)
                if query.result:
                    face = query.face
            if face < 0:
                radiance = radiance + wp.cw_mul(weight, environment_at(environment, d))
                break
            f = wp.min(face, n_faces - 1)
            corners = faces[f]
            hit_corners = hit_faces[wp.min(face, hit_faces.shape[0] - 1)]
            m = face_material[f]
            if not (
                in_range(corners, vertices.shape[0])
                and in_range(hit_corners, hit_vertices.shape[0])
                and (not has_normals or in_range(corners, normals.shape[0]))
                and (not has_uvs or in_range(corners, uvs.shape[0]))
                and m >= 0
                and m < n_materials
            ):
                radiance = nan3  # a bad sample: painted and counted by the caller
                break
            # `hit_geometry`: u, v by Möller–Trumbore
            p0 = hit_vertices[hit_corners[0]]
            e1 = hit_vertices[hit_corners[1]] - p0
            e2 = hit_vertices[hit_corners[2]] - p0
            pvec = wp.cross(d, e2)
            det = wp.dot(e1, pvec)
            u = 0.0
            v = 0.0
            if det != 0.0:
                inv_det = 1.0 / det
                tvec = o - p0
                qvec = wp.cross(tvec, e1)
                u = wp.dot(tvec, pvec) * inv_det
                v = wp.dot(d, qvec) * inv_det
            b0 = 1.0 - u - v
            # `surface_at`: the point, the normals facing the ray, the texture coordinates
            c0 = vertices[corners[0]]
            c1 = vertices[corners[1]]
            c2 = vertices[corners[2]]
            p = c0 * b0 + c1 * u + c2 * v
            n_geo = unit(wp.cross(c1 - c0, c2 - c0))
            sign = 1.0
            if wp.dot(n_geo, d) > 0.0:
                sign = -1.0
            n_geo = n_geo * sign
            n = n_geo
            if has_normals:
                n_interp = unit(normals[corners[0]] * b0 + normals[corners[1]] * u + normals[corners[2]] * v)
                if not (n_interp[0] == 0.0 and n_interp[1] == 0.0 and n_interp[2] == 0.0):
                    n = n_interp * sign
            # `diffuse_color`: Kd times the material's texture
            kd = row3(materials, m, 3)
            t_index = texture[m]
            if t_index >= 0 and t_index < n_textures:
                uv = wp.vec2(0.0, 0.0)
                if has_uvs:
                    uv = uvs[corners[0]] * b0 + uvs[corners[1]] * u + uvs[corners[2]] * v
                kd = wp.cw_mul(kd, bilinear(texels, texture_info[t_index], uv))
            ks = row3(materials, m, 6)
            shininess = materials[m, 15]
            local = wp.cw_mul(row3(materials, m, 0), ambient) + row3(materials, m, 9)
            # `_shadow_rays` and `_light_sum`: one shadow ray per light above both normals
            start = p + offset * n_geo
            lit = wp.vec3(0.0)
            for l in range(n_lights):
                kind = light_kind[l]
                positional = kind == layout_point or kind == layout_spot
                position = row3(lights, l, 0)
                to_light = position
                if positional:
                    to_light = position - p
                l_dir = unit(to_light)
                n_dot_l = wp.dot(n, l_dir)
                spot = 1.0
                if kind == layout_spot:
                    c = -wp.dot(row3(lights, l, 6), l_dir)
                    cos_inner = lights[l, 9]
                    cos_outer = lights[l, 10]
                    width = cos_inner - cos_outer
                    if width <= 0.0:
                        width = 1.0
                    spot = 0.0
                    if c >= cos_inner:
                        spot = 1.0
                    elif c > cos_outer:
                        spot = (c - cos_outer) / width
                if not (n_dot_l > 0.0 and wp.dot(n_geo, l_dir) > 0.0 and spot > 0.0):
                    continue
                n_shadow += 1
                far = 1.0e37
                if positional:
                    far = wp.min(wp.length(to_light), 1.0e37)
                if wp.mesh_query_ray_anyhit(mesh, start, l_dir, far, root):
                    continue
                cosine = 0.0
                if specular == layout_phong:  # eq. 1: the light mirrored about n, v = -d
                    mirrored = (2.0 * n_dot_l) * n - l_dir
                    cosine = -wp.dot(mirrored, d)
                else:
                    cosine = wp.dot(n, unit(l_dir - d))
                spec = 0.0
                if cosine > 0.0:
                    spec = wp.pow(2.0, shininess * wp.log2(cosine))
                if payload != 0:  # §4.4.3: the specular times the shadow ray's payload, n·l
                    spec = spec * n_dot_l
                color = row3(lights, l, 3) * spot
                lit = lit + wp.cw_mul(kd * n_dot_l + ks * spec, color)
            local = local + lit
            radiance = radiance + wp.cw_mul(weight, local)
            # `_finish_shading`: the mirror ray while its weight is nonzero (and bright enough)
            weight = wp.cw_mul(weight, row3(materials, m, 12))
            if depth >= max_depth or (weight[0] == 0.0 and weight[1] == 0.0 and weight[2] == 0.0):
                break
            if min_contribution > 0.0:  # §2.5.2's contribution cut-off
                luminance = luminance_r * weight[0] + luminance_g * weight[1] + luminance_b * weight[2]
                if not (luminance >= min_contribution):
                    break
            reflected = d - 2.0 * wp.dot(d, n) * n
            if wp.dot(reflected, n_geo) <= 0.0:
                reflected = d - 2.0 * wp.dot(d, n_geo) * n_geo
            o = start
            d = unit(reflected)
            n_reflection += 1
        total[i] = radiance
        shadow_rays[i] = n_shadow
        reflection_rays[i] = n_reflection

    # The FFI target is named after the function (Warp appends "_0").
    fovjax_warp_whitted.__qualname__ = fovjax_warp_whitted.__name__
    kernel = wp.kernel(fovjax_warp_whitted, enable_backward=False)
    # Warp loads the kernel's module on the current JAX device while a program is traced (its
    # default), so that on a GPU the load never falls inside a CUDA graph XLA is capturing.
    return wp.jax_kernel(kernel, num_outputs=3, vmap_method="sequential")


def warp_integrator_target() -> str:
    """The XLA FFI target name of the Whitted kernel's call (registered for "cpu" and "CUDA")."""
    return _kernel().name


def warp_targets() -> tuple[str, str]:
    """Every FFI target a program with the Warp integrator calls (the mesh id's and the
    kernel's), e.g. for `jax.export`'s `DisabledSafetyCheck.custom_call`."""
    return mesh_id_target(), warp_integrator_target()


def _texture_info(scene) -> np.ndarray:
    """(T, 3) int32: each texture's first texel's index in the concatenated texels, height, width
    (`whitted_operands` concatenates them in order)."""
    shapes = [np.shape(t)[:2] for t in scene.textures]
    sizes = [3 * h * w for h, w in shapes]
    starts = np.cumsum([0, *sizes])[:-1]
    return np.asarray([(s, h, w) for s, (h, w) in zip(starts, shapes, strict=True)], np.int32).reshape(-1, 3)


def warp_integrate(scene, bvh, o, d, active, offset, config):
    """(radiance (*batch, 3) with NaN/inf kept, shadow rays, reflection rays) of unit-direction
    rays `o`, `d` where `active`, through one launch of the Warp kernel on the device of the
    platform being lowered: the primal of `_integrate` as `_jax_integrate` computes it (the
    same signature), `offset` the ray offset in scene units. Not differentiable (the caller's
    custom JVP is)."""
    batch = active.shape
    n = int(np.prod(batch))
    if n == 0:
        return jnp.zeros(batch + (3,), jnp.float32), jnp.int32(0), jnp.int32(0)
    f32 = jnp.float32
    (
        _,
        bvh_vertices,
        bvh_faces,
        _,
        vertices,
        faces,
        face_material,
        normals,
        uvs,
        materials,
        texture,
        texels,
        _,
        lights,
        light_kind,
        ambient,
        environment,
    ) = whitted_operands(scene, bvh)
    rays = (
        jnp.asarray(o, f32).reshape(n, 3),
        jnp.asarray(d, f32).reshape(n, 3),
        jnp.asarray(active, bool).reshape(n),
    )
    rays = jax.tree.map(jax.lax.stop_gradient, rays)
    hit_vertices = vertices if config.hits == "recomputed" else bvh_vertices
    call = _kernel()
    total, shadow, reflection = call(
        warp_mesh_words(bvh),
        -1 if bvh.roots is None else 0,  # a merged BVH without levels: tree 0, as the queries
        *rays,
        vertices,
        hit_vertices,
        faces,
        bvh_faces,
        face_material,
        normals.reshape(-1, 3),
        uvs.reshape(-1, 2),
        materials,
        texture,
        texels,
        jnp.asarray(_texture_info(scene)),
        lights,
        light_kind,
        ambient.reshape(1, 3),
        environment,
        jax.lax.stop_gradient(jnp.asarray(offset, f32).reshape(1)),
        config.max_depth,
        layout.SPECULARS[config.specular],
        int(config.specular_payload),
        float(config.min_contribution),
        launch_dims=(n,),
        output_dims={"total": (n,), "shadow_rays": (n,), "reflection_rays": (n,)},
    )
    n_shadow = jnp.sum(shadow, dtype=jnp.int32)
    n_reflection = jnp.sum(reflection, dtype=jnp.int32)
    return total.reshape(batch + (3,)), n_shadow, n_reflection


def compile_ahead(arch: int, module_dir: str | None = None) -> list:
    """Compile the kernel's Warp module, and those of the mesh id and the ray queries
    (fovjax.trace), for the CUDA architecture `arch` (90: H100, H200), as PTX and as CUBIN (Warp
    picks one by the driver's version), into Warp's kernel cache (`WARP_CACHE_PATH`) or
    `module_dir`, on any machine (Warp's compiler for CUDA needs no GPU): a GPU with that cache
    loads them instead of compiling them on its first frame. Returns the paths Warp wrote."""
    wp = require_warp()
    module = _kernel().kernel.module
    paths = [
        path
        for use_ptx in (True, False)
        for path in wp.compile_aot_module(module, arch=arch, module_dir=module_dir, use_ptx=use_ptx)
    ]
    return paths + compile_warp_ahead(arch, module_dir)
