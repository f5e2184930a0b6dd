"""The Warp integrator (fovjax/render/_warp_whitted.py: the Whitted loop in one Warp kernel launch,
the primal of `radiance` on an NVIDIA GPU) against the JAX integrator, its oracle, on this
machine's default JAX device: Warp's CPU device here (one thread), CUDA where benchmarks/gpu.sh
runs this file. The same kernel serves both; the CUDA lowering of whole frame programs is
tests/test_trace_native.py's `test_every_frame_program_lowers_for_cuda`.

The scene, a hall of facing mirrors built here: inter-reflection to depth 5 (each depth changes
the image), an occluder beyond a point light (a shadow ray not bounded at the light would stop
at it), a spot light, a directional light, textured and untextured materials read through
per-vertex UVs, bent vertex normals, a lat-long environment map for the rays that leave. The
oracle traces with the same Warp queries (`backend="warp"`), so both integrators meet the same
faces; they differ in where they round (XLA's fusions, Warp's per-thread code).

Agreement as tests/test_render_native.py holds the native integrator to it: the ray counts are
equal, kind by kind, bad samples included, and every sample is the same to float rounding
(SAME_RADIANCE plus the specular exponent's amplification of a rounding of n·h).
"""

from __future__ import annotations

import dataclasses

import _extras
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _frames import N_DOT_H_ULPS, SAME_RADIANCE

import fovjax
from fovjax.render import RenderConfig, StereoRig, radiance, scene_arrays, stereo_sample_rays
from fovjax.render._integrator import _finish_radiance, _jax_integrate, scene_scale
from fovjax.render._native import warp_integrator_plan
from fovjax.render._vec import normalize
from fovjax.scene import DIRECTIONAL_LIGHT, POINT_LIGHT, SPOT_LIGHT
from fovjax.trace import build_bvh, occluded

_extras.require("warp", module_level=True)
from fovjax.render._warp_whitted import warp_integrate, warp_targets  # noqa: E402

EYE_W, EYE_H = 32, 24
DEPTH = 4
# A change of the image "far above rounding": 100x the tolerance of a sample of radiance ~1.
CHANGE = 1e-2
HALF_WIDTH, LENGTH, TOP = 1.3, (-14.0, 3.0), 3.0
LIGHT = (0.3, 2.4, -4.0)  # the point light the occluder lies beyond
OCCLUDER_Y = 2.9


def _quad(corners, material, uvs=None, bend=0.0):
    """A planar quad's four corners, two triangles' material, per-corner UVs and per-corner
    normals: the quad's, each tilted by `bend` along a fixed direction per corner."""
    corners = np.asarray(corners, np.float32)
    normal = np.cross(corners[1] - corners[0], corners[2] - corners[0])
    normal /= np.linalg.norm(normal)
    tilt = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]], np.float32) * bend
    normals = normal[None] + tilt
    return corners, [material, material], np.asarray(uvs or [(0.0, 0.0)] * 4, np.float32), normals


