"""The whole image against a slow, independent NumPy renderer written from the specification.

`oracle_scene()` (also used by test_render.py and test_render_grad.py, so they share compiled
programs) holds a textured floor, a smooth sphere, a mirror, an emissive target seen in the
mirror and a floating shelf that casts a shadow. `reference_render` re-implements, in float64
with brute-force ray–triangle tests and no code from `fovjax.render`: the stratified sample grid
and pinhole camera, Blinn–Phong with shadow rays, mirror reflections to a maximum depth, the
lat-long environment lookup with the thesis's formulas, bilinear wrapping textures, and the
secondary-ray offset rule of `RenderConfig.ray_offset`.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import fovjax
from fovjax.render import RenderConfig, render, scene_arrays
from fovjax.trace import build_bvh

# Material rows of the oracle scene.
FLOOR, SPHERE, MIRROR, TARGET, SHELF = range(5)
LIGHT = (2.0, 8.0, 2.0)
SIZE = 15  # test image size: odd, so the centre pixel's ray is the optical axis


def _quad(corners):
    c = np.asarray(corners, np.float64)
    return c, np.array([[0, 1, 2], [0, 2, 3]])


def oracle_scene() -> fovjax.Scene:
    """Floor y = 0 (|x|, |z| <= 10, checker texture, u = x/4, v = z/4), unit sphere at (0, 1, 0)
    (an icosphere with exact sphere normals), a mirror x = 6 (|z| <= 2, 0 <= y <= 3) facing -x,
    an emissive green target z = -5 (-1 <= x <= 5) facing +z, a 2 x 2 shelf at y = 2 over
    x in [-6, -4], z in [2, 4]; one white point light at LIGHT."""
    parts = []  # (vertices, faces, normals, uvs, material)
    v, f = _quad([(-10, 0, -10), (-10, 0, 10), (10, 0, 10), (10, 0, -10)])
    parts.append((v, f, np.tile([0.0, 1.0, 0.0], (4, 1)), v[:, [0, 2]] / 4.0, FLOOR))
    ico = trimesh.creation.icosphere(subdivisions=2)
    unit = np.asarray(ico.vertices, np.float64)
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    parts.append((unit + (0.0, 1.0, 0.0), np.asarray(ico.faces), unit, np.zeros((len(unit), 2)), SPHERE))
    v, f = _quad([(6, 0, -2), (6, 3, -2), (6, 3, 2), (6, 0, 2)])
    parts.append((v, f, np.tile([-1.0, 0.0, 0.0], (4, 1)), np.zeros((4, 2)), MIRROR))
    v, f = _quad([(-1, 0, -5), (5, 0, -5), (5, 3, -5), (-1, 3, -5)])
    parts.append((v, f, np.tile([0.0, 0.0, 1.0], (4, 1)), np.zeros((4, 2)), TARGET))
    v, f = _quad([(-6, 2, 2), (-6, 2, 4), (-4, 2, 4), (-4, 2, 2)])
    parts.append((v, f, np.tile([0.0, 1.0, 0.0], (4, 1)), np.zeros((4, 2)), SHELF))
    vertices, faces, normals, uvs, face_material, base = [], [], [], [], [], 0
    for v, f, n, uv, m in parts:
        vertices.append(v)
        faces.append(f + base)
        normals.append(n)
        uvs.append(uv)
        face_material.append(np.full(len(f), m))
        base += len(v)
    checker = np.array([[0.9, 0.4, 0.9, 0.4], [0.4, 0.9, 0.4, 0.9]] * 2, np.float32)
    texture = np.stack([checker, checker * 0.8 + 0.1, checker[::-1]], axis=-1)
    materials = fovjax.make_materials(
        [
            {"name": "floor", "ka": (0.3, 0.3, 0.3), "kd": (0.7, 0.7, 0.6), "ks": (0.2,) * 3, "ns": 8.0,
             "kr": (0.25,) * 3, "texture": 0},
            {"name": "sphere", "ka": (0.2, 0.05, 0.05), "kd": (0.7, 0.2, 0.1), "ks": (0.5,) * 3, "ns": 32.0,
             "kr": (0.3,) * 3},
            {"name": "mirror", "ka": (0.0,) * 3, "kd": (0.0,) * 3, "ks": (0.0,) * 3, "kr": (1.0,) * 3},
            {"name": "target", "ka": (0.0,) * 3, "kd": (0.0,) * 3, "ke": (0.0, 1.0, 0.0)},
            {"name": "shelf", "ka": (0.1,) * 3, "kd": (0.5, 0.5, 0.7), "ks": (0.1,) * 3, "ns": 4.0},
        ]
    )  # fmt: skip
    return fovjax.make_scene(
        np.concatenate(vertices),
        np.concatenate(faces),
        face_material=np.concatenate(face_material),
        materials=materials,
        lights=fovjax.make_lights([LIGHT], [(1.0, 1.0, 1.0)]),
        normals=np.concatenate(normals),
        uvs=np.concatenate(uvs),
        textures=(texture,),
        ambient=(0.2, 0.2, 0.2),
        name="oracle",
    )


def envmap_image() -> np.ndarray:
    """An 8 x 16 lat-long map with a different colour in every texel."""
    rows, cols = np.meshgrid(np.arange(8), np.arange(16), indexing="ij")
    return np.stack([0.2 + rows / 10, 0.3 + cols / 20, 0.5 + 0.3 * np.sin(rows + cols)], -1).astype(
        np.float32
    )


# ---- the reference renderer ----------------------------------------------------------------


def _unit(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n == 0, 1.0, n)


def _intersect(tri, o, d, tmin, tmax, any_hit=False):
    """Möller–Trumbore, float64, inclusive edges: (t, prim, u, v), t = inf on a miss."""
    p0, e1, e2 = tri[None, :, 0], tri[None, :, 1] - tri[None, :, 0], tri[None, :, 2] - tri[None, :, 0]
    o, d = o[:, None], d[:, None]
    pvec = np.cross(d, e2)
    det = np.sum(e1 * pvec, -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        tvec = o - p0
        u = np.sum(tvec * pvec, -1) * inv
        qvec = np.cross(tvec, e1)
        v = np.sum(d * qvec, -1) * inv
        t = np.sum(e2 * qvec, -1) * inv
        ok = (det != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > tmin[:, None]) & (t < tmax[:, None])
    t = np.where(ok, t, np.inf)
    if any_hit:
        return np.isfinite(t).any(axis=1)
    prim = np.argmin(t, axis=1)
    rows = np.arange(len(prim))
    hit = np.isfinite(t[rows, prim])
    return t[rows, prim], np.where(hit, prim, -1), u[rows, prim], v[rows, prim]


def _bilinear_wrap(tex, uv):
    h, w = tex.shape[:2]
    x, y = uv[:, 0] * w - 0.5, uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    i0, j0 = x0.astype(int) % w, y0.astype(int) % h
    i1, j1 = (i0 + 1) % w, (j0 + 1) % h
    return (tex[j0, i0] * (1 - fx) + tex[j0, i1] * fx) * (1 - fy) + (
        tex[j1, i0] * (1 - fx) + tex[j1, i1] * fx
    ) * fy


def _environment(env, d):
    """The thesis's miss program: theta = atan2(dx, dz), phi = pi/2 - acos(dy)."""
    d = _unit(d)
    theta = np.arctan2(d[:, 0], d[:, 2])
    phi = np.pi / 2 - np.arccos(np.clip(d[:, 1], -1, 1))
    u = (theta + np.pi) / (2 * np.pi)
    v = 0.5 * (1 + np.sin(phi))
    h, w = env.shape[:2]
    x, y = u * w - 0.5, (1 - v) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    i0 = x0.astype(int) % w
    i1 = (i0 + 1) % w
    j0, j1 = np.clip(y0.astype(int), 0, h - 1), np.clip(y0.astype(int) + 1, 0, h - 1)
    return (env[j0, i0] * (1 - fx) + env[j0, i1] * fx) * (1 - fy) + (
        env[j1, i0] * (1 - fx) + env[j1, i1] * fx
    ) * fy