def hall_scene():
    """Two facing mirrors along a textured floor (one mirror textured), a panel over a point
    light, a glossy box with bent vertex normals (a faint mirror too: its reflections follow
    the bent normals), and two point lights, a spot and a directional light.
    18 triangles."""
    x, (back, front) = HALF_WIDTH, LENGTH
    quads = [
        _quad(
            [(-x, 0, front), (x, 0, front), (x, 0, back), (-x, 0, back)],
            0,
            [(-0.9, 1.35), (0.9, 1.35), (0.9, -6.3), (-0.9, -6.3)],
        ),
        _quad([(-x, 0, front), (-x, 0, back), (-x, TOP, back), (-x, TOP, front)], 1),
        _quad(
            [(x, 0, front), (x, TOP, front), (x, TOP, back), (x, 0, back)],
            2,
            [(0, 0), (0, 1.3), (5.1, 1.3), (5.1, 0)],
        ),
        _quad(
            [(x, OCCLUDER_Y, z) for x, z in ((-1.2, -1.5), (1.2, -1.5), (1.2, -6.5), (-1.2, -6.5))],
            4,
        ),
    ]
    (x0, y0, z0), (x1, y1, z1) = (-0.45, 0.0, -3.3), (0.15, 0.7, -2.55)  # the box, open below
    for face in (
        [(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)],
        [(x1, y0, z0), (x0, y0, z0), (x0, y1, z0), (x1, y1, z0)],
        [(x0, y0, z0), (x0, y0, z1), (x0, y1, z1), (x0, y1, z0)],
        [(x1, y0, z1), (x1, y0, z0), (x1, y1, z0), (x1, y1, z1)],
        [(x0, y1, z1), (x1, y1, z1), (x1, y1, z0), (x0, y1, z0)],
    ):
        quads.append(_quad(face, 3, bend=0.35))
    materials = fovjax.make_materials(
        [
            {"kd": (0.8, 0.8, 0.8), "ka": (0.3, 0.3, 0.3), "ks": (0.2,) * 3, "ns": 12.0, "texture": 0},
            {"kd": (0.1, 0.1, 0.12), "ka": (0.1,) * 3, "ks": (0.4,) * 3, "ns": 60.0, "kr": (0.8, 0.75, 0.7)},
            {
                "kd": (0.12, 0.1, 0.1),
                "ka": (0.1,) * 3,
                "ks": (0.3,) * 3,
                "ns": 40.0,
                "kr": (0.7, 0.8, 0.75),
                "texture": 1,
            },
            {
                "kd": (0.7, 0.3, 0.2),
                "ka": (0.5, 0.2, 0.1),
                "ks": (0.5,) * 3,
                "ns": 24.0,
                "kr": (0.3, 0.25, 0.2),
            },
            {"kd": (0.3, 0.5, 0.3), "ka": (0.2, 0.3, 0.2)},
        ]
    )
    lights = fovjax.make_lights(
        [LIGHT, (-0.5, 1.8, 1.0), (0.35, 1.0, 0.25), (0.1, 2.7, -9.0)],
        [(0.9, 0.85, 0.8), (0.4, 0.45, 0.5), (0.3, 0.3, 0.25), (0.8, 0.7, 0.5)],
        [POINT_LIGHT, POINT_LIGHT, DIRECTIONAL_LIGHT, SPOT_LIGHT],
        direction=[(0, 0, 0), (0, 0, 0), (0, 0, 0), (0.15, -1.0, 0.2)],
        cone_deg=[(180, 180), (180, 180), (180, 180), (20.0, 35.0)],
    )
    rng = np.random.default_rng(0)
    return fovjax.make_scene(
        np.concatenate([q[0] for q in quads]),
        np.concatenate([np.array([[0, 1, 2], [0, 2, 3]]) + 4 * i for i in range(len(quads))]),
        face_material=np.concatenate([q[1] for q in quads]),
        materials=materials,
        lights=lights,
        uvs=np.concatenate([q[2] for q in quads]),
        normals=np.concatenate([q[3] for q in quads]).astype(np.float32),
        textures=(rng.random((5, 7, 3)).astype(np.float32), rng.random((4, 3, 3)).astype(np.float32)),
        name="hall",
    )


@pytest.fixture(scope="module")
def hall():
    """The hall's arrays (with a random lat-long environment), its BVH, and rays: a stereo rig
    looking obliquely across the mirrors (its rays bounce from one mirror to the other along the
    hall), every 7th ray inactive and one with a NaN direction (a bad sample)."""
    scene = hall_scene()
    env = np.random.default_rng(1).random((6, 12, 3)).astype(np.float32)
    arrays = scene_arrays(scene, envmap=env)
    rig = StereoRig.look_at((0.0, 1.5, 2.5), (-1.3, 1.2, 0.8), eye_width=EYE_W, eye_height=EYE_H)
    rays = stereo_sample_rays(rig, None, 1, jax.random.key(7))
    d = np.array(rays.directions, np.float32)
    d[0, 0, 5, 9] = np.nan
    active = np.ones(d.shape[:-1], bool)
    active.reshape(-1)[::7] = False
    return arrays, build_bvh(scene, cache=False), (np.asarray(rays.origins), d, active)


_PROGRAMS: dict = {}


def _program(integrate, config, bvh):
    """`radiance`'s work around one integrator (`_jax_integrate` or `warp_integrate`): the rays
    normalised, the integrator, bad samples painted and every count; compiled once per
    integrator, configuration and BVH."""
    key = (integrate, config, id(bvh))
    if key not in _PROGRAMS:
        _PROGRAMS[key] = _compile(integrate, config, bvh)
    return _PROGRAMS[key]


def _compile(integrate, config, bvh):

    def run(arrays, o, d_raw, active):
        o = jnp.asarray(o)
        d = normalize(d_raw)
        valid = jnp.all(jnp.isfinite(o), -1) & jnp.all(jnp.isfinite(d_raw), -1) & jnp.any(d != 0, -1)
        offset = config.ray_offset * scene_scale(arrays)
        total, n_shadow, n_reflection = integrate(arrays, bvh, o, d, active, offset, config)
        return _finish_radiance(total, active, valid, config, n_shadow, n_reflection)

    return jax.jit(run)


def _both(arrays, bvh, rays, config):
    """(Warp's, the JAX integrator's) `Radiance` of `rays` under `config`."""
    warp = _program(warp_integrate, config, bvh)(arrays, *rays)
    reference = _program(_jax_integrate, config, bvh)(arrays, *rays)
    return warp, reference


def assert_agree(warp, reference, arrays) -> None:
    """Equal counts kind by kind (bad samples too), every sample to float rounding."""
    assert [int(c) for c in warp.counts] == [int(c) for c in reference.counts]
    np.testing.assert_array_equal(np.asarray(warp.bad), np.asarray(reference.bad))
    rtol = SAME_RADIANCE + N_DOT_H_ULPS * 2.0**-24 * float(np.nanmax(np.asarray(arrays.ns)))
    np.testing.assert_allclose(np.asarray(warp.rgb), np.asarray(reference.rgb), rtol=rtol, atol=SAME_RADIANCE)


def test_the_occluder_lies_beyond_the_light(hall):
    """What the panel is for: from the floor below it, the shadow ray bounded at the light is
    unblocked, and the same ray unbounded meets the panel."""
    _, bvh, _ = hall
    xs, zs = np.meshgrid(np.linspace(-1.0, 1.0, 5), np.linspace(-6.0, -2.0, 6))
    points = np.stack([xs.ravel(), np.full(xs.size, 1e-3), zs.ravel()], -1).astype(np.float32)
    to_light = np.asarray(LIGHT, np.float32) - points
    distance = np.linalg.norm(to_light, axis=-1)
    directions = to_light / distance[:, None]
    lit = ~np.asarray(occluded(bvh, points, directions, distance, backend="warp"))
    unbounded = np.asarray(occluded(bvh, points, directions, backend="warp"))
    assert lit.sum() >= 0.8 * len(points)  # the box shades a few
    assert unbounded[lit].all()


def test_warp_agrees_with_the_jax_integrator(hall):
    """The default shading (Blinn–Phong) at depth 4: equal counts, every sample to float
    rounding; the hall exercises what it is meant to (most rays meet a mirror, four lights'
    shadow rays, the NaN ray a bad sample painted in both)."""
    arrays, bvh, rays = hall
    warp, reference = _both(arrays, bvh, rays, RenderConfig(max_depth=DEPTH, backend="warp"))
    assert_agree(warp, reference, arrays)
    counts = reference.counts
    n_active = int(rays[2].sum())
    assert int(counts.primary) == n_active - 1  # the NaN ray is traced but not a valid primary
    assert int(counts.reflection) > n_active // 2
    assert int(counts.shadow) > 2 * n_active
    assert int(counts.bad) == 1 and np.asarray(reference.rgb).std() > 0.05
    assert (np.asarray(warp.rgb)[~rays[2]] == 0).all()


def test_every_depth_adds_its_bounces(hall):
    """Warp at depths 0..5: each depth changes the image far above rounding and traces more
    reflection rays, so the kernel follows the mirrors to the depth asked for (depth 4 being
    the oracle's, above)."""
    arrays, bvh, rays = hall
    previous = None
    for depth in range(6):
        out = _program(warp_integrate, RenderConfig(max_depth=depth, backend="warp"), bvh)(arrays, *rays)
        rgb, reflection = np.asarray(out.rgb), int(out.counts.reflection)
        if previous is None:
            assert reflection == 0
        else:
            assert np.abs(rgb - previous[0]).max() > CHANGE, depth
            assert reflection > previous[1], depth
        previous = rgb, reflection