def reference_render(scene, camera, *, spp, max_depth, env, ray_offset):
    V = np.asarray(scene.vertices, np.float64)
    F = np.asarray(scene.faces)
    N = np.asarray(scene.normals, np.float64)
    UV = np.asarray(scene.uvs, np.float64)
    FM = np.asarray(scene.face_material)
    mat = {
        k: np.asarray(getattr(scene.materials, k), np.float64) for k in ("ka", "kd", "ks", "ke", "kr", "ns")
    }
    tex_index = np.asarray(scene.materials.texture)
    textures = [np.asarray(t, np.float64) for t in scene.textures]
    lights = scene.lights
    tri = V[F]
    scale = max(np.linalg.norm(V.max(0) - V.min(0)), np.abs(V).max())
    eps = ray_offset * scale

    # camera: stratified cell centres, pinhole through the image plane
    w, h = camera.width, camera.height
    n = int(round(np.sqrt(spp)))
    s = np.arange(spp)
    sx, sy = (s % n + 0.5) / n, (s // n + 0.5) / n
    px = np.arange(w)[None, None, :] + sx[:, None, None] + np.zeros((1, h, 1))
    py = np.arange(h)[None, :, None] + sy[:, None, None] + np.zeros((1, 1, w))
    tan_half = np.tan(np.radians(float(camera.vfov_deg)) / 2)
    off = np.asarray(camera.offset, np.float64)
    cx = (2 * px / w - 1 + off[0]) * tan_half * w / h
    cy = (1 - 2 * py / h + off[1]) * tan_half
    R = np.asarray(camera.rotation, np.float64)
    d = _unit(np.stack([cx, cy, -np.ones_like(cx)], -1).reshape(-1, 3) @ R.T)
    o = np.broadcast_to(np.asarray(camera.position, np.float64), d.shape).copy()

    total = np.zeros_like(d)
    weight = np.ones_like(d)
    alive = np.ones(len(d), bool)
    for depth in range(max_depth + 1):
        idx = np.flatnonzero(alive)
        if not len(idx):
            break
        oi, di, wi = o[idx], d[idx], weight[idx]
        t, prim, u, v = _intersect(tri, oi, di, np.zeros(len(idx)), np.full(len(idx), np.inf))
        miss = prim < 0
        total[idx[miss]] += wi[miss] * _environment(env, di[miss])
        hit = ~miss
        hi, oi, di, wi, prim, u, v = idx[hit], oi[hit], di[hit], wi[hit], prim[hit], u[hit], v[hit]
        b = np.stack([1 - u - v, u, v], -1)[:, :, None]
        p = np.sum(b * tri[prim], axis=1)
        ng = _unit(np.cross(tri[prim, 1] - tri[prim, 0], tri[prim, 2] - tri[prim, 0]))
        sign = np.where(np.sum(ng * di, -1) > 0, -1.0, 1.0)[:, None]
        ng = ng * sign
        ns_ = _unit(np.sum(b * N[F[prim]], axis=1)) * sign
        uv = np.sum(b * UV[F[prim]], axis=1)
        m = FM[prim]
        kd = mat["kd"][m].copy()
        for i, texture in enumerate(textures):
            use = tex_index[m] == i
            kd[use] *= _bilinear_wrap(texture, uv[use])
        local = mat["ka"][m] * np.asarray(scene.ambient, np.float64) + mat["ke"][m]
        for lp, lc, kind in zip(np.asarray(lights.position, np.float64), np.asarray(lights.color, np.float64),
                                np.asarray(lights.kind), strict=True):  # fmt: skip
            point = kind == fovjax.POINT_LIGHT
            to_l = lp[None] - p if point else np.broadcast_to(lp, p.shape)
            dist = np.linalg.norm(to_l, axis=-1) if point else np.full(len(p), np.inf)
            lv = _unit(to_l)
            ndl = np.sum(ns_ * lv, -1)
            want = (ndl > 0) & (np.sum(ng * lv, -1) > 0)
            blocked = np.zeros(len(p), bool)
            if want.any():
                origin = (p + eps * ng)[want]
                blocked[want] = _intersect(
                    tri, origin, lv[want], np.zeros(len(origin)), dist[want], any_hit=True
                )
            vis = want & ~blocked
            hv = _unit(lv - di)
            ndh = np.sum(ns_ * hv, -1)
            spec = np.where(ndh > 0, np.maximum(ndh, 0) ** mat["ns"][m], 0.0)
            local += np.where(vis[:, None], (kd * ndl[:, None] + mat["ks"][m] * spec[:, None]) * lc, 0.0)
        total[hi] += wi * local
        alive[:] = False
        if depth == max_depth:
            break
        wnew = wi * mat["kr"][m]
        go = np.any(wnew != 0, axis=-1)
        r = di - 2 * np.sum(di * ns_, -1)[:, None] * ns_
        into = np.sum(r * ng, -1) <= 0
        r[into] = (di - 2 * np.sum(di * ng, -1)[:, None] * ng)[into]
        o[hi[go]] = (p + eps * ng)[go]
        d[hi[go]] = _unit(r[go])
        weight[hi[go]] = wnew[go]
        alive[hi[go]] = True
    return total.reshape(spp, h, w, 3).mean(axis=0)


# ---- the comparison ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def scene_and_bvh():
    scene = oracle_scene()
    return scene, build_bvh(scene, cache=False)


def main_camera(size=SIZE):
    """Sees the sphere (with the floor and the mirror reflected in it), the textured floor, the
    shelf's shadow region, the mirror (showing the target) and the sky."""
    return fovjax.Camera.look_at((-3.0, 4.0, 9.0), (1.0, 1.0, 0.0), vfov_deg=70.0, width=size, height=size)


def test_whole_image_matches_numpy_reference(scene_and_bvh):
    scene, bvh = scene_and_bvh
    camera = main_camera()
    env = envmap_image()
    config = RenderConfig(max_depth=2)
    frame = render(scene_arrays(scene, envmap=env), camera, spp=16, config=config, bvh=bvh)
    expected = reference_render(scene, camera, spp=16, max_depth=2, env=env.astype(np.float64),
                                ray_offset=config.ray_offset)  # fmt: skip
    assert frame.stats.bad_pixels == 0
    assert frame.stats.reflection_rays > 0 and frame.stats.shadow_rays > 0
    np.testing.assert_allclose(frame.image, expected, rtol=0, atol=1e-4)
    # the scene is not trivially uniform: every kind of surface shows up
    assert np.ptp(expected) > 0.5