def test_every_shading_option_agrees(hall):
    """Phong's (r·v)^Ns, the specular payload, the contribution cut-off (it ends some paths
    before max_depth 5) and the backend's barycentrics, with one material's Ks NaN: the samples
    that see it lit are bad in both, painted and counted alike."""
    arrays, bvh, rays = hall
    ks = np.array(arrays.ks, np.float32)
    ks[3] = np.nan  # the box
    arrays = dataclasses.replace(arrays, ks=ks)
    options = dict(specular="phong", specular_payload=True, min_contribution=0.3, hits="backend")
    config = RenderConfig(max_depth=5, backend="warp", **options)
    warp, reference = _both(arrays, bvh, rays, config)
    assert_agree(warp, reference, arrays)
    assert int(reference.counts.bad) > 10
    uncut = _program(warp_integrate, dataclasses.replace(config, min_contribution=0.0), bvh)(arrays, *rays)
    assert int(warp.counts.reflection) < int(uncut.counts.reflection)


def test_a_face_out_of_range_makes_bad_samples(hall):
    """Scene arrays whose faces name vertices that do not exist (the BVH traced the original
    faces): the kernel does not read past the vertices; every sample that hits them is bad."""
    arrays, bvh, rays = hall
    faces = np.array(arrays.faces, copy=True)
    faces[:, 0] = np.asarray(arrays.vertices).shape[0] + 5
    out = _program(warp_integrate, RenderConfig(max_depth=1, backend="warp"), bvh)(
        dataclasses.replace(arrays, faces=faces), *rays
    )
    assert int(out.counts.bad) > 0.5 * int(rays[2].sum())
    painted = np.asarray(out.rgb)[np.asarray(out.bad)]
    np.testing.assert_array_equal(painted, [(1.0, 0.0, 1.0)] * int(out.counts.bad))


def test_the_plan_names_what_runs_on_a_gpu():
    """'auto' runs the Warp integrator on CUDA where Warp is installed; 'jax', 'native' (a CPU
    program) and another ray backend keep the JAX integrator there, each saying why."""
    from fovjax.render import describe_integrator

    assert warp_integrator_plan(RenderConfig()).cuda
    assert warp_integrator_plan(RenderConfig(backend="warp")).cuda
    for config, why in (
        (RenderConfig(integrator="jax"), "integrator 'jax'"),
        (RenderConfig(integrator="native"), "for the CPU alone"),
        (RenderConfig(backend="jax"), "the ray backend is 'jax'"),
    ):
        plan = warp_integrator_plan(config)
        assert not plan.cuda and why in plan.reason
        assert describe_integrator(config, "cuda") == f"jax ({plan.reason})"
    assert describe_integrator(RenderConfig(), "cuda").startswith("warp (")


def test_radiance_runs_the_kernel_on_cuda_only(hall):
    """`radiance` with integrator 'auto': its CUDA lowering calls the mesh id and the kernel
    (and no CPU handler); its CPU lowering does not call the kernel."""
    arrays, bvh, (o, d, _) = hall
    fn = jax.jit(lambda a, o, d: radiance(a, bvh, o, d, config=RenderConfig(max_depth=1)).rgb)
    checks = [jax.export.DisabledSafetyCheck.custom_call(t) for t in warp_targets()]
    cuda = jax.export.export(fn, platforms=("cuda",), disabled_checks=checks)(arrays, o, d).mlir_module()
    assert all(t in cuda for t in warp_targets())
    assert "fovjax_embree" not in cuda and "callback" not in cuda
    cpu = fn.trace(arrays, o, d).lower(lowering_platforms=("cpu",)).as_text()
    assert warp_targets()[1] not in cpu


def test_the_foveated_frames_slots_in_one_launch(hall):
    """The foveated frame's slots on a GPU (`warp_slot_sums`: every slot's ray made at once, the
    live ones traced in one launch, summed into their pixels) against the CPU's one native call
    (`traced_sums` through the native integrator, which tests/test_render_native.py holds to the
    chunked JAX path at every depth): the same samples traced, kind by kind, and every pixel's
    sum to float rounding, with the slots beyond the live count left out."""
    _extras.require("embreex")
    from fovjax.foveate import Foveation
    from fovjax.foveate._frame import eccentricities, selection_with_mask, traced_sums, warp_slot_sums
    from fovjax.native import status

    if not status():
        pytest.fail(f"the native handlers are unavailable: {status().reason}", pytrace=False)
    arrays, bvh, _ = hall
    rig = StereoRig.look_at((0.0, 1.5, 2.5), (-1.3, 1.2, 0.8), eye_width=EYE_W, eye_height=EYE_H)
    fov = Foveation(20.0, 40.0, spp=1)
    cameras = rig.eye_cameras(None)
    budget = 2 * EYE_W * EYE_H

    def select(gaze, key):
        ecc = eccentricities(cameras, gaze, fov)
        return selection_with_mask(ecc, key, foveation=fov, budget=budget, native=False)[0]

    sel = jax.jit(select)(jnp.asarray([[0.3, 0.4], [0.55, 0.5]]), jax.random.key(3))
    key = jax.random.key(8)

    def native(a, sel):
        config = RenderConfig(max_depth=DEPTH, integrator="native")
        out = traced_sums(a, bvh, cameras, key, sel, config=config, budget=budget)
        return out.consumed, (out.primary, out.shadow, out.reflection)

    config = RenderConfig(max_depth=DEPTH, backend="warp")
    warp = jax.jit(lambda a, sel: warp_slot_sums(a, bvh, cameras, key, sel, config=config, budget=budget))(
        arrays, sel
    )
    (sums, bad_pixel, n_bad), counts = warp
    (ref_sums, ref_bad_pixel, ref_n_bad), ref_counts = jax.jit(native)(arrays, sel)
    assert [int(c) for c in (*counts, n_bad)] == [int(c) for c in (*ref_counts, ref_n_bad)]
    assert int(counts[0]) == int(sel.n_traced) < budget  # some slots are not live
    np.testing.assert_array_equal(np.asarray(bad_pixel), np.asarray(ref_bad_pixel))
    rtol = SAME_RADIANCE + N_DOT_H_ULPS * 2.0**-24 * float(np.max(np.asarray(arrays.ns)))
    np.testing.assert_allclose(np.asarray(sums), np.asarray(ref_sums), rtol=rtol, atol=SAME_RADIANCE)
    assert int(counts[2]) > int(counts[0]) // 2 and np.asarray(ref_sums).std() > 0.05


def test_a_bare_scene_is_ambient_emission_and_background():
    """No lights, textures, UVs or vertex normals, a constant background (the kernel's empty
    operands): a hit is Ka·ambient + Ke, a miss the background, a mirror adds Kr times what it
    reflects (here the background: it faces away from everything)."""
    quad = np.array([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], np.float32)
    scene = fovjax.make_scene(
        np.concatenate([quad, quad + (0, 0, -1)]),
        np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]),
        face_material=np.array([0, 0, 1, 1]),
        materials=fovjax.make_materials(
            [{"ka": (0.5, 0.25, 1.0), "ke": (0.1, 0.2, 0.3), "kr": (0.5, 0.5, 0.5)}, {"ka": 1.0}]
        ),
        lights=fovjax.make_lights(np.zeros((0, 3)), np.zeros((0, 3))),
        ambient=(0.4, 0.4, 0.4),
    )
    background = (0.2, 0.3, 0.4)
    arrays = scene_arrays(scene, background=background)
    assert arrays.num_lights == 0 and arrays.normals is None and not arrays.textures
    o = np.array([[0.2, 0.1, 2.0], [3.0, 0.0, 2.0]], np.float32)  # onto the quad, past it
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]], np.float32)
    config = RenderConfig(max_depth=2, backend="warp")
    out = _program(warp_integrate, config, build_bvh(scene, cache=False))(arrays, o, d, np.ones(2, bool))
    hit = 0.4 * np.array([0.5, 0.25, 1.0]) + np.array([0.1, 0.2, 0.3]) + 0.5 * np.array(background)
    np.testing.assert_allclose(np.asarray(out.rgb), [hit, background], rtol=1e-6)
    assert [int(c) for c in out.counts] == [2, 0, 1, 0]
