"""The native integrator (`RenderConfig.integrator`) against the JAX integrator, its oracle.

The native integrator is the native handlers' Whitted loop per ray (fovjax/render/_whitted.cc):
the same arithmetic as fovjax/render/_integrator.py, written per ray in C++, rounded its own
way. Two scenes:

- `featured`: the spheres scene with every shading feature the loop implements: vertex normals,
  a texture read through per-vertex UVs (bilinear, wrapping), a lat-long environment map, a
  point light and a directional light, a curved mirror (compared at depth 3).
- `corridor`: a tiny scene built here for what the spheres cannot show: two facing mirrors
  (every reflection depth up to 5 changes the image, asserted of the oracle), an occluder
  beyond a point light (a shadow ray that is not bounded at the light would stop at it),
  textured and untextured materials, two point lights and a directional one; compared at
  depth 4 in the full frame and at every depth 0..5 in the foveated frame's slots.

Both the full frame (`radiance`, the handler's image tiles) and the foveated frame's slots
(`traced_sums`: rays made, traced and summed in one native call) are compared. The renderer's
hand-computed oracles (tests/test_render.py) run through whichever integrator "auto" picks,
the native one here.

Agreement: the ray counts are equal, kind by kind, and every sample is the same to float
rounding between two programs (`assert_native_radiance`: tests/_frames.py's SAME_RADIANCE,
widened where a specular exponent multiplies a rounding difference). A ray within float
rounding of a triangle's edge or of a light's horizon could take the other side in one
integrator only; no ray of these fixed sets does, and such a ray would fail this file rather
than pass as a fraction of samples allowed off. `python tests/native_mutations.py` checks that
this file fails for each of a set of one-line mistakes in the native integrator.
"""

from __future__ import annotations

import dataclasses
import functools

import _extras
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _frames import assert_native_radiance

import fovjax
import fovjax.scenes
from fovjax.foveate import Foveation
from fovjax.native import status as embree_status
from fovjax.render import RenderConfig, StereoRig, radiance, render_stereo, scene_arrays, stereo_sample_rays
from fovjax.scene import DIRECTIONAL_LIGHT, POINT_LIGHT
from fovjax.trace import build_bvh

_extras.require("embreex", module_level=True)
if not embree_status():  # embreex is here but the handler did not build (e.g. no C++ compiler)
    if _extras.required():
        pytest.fail(f"the Embree FFI handler is unavailable: {embree_status().reason}", pytrace=False)
    pytest.skip(
        f"the Embree FFI handler is unavailable here: {embree_status().reason}", allow_module_level=True
    )


def assert_same_counts(native, reference) -> None:
    """The same rays traced, kind by kind (`RayCounts`, or sequences in one order)."""
    a = [int(x) for x in native]
    b = [int(x) for x in reference]
    assert a == b, (a, b)


# ---- the corridor: inter-reflection, an occluder beyond a light, several lights --------------

CORRIDOR_W = CORRIDOR_H = 32
# Compared at depth 4, so that one bounce fewer (3) and one more (5) both change the image: the
# oracle's images at depths 0..5 are each asserted to differ from the one before.
CORRIDOR_DEPTH = 4
CORRIDOR_DEPTHS = range(6)
# A change of the image "far above rounding": 100x the tolerance of a sample of radiance ~1.
CHANGE = 1e-2
MISS = 1e3  # a missing ray's point, in scene sizes along it (Weier's `MISS_DISTANCE`)
HALF_WIDTH, LENGTH = 1.3, (-14.0, 3.0)  # mirrors at x = ±HALF_WIDTH, from z = LENGTH[0] to LENGTH[1]
LIGHT = (0.3, 2.4, -4.0)  # the point light the occluder lies beyond
OCCLUDER_Y = 2.9


def _quad(corners, material, uvs=None):
    """Two triangles of a planar quad (corners in order), its material and per-corner UVs."""
    return np.asarray(corners, np.float32), [material, material], np.asarray(uvs or [(0.0, 0.0)] * 4)


def corridor_scene():
    """Two facing mirrors (Kr 0.8/0.75/0.7 and 0.7/0.8/0.75, one textured) along a textured
    floor, an untextured glossy box between them, a point light under a panel (the occluder
    beyond it: every floor point below the panel sees the light, and the line past the light
    meets the panel), a second point light and a directional light. 26 triangles."""
    x, (back, front), top = HALF_WIDTH, LENGTH, 3.0
    quads = [
        # floor: its texture repeats about twice across and eight times along
        _quad(
            [(-x, 0, front), (x, 0, front), (x, 0, back), (-x, 0, back)],
            0,
            [(-0.9, 1.35), (0.9, 1.35), (0.9, -6.3), (-0.9, -6.3)],
        ),
        _quad([(-x, 0, front), (-x, 0, back), (-x, top, back), (-x, top, front)], 1),  # mirror, untextured
        _quad(
            [(x, 0, front), (x, top, front), (x, top, back), (x, 0, back)],
            2,
            [(0, 0), (0, 1.3), (5.1, 1.3), (5.1, 0)],
        ),
        _quad(
            [
                (-1.2, OCCLUDER_Y, -1.5),
                (1.2, OCCLUDER_Y, -1.5),
                (1.2, OCCLUDER_Y, -6.5),
                (-1.2, OCCLUDER_Y, -6.5),
            ],
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
        quads.append(_quad(face, 3))
    vertices = np.concatenate([q[0] for q in quads])
    faces = np.concatenate([np.array([[0, 1, 2], [0, 2, 3]]) + 4 * i for i in range(len(quads))])
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
            {"kd": (0.7, 0.3, 0.2), "ka": (0.5, 0.2, 0.1), "ks": (0.5,) * 3, "ns": 24.0},
            {"kd": (0.3, 0.5, 0.3), "ka": (0.2, 0.3, 0.2)},
        ]
    )
    lights = fovjax.make_lights(
        [LIGHT, (-0.5, 1.8, 1.0), (0.35, 1.0, 0.25)],
        [(0.9, 0.85, 0.8), (0.4, 0.45, 0.5), (0.3, 0.3, 0.25)],
        [POINT_LIGHT, POINT_LIGHT, DIRECTIONAL_LIGHT],
    )
    rng = np.random.default_rng(0)
    return fovjax.make_scene(
        vertices,
        faces,
        face_material=np.concatenate([q[1] for q in quads]),
        materials=materials,
        lights=lights,
        uvs=np.concatenate([q[2] for q in quads]).astype(np.float32),
        textures=(rng.random((5, 7, 3)).astype(np.float32), rng.random((4, 3, 3)).astype(np.float32)),
        name="corridor",
    )


@pytest.fixture(scope="module")
def corridor():
    """The corridor's arrays, BVH and a stereo rig looking obliquely across the mirrors (its
    rays bounce from one mirror to the other along the corridor)."""
    scene = corridor_scene()
    rig = StereoRig.look_at((0.0, 1.5, 2.5), (-1.3, 1.2, 0.8), eye_width=CORRIDOR_W, eye_height=CORRIDOR_H)
    return scene_arrays(scene), build_bvh(scene, cache=False), rig


def test_the_occluder_lies_beyond_the_light(corridor):
    """What the corridor is for: from the floor below the panel, the shadow ray bounded at the
    light is unblocked, and the same ray unbounded meets the panel."""
    from fovjax.trace import occluded

    _, bvh, _ = corridor
    xs, zs = np.meshgrid(np.linspace(-1.0, 1.0, 5), np.linspace(-6.0, -2.0, 6))
    points = np.stack([xs.ravel(), np.full(xs.size, 1e-3), zs.ravel()], -1).astype(np.float32)
    to_light = np.asarray(LIGHT, np.float32) - points
    distance = np.linalg.norm(to_light, axis=-1)
    directions = to_light / distance[:, None]
    bounded = np.asarray(occluded(bvh, points, directions, distance))
    unbounded = np.asarray(occluded(bvh, points, directions))
    lit = ~bounded
    assert lit.sum() >= 0.8 * len(points)  # the box shades a few
    assert unbounded[lit].all()


def test_corridor_full_frame_native_agrees(corridor):
    """`radiance` through the native integrator and through the JAX one, on the corridor at
    CORRIDOR_DEPTH: equal counts, every sample to float rounding."""
    arrays, bvh, rig = corridor
    rays = stereo_sample_rays(rig, None, 1, jax.random.key(7))
    out = {}
    for integrator in ("native", "jax"):
        config = RenderConfig(max_depth=CORRIDOR_DEPTH, integrator=integrator)
        fn = jax.jit(lambda a, o, d, c=config: radiance(a, bvh, o, d, config=c))
        out[integrator] = fn(arrays, rays.origins, rays.directions)
    native, reference = out["native"], out["jax"]
    assert_native_radiance(native.rgb, reference.rgb, arrays)
    assert_same_counts(native.counts, reference.counts)
    counts = reference.counts
    assert int(counts.primary) == 2 * CORRIDOR_W * CORRIDOR_H
    assert int(counts.reflection) > int(counts.primary) // 2  # most rays meet a mirror
    assert int(counts.shadow) > 2 * int(counts.primary)  # three lights
    assert int(counts.bad) == 0 and np.asarray(reference.rgb).std() > 0.05


def _corridor_selection(rig):
    """The corridor's eye cameras and one foveated selection (20°/40°, SPP 1, off-centre
    gazes, the JAX selection): (cameras, selection, traced samples per pixel, slot budget)."""
    from fovjax.foveate._frame import eccentricities, selection_with_mask

    fov = Foveation(20.0, 40.0, spp=1)
    cameras = rig.eye_cameras(None)
    ecc = eccentricities(cameras, jnp.asarray([[0.3, 0.4], [0.55, 0.5]]), fov)
    budget = 2 * CORRIDOR_W * CORRIDOR_H
    select = functools.partial(selection_with_mask, foveation=fov, budget=budget, native=False)
    sel, _, n, _ = jax.jit(select)(ecc, jax.random.key(3))
    return cameras, sel, n, budget


def test_corridor_slots_native_agree_at_every_depth(corridor):
    """The foveated frame's slots (`traced_sums`) through the native handler and through the
    JAX integrator, at every depth 0..5: equal counts, every pixel to float rounding; and each
    depth changes the oracle's image (far above rounding) and adds reflection rays, so a wrong
    number of bounces cannot pass.

    One compiled JAX program serves every depth: per-class depth limits (`ShadingClasses`, the
    per-region fidelity's tables, traced values) cap its reflections below `max_depth` 5, as
    `RenderConfig.max_depth` does (tests/test_fidelity.py: the class path at full tables is the
    plain one). The native programs are one handler call each."""
    from fovjax.foveate._frame import traced_sums
    from fovjax.render.internal import SHADOWS_ALL, ShadingClasses

    arrays, bvh, rig = corridor
    cameras, sel, n, budget = _corridor_selection(rig)
    traced = np.asarray(n).reshape(-1) > 0
    key = jax.random.key(8)

    def sums(a, sel, config, classes=None):
        out = traced_sums(a, bvh, cameras, key, sel, config=config, budget=budget, classes=classes)
        (rgb, bad, n_bad) = out.consumed
        return rgb, jnp.stack([out.primary, out.shadow, out.reflection, n_bad])

    oracle = jax.jit(
        lambda a, sel, depth: sums(
            a,
            sel,
            RenderConfig(max_depth=max(CORRIDOR_DEPTHS), integrator="jax"),
            ShadingClasses(depth, jnp.full(3, SHADOWS_ALL, jnp.int32)),
        )
    )
    previous = None
    for depth in CORRIDOR_DEPTHS:
        config = RenderConfig(max_depth=depth, integrator="native")
        native = jax.jit(lambda a, sel, c=config: sums(a, sel, c))(arrays, sel)
        reference = oracle(arrays, sel, jnp.full(3, depth, jnp.int32))
        assert_native_radiance(native[0], reference[0], arrays)
        assert_same_counts(native[1], reference[1])
        rgb, counts = np.asarray(reference[0]), np.asarray(reference[1])
        assert counts[0] == int(sel.n_traced) and counts[3] == 0
        assert (rgb[~traced] == 0).all()
        if previous is not None:
            assert np.abs(rgb - previous[0]).max() > CHANGE, depth  # this depth's bounces show
            assert counts[2] > previous[1][2], depth
        previous = rgb, counts
    assert traced.sum() > 0.25 * budget
    assert previous[1][1] > 2 * previous[1][0]  # three lights' shadow rays


# Per-region shading tables (`ShadingClasses`: reflection depth and shadow mode per region,
# fovea / periphery / outside), each with a region at depth 0 against one at full depth and a
# region without shadow rays against one with all of them; "brightest" in one region.
CLASS_TABLES = [
    ((0, CORRIDOR_DEPTH, 2), ("brightest", "none", "all")),
    ((CORRIDOR_DEPTH, 2, 0), ("all", "brightest", "none")),
]


def _modes(names):
    from fovjax.render.internal import SHADOWS_ALL, SHADOWS_BRIGHTEST, SHADOWS_NONE

    codes = {"all": SHADOWS_ALL, "brightest": SHADOWS_BRIGHTEST, "none": SHADOWS_NONE}
    return jnp.asarray([codes[n] for n in names], jnp.int32)


def test_corridor_slots_with_shading_classes_agree(corridor):
    """Per-region fidelity in the native slots integrator (`traced_sums` with `ShadingClasses`,
    a slot's class its pixel's region) against the chunked JAX path with the same tables: equal
    ray counts, every pixel to float rounding, for tables in which each lever changes the
    oracle's image far above rounding (a region's depth, a region's shadow rays, "brightest"
    against "all" and "none"), with the brightest light first and, its colour swapped with
    another light's, second. The tables are traced operands: every table runs in the one
    compiled native program."""
    from fovjax.foveate._frame import traced_sums
    from fovjax.render.internal import ShadingClasses

    arrays, bvh, rig = corridor
    cameras, sel, n, budget = _corridor_selection(rig)
    key = jax.random.key(8)
    traces = {"native": 0, "jax": 0}

    def sums(a, depth, shadows, integrator):
        traces[integrator] += 1
        config = RenderConfig(max_depth=CORRIDOR_DEPTH, integrator=integrator)
        classes = ShadingClasses(depth, shadows)
        out = traced_sums(a, bvh, cameras, key, sel, config=config, budget=budget, classes=classes)
        (rgb, bad, n_bad) = out.consumed
        return rgb, jnp.stack([out.primary, out.shadow, out.reflection, n_bad])

    native = jax.jit(functools.partial(sums, integrator="native"))
    oracle = jax.jit(functools.partial(sums, integrator="jax"))
    depth0 = jnp.zeros(3, jnp.int32)
    assert "fovjax_whitted_slots" in native.lower(arrays, depth0, depth0).as_text()
    colours = np.asarray(arrays.light_color)
    brightest = int(np.argmax(colours.sum(axis=1)))
    swapped = colours.copy()
    swapped[[brightest, 1 - brightest]] = colours[[1 - brightest, brightest]]
    full_depth = jnp.full(3, CORRIDOR_DEPTH, jnp.int32)
    region = np.asarray(sel.region).reshape(-1)
    traced = np.asarray(n).reshape(-1) > 0
    for light_color in (colours, swapped):
        a = dataclasses.replace(arrays, light_color=jnp.asarray(light_color))
        for depths, names in CLASS_TABLES:
            depth, shadows = jnp.asarray(depths, jnp.int32), _modes(names)
            got, want = native(a, depth, shadows), oracle(a, depth, shadows)
            assert_native_radiance(got[0], want[0], arrays)
            assert_same_counts(got[1], want[1])
            rgb = np.asarray(want[0])
            # Each lever shows in the oracle, in the region that pulls it.
            shallow = int(np.argmin(depths))
            deep = np.asarray(oracle(a, full_depth, shadows)[0])
            assert np.abs(rgb - deep)[traced & (region == shallow)].max() > CHANGE, (depths, names)
            for mode in ("none", "brightest"):
                k = names.index(mode)
                others = ("all", "none") if mode == "brightest" else ("all",)
                for other in others:
                    moved = _modes([other if i == k else m for i, m in enumerate(names)])
                    changed = np.asarray(oracle(a, depth, moved)[0])
                    assert np.abs(rgb - changed)[traced & (region == k)].max() > CHANGE, (names, k, other)
            assert int(np.asarray(want[1])[0]) == int(sel.n_traced)
    assert traces == {"native": 1, "jax": 1}  # new tables (and colours) recompile nothing


def test_corridor_slots_with_levels_of_detail_agree(corridor):
    """Geometry level of detail per region in the native slots integrator: the corridor and a
    second level whose box stands elsewhere, merged into one BVH and one set of scene arrays as
    `Fidelity.lod` merges a scene's levels; each slot, its shadow rays and its reflections are
    traced against its region's tree (`ShadingClasses.level`) and shaded with that tree's
    triangles. Against the chunked JAX path with the same tables: equal ray counts, every
    pixel to float rounding, for tables under which the second level changes the oracle's image
    in its regions far above rounding."""
    import equinox as eqx

    from fovjax.foveate._frame import traced_sums
    from fovjax.foveate._lod import _merged_geometry, _with_geometry
    from fovjax.render.internal import ShadingClasses, scene_scale
    from fovjax.trace import merge_bvhs

    arrays, _, rig = corridor
    scene = corridor_scene()
    moved = np.asarray(scene.vertices).copy()
    moved[-20:] += np.asarray([0.5, 0.3, 0.6], np.float32)  # the box: its five quads come last
    other = eqx.tree_at(lambda s: s.vertices, scene, moved)
    merged = _with_geometry(arrays, _merged_geometry([scene, other]))
    bvh = merge_bvhs([build_bvh(scene, cache=False), build_bvh(other, cache=False)])
    scale = scene_scale(arrays)  # the finest level's, as the foveated frame passes it
    cameras, sel, n, budget = _corridor_selection(rig)
    region = np.asarray(sel.region).reshape(-1)
    traced = np.asarray(n).reshape(-1) > 0

    def sums(level, shadows, integrator):
        config = RenderConfig(max_depth=2, integrator=integrator)
        classes = ShadingClasses(jnp.full(3, 2, jnp.int32), shadows, level=level)
        out = traced_sums(
            merged,
            bvh,
            cameras,
            jax.random.key(8),
            sel,
            config=config,
            budget=budget,
            classes=classes,
            scale=scale,
        )
        return out.consumed[0], jnp.stack([out.primary, out.shadow, out.reflection, out.consumed[2]])

    native = jax.jit(functools.partial(sums, integrator="native"))
    oracle = jax.jit(functools.partial(sums, integrator="jax"))
    shadows = _modes(("all", "brightest", "all"))
    level0 = oracle(jnp.zeros(3, jnp.int32), shadows)[0]
    for levels in ((0, 1, 1), (1, 0, 1)):
        level = jnp.asarray(levels, jnp.int32)
        got, want = native(level, shadows), oracle(level, shadows)
        assert_native_radiance(got[0], want[0], arrays)
        assert_same_counts(got[1], want[1])
        for k in range(3):
            if levels[k]:  # the second level shows where it is traced
                assert np.abs(np.asarray(want[0] - level0))[traced & (region == k)].max() > CHANGE, (
                    levels,
                    k,
                )


def test_slots_keep_the_chunked_path_for_a_texture_level_of_detail():
    """A texture level of detail per region is not written natively: `slots_why_not` names it
    (the frame takes the chunked path), and the handler's wrapper refuses its tables."""
    from fovjax.foveate._frame import slots_in_one_call, slots_why_not
    from fovjax.foveate._native import native_whitted_slots
    from fovjax.render.internal import SHADOWS_ALL, ShadingClasses

    config = RenderConfig(max_depth=2, integrator="native")
    depth, shadows = np.full(3, 2, np.int32), np.full(3, SHADOWS_ALL, np.int32)
    plain = ShadingClasses(depth, shadows, level=np.zeros(3, np.int32))
    textured = ShadingClasses(
        depth, shadows, texture_level=np.zeros(3, np.float32), texture_cone=np.ones(3, np.float32)
    )
    key = jax.random.key(0)
    assert slots_why_not(config, key, plain, 8, 8, 1) == "" and slots_in_one_call(config, key, plain, 8, 8, 1)
    why = slots_why_not(config, key, textured, 8, 8, 1)
    assert "texture_lod" in why and not slots_in_one_call(config, key, textured, 8, 8, 1)
    assert "off" in slots_why_not(RenderConfig(integrator="jax"), key, None, 8, 8, 1)
    with pytest.raises(ValueError, match="texture level of detail"):
        native_whitted_slots(
            (),
            np.zeros(4, np.int32),
            4,
            np.zeros(2, np.uint32),
            np.arange(16),
            np.zeros((1, 2)),
            np.zeros((2, 16)),
            spp=1,
            height=4,
            width=4,
            jitter=False,
            max_depth=2,
            recompute=True,
            packets=False,
            region=np.zeros((2, 4, 4), np.int32),
            classes=textured,
        )


def test_corridor_slots_with_shading_classes_derivatives(corridor):
    """The derivative of the native slots with shading classes is the replay of the paths it
    stored, which hold what the classes left out (no reflection past a region's depth, a light
    whose shadow ray was not traced counted as unblocked): the chunked JAX path's, in Kd and in
    the lights' colours."""
    from fovjax.foveate._frame import traced_sums
    from fovjax.render.internal import ShadingClasses

    arrays, bvh, rig = corridor
    cameras, sel, _, budget = _corridor_selection(rig)
    classes = ShadingClasses(jnp.asarray([0, 2, 1], jnp.int32), _modes(("brightest", "none", "all")))
    kd, colour = jnp.asarray(arrays.kd), jnp.asarray(arrays.light_color)
    tangents = (
        jax.random.normal(jax.random.key(1), kd.shape, jnp.float32),
        jax.random.normal(jax.random.key(2), colour.shape, jnp.float32),
    )

    def sums(kd, colour, integrator):
        config = RenderConfig(max_depth=2, integrator=integrator)
        a = dataclasses.replace(arrays, kd=kd, light_color=colour)
        out = traced_sums(a, bvh, cameras, None, sel, config=config, budget=budget, classes=classes)
        return out.consumed[0]

    def both(kd, colour):
        return tuple(
            jax.jvp(functools.partial(sums, integrator=name), (kd, colour), tangents)
            for name in ("native", "jax")
        )

    lowered = jax.jit(both).lower(kd, colour)
    assert "fovjax_whitted_slots" in lowered.as_text()
    (native, d_native), (chunked, d_jax) = lowered.compile()(kd, colour)
    assert_native_radiance(native, chunked, arrays)
    assert np.abs(np.asarray(d_jax)).max() > 0.1
    np.testing.assert_allclose(np.asarray(d_native), np.asarray(d_jax), rtol=1e-5, atol=1e-5)


def test_methods_pixels_through_the_native_handlers_are_the_chunked_path(corridor):
    """The other foveation methods' traced pixels (`trace_pixels`: Guenter 2012, Patney 2016 and
    Weier 2016 all trace through it) on a CPU: selected by the native selection handler and
    traced and summed by the native slots handler, against the JAX selection and chunk loop: the
    same slots, masks, per-pixel and per-region counts (integers), every pixel's mean to float rounding and
    the same ray counts, at SPP 4 with jitter along the corridor's mirrors at one reflection
    level (a bounce skipped, or a pixel's sub-sample left out, changes the means far above
    rounding: asserted of the reflections the oracle traced). Weier's points (`first_hit_points`:
    each pixel's sub-sample 0's hit), which the slots handler keeps from the rays it traces, are
    the chunk loop's own queries' to float rounding (a pixel's other sub-samples hit elsewhere;
    a miss lies `MISS` scene sizes away, untraced pixels hold 0)."""
    from fovjax.foveate._frame import eccentricities
    from fovjax.foveate._methods._sparse import trace_pixels
    from fovjax.render.internal import scene_scale

    arrays, bvh, rig = corridor
    spp = 4
    fov = Foveation(20.0, 40.0, spp=spp)
    cameras = rig.eye_cameras(None)
    ecc = eccentricities(cameras, jnp.asarray([[0.3, 0.4], [0.55, 0.5]]), fov)
    trace_pixel = jax.random.uniform(jax.random.key(5), ecc.shape) < 0.4
    key = jax.random.key(8)

    def pixels(integrator):
        config = RenderConfig(max_depth=1, integrator=integrator)
        out = trace_pixels(
            arrays,
            bvh,
            cameras,
            key,
            ecc,
            trace_pixel,
            foveation=fov,
            spp=spp,
            jitter=True,
            config=config,
            first_points=MISS,
        )
        k = out.selection.n_traced
        live = jnp.where(jnp.arange(out.selection.order.shape[0]) < k, out.selection.order, -1)
        c = out.counts
        counts = jnp.stack([c.primary, c.shadow, c.reflection, c.bad])
        return out.prefill, out.n, out.mask, live, out.first_points, counts, out.by_region

    lowered = jax.jit(lambda: (pixels("native"), pixels("jax"))).lower()
    text = lowered.as_text()
    assert "fovjax_whitted_slots" in text and "fovjax_select_samples" in text
    native, reference = lowered.compile()()
    # counts, mask, slots, samples by region: integers
    for a, b in zip(native[1:4] + native[6:], reference[1:4] + reference[6:], strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    by_region = np.asarray(native[6])
    assert by_region.sum() == np.asarray(native[1]).sum() and (by_region > 0).sum() >= 2
    assert_native_radiance(native[0], reference[0], arrays)
    assert_same_counts(native[5], reference[5])
    n, counts = np.asarray(reference[1]), np.asarray(reference[5])
    points, traced = np.asarray(reference[4]), np.asarray(trace_pixel)
    far = MISS * float(scene_scale(arrays))
    assert (points[~traced] == 0).all() and (np.asarray(native[4])[~traced] == 0).all()
    distance = np.linalg.norm(points - np.asarray(cameras[0].position), axis=-1)[traced]
    assert (distance < 0.5 * far).mean() > 0.5 and (distance > 0.5 * far).any()  # the open end: misses
    np.testing.assert_allclose(np.asarray(native[4]), points, rtol=1e-5, atol=1e-5 * far / MISS)
    np.testing.assert_array_equal(n, spp * np.asarray(trace_pixel))  # every sub-sample of a traced pixel
    assert counts[0] == n.sum() and counts[2] > 0.25 * counts[0]  # the mirrors' reflections
    assert (np.asarray(reference[0])[n == 0] == 0).all()


# The pre-filter's cases: (eye height, width, gaze (x, y) in the eye's pixels, inner and middle
# radii, blur σ of the middle and coarse rates): the rates' rings cut by the image's edges; a
# window wider than the image (every tap clamped); gaze None: the left eye's eccentricity 0
# (the inner rate over the whole image: no filter computed), the right eye's 100 (the coarse
# rate everywhere, no inner or middle rate).
PREFILTER_CASES = [
    # Rows wider than the blurs' strips of columns (each plane of the window too), the rates'
    # rectangles narrower than the image.
    (21, 290, (140.0, 10.0), (30.0, 80.0), (1.0, 2.0)),
    (13, 9, (4.0, 6.0), (2.0, 4.0), (2.0, 4.0)),
    (100, 15, None, (4.0, 9.0), (1.0, 2.0)),  # columns taller than the handler's bands of rows
    (110, 40, (20.0, 55.0), (10.0, 25.0), (1.0, 2.0)),  # the rates' rectangles across bands of rows
]


def _blur64(values, taps):
    """`gaussian_blur` in float64: down the columns, then along the rows, edges repeated."""
    r = len(taps) // 2
    _, h, w, _ = values.shape
    padded = np.pad(values, ((0, 0), (r, r), (0, 0), (0, 0)), mode="edge")
    values = sum(t * padded[:, u : u + h] for u, t in enumerate(taps))
    padded = np.pad(values, ((0, 0), (0, 0), (r, r), (0, 0)), mode="edge")
    return sum(t * padded[:, :, u : u + w] for u, t in enumerate(taps))


def _prefilter_rounding_bound(image, w_inner, w_middle, sigmas, *, window_per_sigma, max_gain):
    """Per element of `prefilter_and_blend`'s result (H, 2W, 3), how far float32 rounding can
    move it, to first order: the contrast gain is s_I / s_B with s² = E[x²] − E[x]², and a
    window's sums of positive terms round by at most (terms)·u of their value (u = 2⁻²⁴), so
    each variance moves by up to γ·(E[x²] + E[x]²), its deviation by that over 2s (or its
    square root, near 0), the gain by the ratio's first-order change (by up to max_gain − 1
    where s_B is that close to the flat threshold: the two sides may choose differently), and
    the result by |B − m| times the gain's change. Computed in float64 from the same inputs."""
    from fovjax.foveate._methods._patney import FLAT_STD, LUMINANCE, blur_taps

    u = 2.0**-24
    image = np.asarray(image, np.float64)
    lum = np.asarray(LUMINANCE)
    bounds = []
    for sigma in sigmas:
        blur, window = blur_taps(sigma), blur_taps(window_per_sigma * sigma)
        gamma = (4 * (len(blur) + len(window)) + 16) * u
        b = _blur64(image, blur)
        m = _blur64(b, window)
        li, lb = image @ lum, b @ lum
        stats = _blur64(np.stack([li, li * li, lb * lb], -1), window)
        mean_i, mean_i2, mean_b2 = stats[..., 0], stats[..., 1], stats[..., 2]
        mean_b = m @ lum
        deviations = []
        for second, first in ((mean_i2, mean_i), (mean_b2, mean_b)):
            d_var = gamma * (second + first * first)
            sd = np.sqrt(np.maximum(second - first * first, 0.0))
            deviations.append((sd, np.minimum(d_var / np.maximum(2 * sd, 1e-300), np.sqrt(d_var))))
        (s_i, ds_i), (s_b, ds_b) = deviations
        gain = np.clip(s_i / np.maximum(s_b, FLAT_STD), 1.0, max_gain)
        d_gain = (ds_i + gain * ds_b) / np.maximum(s_b - ds_b, FLAT_STD)
        d_gain = np.where(np.abs(s_b - FLAT_STD) <= ds_b, max_gain - 1.0, np.minimum(d_gain, max_gain - 1.0))
        bounds.append(np.abs(b - m) * d_gain[..., None])
    wi, wm = np.asarray(w_inner)[..., None], np.asarray(w_middle)[..., None]
    bound = (1 - wi) * ((1 - wm) * bounds[1] + wm * bounds[0])
    return np.concatenate([bound[0], bound[1]], axis=1)


@pytest.mark.parametrize(
    "case", PREFILTER_CASES, ids=lambda c: f"{c[0]}x{c[1]}-{'rings' if c[2] else 'whole'}"
)
def test_patney_prefilter_native_is_the_jax_path(case):
    """Patney 2016's pre-filters and the blend of its rates (`prefilter_and_blend`) through the
    pre-filter handler, which computes each rate's filter only in the rectangle where it shows,
    against the JAX filters over the whole image: equal to float rounding (1e-4 of a value, and
    where the contrast gain's E[x²] − E[x]² cancels, within twice the rounding that the
    cancellation can amplify, `_prefilter_rounding_bound`; both far below a filter's effect),
    and the derivative is the JAX path's. The filters change the image where a coarser rate
    shows and the inner rate's pixels are the image's."""
    from fovjax.foveate._methods._guenter import layer_weights
    from fovjax.foveate._methods._patney import prefilter_and_blend

    h, w, gaze, radii, sigmas = case
    k = jax.random.split(jax.random.key(h * w), 2)
    image = jax.random.uniform(k[0], (2, h, w, 3)) * jnp.asarray([1.0, 0.5, 2.0])
    y, x = jnp.mgrid[0:h, 0:w]
    if gaze is None:
        ecc = jnp.stack([jnp.zeros((h, w)), jnp.full((h, w), 100.0)])
        # Rows alternately dark and bright: a row read in place of its neighbour shows.
        image = image * (1.0 + 9.0 * (y % 2))[None, :, :, None]
    else:
        gx, gy = gaze
        ecc = jnp.stack([jnp.hypot(x - gx, y - gy), jnp.hypot(x - w + 1 - gx, y - gy)])  # degrees = pixels
    w_inner, w_middle = layer_weights(ecc, jnp.asarray(radii), 1.5)
    tangent = jax.random.normal(k[1], image.shape)

    def both(image, w_inner, w_middle):
        def run(native):
            return lambda im: prefilter_and_blend(
                im, w_inner, w_middle, sigmas, window_per_sigma=2.0, max_gain=4.0, native=native
            )

        # Under differentiation both sides are the JAX path's (its JVP gives the primal too).
        return [run(n)(image) for n in (True, False)], [
            jax.jvp(run(n), (image,), (tangent,))[1] for n in (True, False)
        ]

    lowered = jax.jit(both).lower(image, w_inner, w_middle)
    assert "fovjax_patney_prefilter" in lowered.as_text()
    (native, reference), (d_native, d_reference) = lowered.compile()(image, w_inner, w_middle)
    native, reference = np.asarray(native), np.asarray(reference)
    assert native.shape == (h, 2 * w, 3)
    bound = _prefilter_rounding_bound(image, w_inner, w_middle, sigmas, window_per_sigma=2.0, max_gain=4.0)
    # The rounding bound is far below what the filters change (the comparison is one).
    changed = bound > 0
    effect = np.abs(reference - np.concatenate([image[0], image[1]], axis=1))
    assert np.median(bound[changed]) < 0.01 * np.median(effect[changed])
    allowed = 1e-4 * np.abs(reference) + 1e-5 + 2 * bound
    worst = np.unravel_index(np.argmax(np.abs(native - reference) - allowed), native.shape)
    assert np.all(np.abs(native - reference) <= allowed), (worst, native[worst], reference[worst])
    assert np.isfinite(np.asarray(d_reference)).all()
    np.testing.assert_allclose(np.asarray(d_native), np.asarray(d_reference), rtol=1e-4, atol=1e-5)
    eyes = np.stack([native[:, :w], native[:, w:]])
    inner = np.asarray(w_inner) == 1.0
    np.testing.assert_array_equal(eyes[inner], np.asarray(image)[inner])
    if not inner.all():
        assert np.abs(eyes[~inner] - np.asarray(image)[~inner]).max() > 0.05


def _taa_rounding_bound(image, *, gamma, keep):
    """Per element of `taa_blend`'s result, how far float32 rounding can move it: the clip
    box's half-width is gamma·std, std = sqrt(E[x²] − E[x]²) over the 3×3 neighbourhood, whose
    few roundings move the variance by up to 16·u·E[x²] (u = 2⁻²⁴) and so the deviation by that
    over 2·std, or its square root where the neighbourhood is flat (held blocks, where the
    square root amplifies it most); the clipped history moves by gamma times that, the result
    by `keep` times that. Computed in float64 from the image blended."""
    x = np.asarray(image, np.float64)
    _, h, w, _ = x.shape
    padded = np.pad(x, ((0, 0), (1, 1), (1, 1), (0, 0)), mode="edge")
    taps = [padded[:, dy : dy + h, dx : dx + w] for dy in range(3) for dx in range(3)]
    mean = sum(taps) / 9.0
    squares = sum(t * t for t in taps) / 9.0
    sd = np.sqrt(np.maximum(squares - mean * mean, 0.0))
    d_var = 16 * 2.0**-24 * squares
    d_sd = np.minimum(d_var / np.maximum(2 * sd, 1e-300), np.sqrt(d_var))
    return keep * gamma * d_sd


def test_patney_history_blend_native_is_the_jax_path():
    """Patney 2016's shading rates blended and its history blend (`rates_and_history`) through
    the native TAA handler against the JAX functions: equal to float rounding (within the
    rounding that a flat neighbourhood's square root amplifies, `_taa_rounding_bound`), with
    pixels with and without a history, odd sizes (the border's taps clamped, a single row), a
    history far outside the neighbourhood (clipped), the inner rate everywhere (the traced image
    itself), the rates' held blocks at strides that do not divide the image (flat
    neighbourhoods) and an image taller than the handler's bands of rows; the derivative is the
    JAX functions', finite where a neighbourhood is flat."""
    from fovjax.foveate._methods._guenter import layer_weights
    from fovjax.foveate._methods._patney import TaaHistory, hold, rate_blend, rates_and_history

    cases = []  # (pixels, w_inner, w_middle, strides, history)
    for i, shape in enumerate([(2, 13, 9, 3), (1, 5, 7, 3), (1, 1, 2, 3)]):
        k = jax.random.split(jax.random.key(10 + i), 3)
        color = 3.0 * jax.random.uniform(k[1], shape) - 1.0  # partly outside the clip box
        history = TaaHistory(color, jax.random.bernoulli(k[2], 0.7, shape[:3]))
        ones = jnp.ones(shape[:3])
        cases.append((jax.random.uniform(k[0], shape), ones, 0 * ones, (2, 3), history))
    for i, (h, w, strides) in enumerate([(13, 18, (2, 4)), (10, 7, (3, 5)), (37, 11, (2, 4))]):
        k = jax.random.split(jax.random.key(20 + i), 3)
        y, x = jnp.mgrid[0:h, 0:w]
        ecc = jnp.stack([jnp.hypot(x - 3.0, y - 4.0), jnp.hypot(x - w + 2.0, y - 1.0)])  # degrees = pixels
        pix = jax.random.uniform(k[0], (2, h, w, 3))
        color = 3.0 * jax.random.uniform(k[1], (2, h, w, 3)) - 1.0
        history = TaaHistory(color, jax.random.bernoulli(k[2], 0.7, (2, h, w)))
        cases.append((pix, *layer_weights(ecc, jnp.asarray([2.0, 5.0]), 1.5), strides, history))

    def blended(case, native, alpha=0.1, gamma=1.0):
        pix, w_inner, w_middle, strides, history = case
        return rates_and_history(
            pix, w_inner, w_middle, history, strides=strides, alpha=alpha, gamma=gamma, native=native
        )

    def both(arrays):
        cases_now = [(*a[:3], c[3], a[3]) for a, c in zip(arrays, cases, strict=True)]
        out = [[blended(c, n) for n in (True, False)] for c in cases_now]
        for case in (cases_now[0], cases_now[3]):
            tangent = jnp.ones_like(case[0])
            out.append(
                [
                    jax.jvp(
                        lambda x, n=n, c=case: blended((x, *c[1:]), n, 0.25, 0.5), (case[0],), (tangent,)
                    )[1]
                    for n in (True, False)
                ]
            )
        return out

    arrays = [(*c[:3], c[4]) for c in cases]  # the strides are static
    lowered = jax.jit(both).lower(arrays)
    assert lowered.as_text().count("fovjax_taa_blend") >= 6
    results = lowered.compile()(arrays)
    images = [
        rate_blend(*(hold(pix, s) for s in (1, *strides)), w_inner, w_middle)
        for pix, w_inner, w_middle, strides, _ in cases
    ]
    for (native, reference), image in zip(results, [*images, None, None], strict=True):
        native, reference = np.asarray(native), np.asarray(reference)
        bound = 0.0 if image is None else _taa_rounding_bound(image, gamma=1.0, keep=0.9)
        assert np.isfinite(reference).all()  # held blocks' flat neighbourhoods: no NaN slope either
        assert np.all(np.abs(native - reference) <= 1e-6 * np.abs(reference) + 1e-7 + 2 * bound)
    # The history counts: blended pixels differ from this frame, the others are it.
    (native, _), (current, *_, hist) = results[0], cases[0]
    held = np.asarray(hist.valid)
    changed = np.any(np.asarray(native) != np.asarray(current), axis=-1)
    assert changed[held].mean() > 0.9 and not changed[~held].any()
    # The rates are blended: their held blocks show where the history holds none.
    (native, _), (pix, w_inner, *_, hist) = results[3], cases[3]
    fresh = ~np.asarray(hist.valid) & (np.asarray(w_inner) == 0.0)
    assert fresh.any() and np.abs(np.asarray(native)[fresh] - np.asarray(pix)[fresh]).max() > 0.05


@pytest.mark.parametrize(("h", "w", "strides"), [(13, 18, (2, 4)), (10, 7, (3, 5))])
def test_guenter_layers_native_are_the_jax_path(h, w, strides):
    """Guenter 2012's layers (`composite`: the middle and outer layers magnified, blended by
    eccentricity, both eyes side by side) through the native layers handler against the JAX
    composite: equal to float rounding, at sizes the strides do not divide and radii that put
    every pixel in a blend somewhere; the derivative is the JAX composite's."""
    from fovjax.foveate._methods._guenter import composite

    k = jax.random.split(jax.random.key(h * w), 2)
    pix = jax.random.uniform(k[0], (2, h, w, 3))
    ecc = 12.0 * jax.random.uniform(k[1], (2, h, w))
    radii = jnp.asarray([3.0, 7.0])

    def both(pix, ecc, radii):
        out = [composite(pix, ecc, radii, strides=strides, blend_deg=2.0, native=n) for n in (True, False)]
        jvps = [
            jax.jvp(
                lambda r, n=n: composite(pix, ecc, r, strides=strides, blend_deg=2.0, native=n),
                (radii,),
                (jnp.ones_like(radii),),
            )[1]
            for n in (True, False)
        ]
        return out, jvps

    lowered = jax.jit(both).lower(pix, ecc, radii)
    assert "fovjax_layer_blend" in lowered.as_text()
    (native, reference), (native_jvp, reference_jvp) = lowered.compile()(pix, ecc, radii)
    assert native.shape == (h, 2 * w, 3)
    np.testing.assert_allclose(np.asarray(native), np.asarray(reference), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(np.asarray(native_jvp), np.asarray(reference_jvp), rtol=1e-6, atol=1e-6)
    # Inside the inner radius a pixel is its own mean (the left eye on the left).
    inner = np.asarray(ecc[0]) < 3.0
    np.testing.assert_array_equal(np.asarray(native)[:, :w][inner], np.asarray(pix[0])[inner])
    assert np.abs(np.asarray(native)[:, :w][~inner] - np.asarray(pix[0])[~inner]).max() > 0.05


# ---- the featured spheres ---------------------------------------------------------------------

EYE_W, EYE_H = 40, 32
DEPTH = 3


@pytest.fixture(scope="module")
def featured():
    """The spheres scene with UVs, a texture on the floor's material, an environment map and a
    second, directional light; its BVH and a stereo rig."""
    scene = fovjax.scenes.spheres()
    arrays = scene_arrays(scene)
    rng = np.random.default_rng(0)
    uvs = (rng.random((scene.vertices.shape[0], 2)) * 3.0 - 1.0).astype(np.float32)
    texture = rng.random((5, 7, 3)).astype(np.float32)
    env = rng.random((6, 12, 3)).astype(np.float32)
    tex_index = np.full(np.shape(arrays.texture), -1, np.int32)
    tex_index[0] = 0
    lights = np.concatenate([np.asarray(arrays.light_position), [[0.3, 1.0, 0.5]]]).astype(np.float32)
    colors = np.concatenate([np.asarray(arrays.light_color), [[0.4, 0.35, 0.3]]]).astype(np.float32)
    kinds = np.array([POINT_LIGHT, DIRECTIONAL_LIGHT], np.int32)
    arrays = dataclasses.replace(
        arrays,
        uvs=uvs,
        textures=(texture,),
        texture=tex_index,
        environment=env,
        light_position=lights,
        light_color=colors,
        light_kind=kinds,
    )
    bvh = build_bvh(scene, cache=False)
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=EYE_W, eye_height=EYE_H)
    return scene, arrays, bvh, rig


def _radiance(arrays, bvh, rig, integrator, *, hits="recomputed"):
    rays = stereo_sample_rays(rig, None, 4, jax.random.key(3))
    config = RenderConfig(max_depth=DEPTH, integrator=integrator, hits=hits)
    fn = jax.jit(lambda a, o, d: radiance(a, bvh, o, d, config=config))
    return jax.block_until_ready(fn(arrays, rays.origins, rays.directions))


def _agree(native, reference, arrays):
    assert np.shape(native.rgb) == np.shape(reference.rgb)
    assert_native_radiance(native.rgb, reference.rgb, arrays)
    assert_same_counts(native.counts, reference.counts)


@pytest.mark.parametrize("hits", ["recomputed", "backend"])
def test_native_radiance_agrees_with_the_jax_integrator(featured, hits):
    _, arrays, bvh, rig = featured
    native = _radiance(arrays, bvh, rig, "native", hits=hits)
    reference = _radiance(arrays, bvh, rig, "jax", hits=hits)
    _agree(native, reference, arrays)
    # the scene exercises what it is meant to: reflections, shadow rays to both lights, misses
    assert int(reference.counts.reflection) > 100
    assert int(reference.counts.shadow) > int(reference.counts.primary)
    assert np.asarray(reference.rgb).std() > 0.05


def test_auto_runs_the_native_integrator_on_this_cpu(featured):
    """'auto' picks the native loop here (the handler is built): its program for the CPU calls
    the handler's Whitted loop (and integrator='jax' does not), and its images are the native
    ones bit for bit."""
    from fovjax.render._native import WHITTED_TARGET

    _, arrays, bvh, rig = featured
    rays = stereo_sample_rays(rig, None, 1, None)
    for integrator, calls in (("auto", True), ("jax", False)):
        config = RenderConfig(max_depth=DEPTH, integrator=integrator)
        lowered = jax.jit(lambda a, o, d, c=config: radiance(a, bvh, o, d, config=c).rgb).lower(
            arrays, rays.origins, rays.directions
        )
        assert (WHITTED_TARGET in lowered.as_text()) == calls, integrator
    auto = _radiance(arrays, bvh, rig, "auto")
    native = _radiance(arrays, bvh, rig, "native")
    np.testing.assert_array_equal(np.asarray(auto.rgb), np.asarray(native.rgb))


def test_gradients_are_the_jax_integrators(featured):
    """The native primal's derivatives in the shading parameters (every material column, the
    lights' colours, the ambient colour), from the native adjoint
    (fovjax/render/_whitted_adjoint.cc), are the JAX integrator's; textures, normals, the
    environment and both kinds of light on the way. (The other parameters' come from a replay of
    the stored paths, fovjax/render/_replay.py: tests/test_render_grad.py checks both at once
    against finite differences.) One closed form in two programs, whose gradients are sums over
    every ray added in different orders, so within float32's bound for such a sum, eps × rays ×
    the gradient's largest component."""
    _, arrays, bvh, rig = featured
    fields = ("ka", "kd", "ks", "ke", "kr", "ns", "light_color", "ambient")
    _assert_gradients_are_the_jax_integrators(arrays, bvh, rig, fields, max_depth=2)


def test_gradients_are_the_jax_integrators_where_rays_meet_back_faces(corridor):
    """The same on the corridor, where some rays meet a face from behind (the featured spheres'
    do not): the adjoint turns the normals to face the ray as the primal does (the mutation
    `surface-normal-unflipped` fails here). No reflection: the diffuse and specular terms,
    where the normals count."""
    arrays, bvh, rig = corridor
    _assert_gradients_are_the_jax_integrators(arrays, bvh, rig, ("kd", "ks", "light_color"), max_depth=0)


def _assert_gradients_are_the_jax_integrators(arrays, bvh, rig, fields, *, max_depth):
    rays = stereo_sample_rays(rig, None, 1, jax.random.key(5))
    # Every material reflects and shines a little, so that each column's gradient is not zero.
    start = {name: jnp.asarray(getattr(arrays, name)) for name in fields}
    if "kr" in start:
        start["kr"] = jnp.maximum(start["kr"], 0.2)
    if "ke" in start:
        start["ke"] = start["ke"] + 0.05
    if "ns" in start:
        start["ns"] = jnp.clip(start["ns"], 4.0, 64.0)

    def loss(params, integrator):
        a = dataclasses.replace(arrays, **params)
        # Each reflection level adds to the two gradient programs' compile: as few as the
        # parameters need (Kr's derivative reaches past a level with two).
        config = RenderConfig(max_depth=max_depth, integrator=integrator)
        rgb = radiance(a, bvh, rays.origins, rays.directions, config=config).rgb
        return jnp.mean(rgb * jnp.asarray([1.0, 0.5, 0.25]))

    grads = {name: jax.jit(jax.grad(lambda p, n=name: loss(p, n)))(start) for name in ("native", "jax")}
    bound = float(np.finfo(np.float32).eps) * int(np.prod(rays.origins.shape[:-1]))
    for name in fields:
        g_native, g_jax = np.asarray(grads["native"][name]), np.asarray(grads["jax"][name])
        scale = float(np.max(np.abs(g_jax)))
        assert scale > 0, name  # the parameter matters to the image
        np.testing.assert_allclose(g_native, g_jax, rtol=0, atol=bound * scale, err_msg=name)


def test_the_shading_adjoint_alone_is_the_replays(featured):
    """A gradient with respect to the shading parameters alone runs the native adjoint and no
    replay (its program holds the adjoint's call, and its reverse pass no scan over the replay's
    chunks), and is the replay's gradient (`integrator='jax'`, the oracle)."""
    from fovjax.render._native import ADJOINT_TARGET

    _, arrays, bvh, rig = featured
    rays = stereo_sample_rays(rig, None, 1, jax.random.key(6))

    def loss(kd, integrator):
        a = dataclasses.replace(arrays, kd=kd)
        config = RenderConfig(max_depth=1, integrator=integrator)
        return jnp.sum(radiance(a, bvh, rays.origins, rays.directions, config=config).rgb ** 2)

    kd = jnp.asarray(arrays.kd)
    text = jax.jit(jax.grad(lambda k: loss(k, "native"))).lower(kd).as_text()
    assert ADJOINT_TARGET in text and "while" not in text
    native = jax.jit(jax.grad(lambda k: loss(k, "native")))(kd)
    reference = jax.jit(jax.grad(lambda k: loss(k, "jax")))(kd)
    bound = float(np.finfo(np.float32).eps) * int(np.prod(rays.origins.shape[:-1]))
    scale = float(np.max(np.abs(np.asarray(reference))))
    np.testing.assert_allclose(np.asarray(native), np.asarray(reference), rtol=0, atol=bound * scale)


def test_foveated_frame_through_the_native_integrator_agrees(featured):
    """A foveated frame (the chunked integrator, `radiance_in_chunks`) with the native loop and
    with the JAX one: the same samples traced, radiance within the file's agreement."""
    scene, _, bvh, rig = featured
    foveation = Foveation(5.0, 10.0)
    frames = {
        name: fovjax.FoveatedRenderer(
            scene,
            rig,
            foveation,
            RenderConfig(max_depth=DEPTH, integrator=name),
            bvh=bvh,
            diagnostics=("traced",),
        ).render(gaze=((0.4, 0.45), (0.4, 0.45)), key=jax.random.key(2))
        for name in ("native", "jax")
    }
    a, b = frames["native"], frames["jax"]
    np.testing.assert_array_equal(a.sample_mask, b.sample_mask)
    assert a.stats.primary_rays > 0
    assert_same_counts(_stats_counts(a), _stats_counts(b))
    assert_native_radiance(a.image, b.image, featured[1])


def _stats_counts(frame):
    s = frame.stats
    return (s.primary_rays, s.shadow_rays, s.reflection_rays, s.bad_samples)


def test_full_frame_entry_point_uses_it(featured):
    """`render_stereo` (the full frame program) through both integrators."""
    scene, _, bvh, rig = featured
    frames = [
        render_stereo(scene, rig, spp=1, key=jax.random.key(0), bvh=bvh, config=RenderConfig(integrator=name))
        for name in ("native", "jax")
    ]
    assert_native_radiance(frames[0].image, frames[1].image, featured[1])
    assert_same_counts(_stats_counts(frames[0]), _stats_counts(frames[1]))
    assert frames[0].stats.primary_rays == 2 * EYE_W * EYE_H


# ---- the camera frame handler: the full frame's rays, radiance and box filter in one call -------

CAMERA_FRAME_CASES = [
    # (samples per pixel, key: None, "typed" or "raw", cameras, eye width, height)
    (1, None, 2, 32, 32),
    (4, "typed", 2, 37, 21),  # ragged tiles: 74 sub-sample columns, 21 rows
    (9, "raw", 1, 30, 18),  # 3 x 3 sub-samples: 12 rows a block
    (1, "typed", 1, 300, 8),  # two blocks a row: 256 columns and 44
]


def _camera_frame_key(kind):
    return {None: None, "typed": jax.random.key(5), "raw": jax.random.PRNGKey(6)}[kind]


@pytest.mark.parametrize(
    "case", CAMERA_FRAME_CASES, ids=lambda c: f"spp{c[0]}-{c[1]}-{c[2]}eyes-{c[3]}x{c[4]}"
)
def test_camera_frame_handler_is_its_reference(corridor, case):
    """`camera_frame` through the handler (its rays made natively: the cell centres or the key's
    threefry draws, one or two cameras, ragged tiles) against `_frame_of_rays` (the rays in
    JAX, the same native integrator, `resolve`): every pixel to float rounding, the same ray
    counts and bad pixels."""
    from fovjax.render._frame import _frame_of_rays, camera_frame
    from fovjax.render._native import FRAME_TARGET

    arrays, bvh, rig = corridor
    spp, key_kind, n_cameras, w, h = case
    key = _camera_frame_key(key_kind)
    rig = dataclasses.replace(rig, eye_width=w, eye_height=h)
    cameras = rig.eye_cameras(jnp.asarray([4.0, -3.0, 2.0]))[:n_cameras]
    config = RenderConfig(max_depth=CORRIDOR_DEPTH, integrator="native")

    def both(a, cams, k):
        native = camera_frame(a, bvh, cams, k, spp=spp, config=config)
        reference = _frame_of_rays(a, bvh, cams, k, spp=spp, config=config)
        return native, reference

    lowered = jax.jit(both).lower(arrays, cameras, key)
    assert FRAME_TARGET in lowered.as_text()
    native, reference = lowered.compile()(arrays, cameras, key)
    assert np.shape(native[0]) == (h, n_cameras * w, 3) == np.shape(reference[0])
    assert_native_radiance(native[0], reference[0], arrays)
    assert_same_counts(native[1], reference[1])
    assert int(native[2]) == int(reference[2]) == 0
    assert int(reference[1].primary) == n_cameras * spp * w * h
    assert int(reference[1].reflection) > 0 and np.asarray(reference[0]).std() > 0.05


def test_camera_frame_handler_draws_the_keys_jitter(corridor):
    """With a key the handler's sub-samples move (the draws are read, and are the key's): two
    keys give two images, each its reference's."""
    from fovjax.render._frame import _frame_of_rays, camera_frame

    arrays, bvh, rig = corridor
    rig = dataclasses.replace(rig, eye_width=24, eye_height=16)
    cameras = rig.eye_cameras(None)
    config = RenderConfig(max_depth=2, integrator="native")
    images = []
    for key in (jax.random.key(1), jax.random.key(2), None):
        native = jax.jit(lambda a, k: camera_frame(a, bvh, cameras, k, spp=4, config=config)[0])
        reference = jax.jit(lambda a, k: _frame_of_rays(a, bvh, cameras, k, spp=4, config=config)[0])
        native, reference = native(arrays, key), reference(arrays, key)
        assert_native_radiance(native, reference, arrays)
        images.append(np.asarray(native))
    assert np.abs(images[0] - images[1]).max() > CHANGE and np.abs(images[0] - images[2]).max() > CHANGE


def test_camera_frame_handler_paints_bad_pixels(corridor):
    """A material whose colour is not finite: the samples that meet it are bad, their pixels the
    bad colour, counted as the reference counts them (bad samples and bad pixels)."""
    from fovjax.render._frame import _frame_of_rays, camera_frame

    arrays, bvh, rig = corridor
    rig = dataclasses.replace(rig, eye_width=20, eye_height=12)
    kd = np.array(arrays.kd, copy=True)
    kd[3] = np.nan  # the box's
    broken = dataclasses.replace(arrays, kd=kd)
    cameras = rig.eye_cameras(None)
    config = RenderConfig(max_depth=2, integrator="native", bad_color=(0.25, 0.5, 0.75))
    key = jax.random.key(4)
    native = jax.jit(lambda a: camera_frame(a, bvh, cameras, key, spp=4, config=config))(broken)
    reference = jax.jit(lambda a: _frame_of_rays(a, bvh, cameras, key, spp=4, config=config))(broken)
    assert 0 < int(reference[2]) < 2 * 20 * 12 and int(reference[1].bad) >= int(reference[2])
    assert int(native[2]) == int(reference[2])
    assert_same_counts(native[1], reference[1])
    painted = np.all(np.asarray(native[0]) == np.float32([0.25, 0.5, 0.75]), axis=-1)
    assert int(painted.sum()) == int(native[2])
    np.testing.assert_array_equal(np.asarray(native[0])[painted], np.asarray(reference[0])[painted])
    assert_native_radiance(np.asarray(native[0])[~painted], np.asarray(reference[0])[~painted], arrays)


def test_camera_frame_derivatives_are_its_references(corridor):
    """Derivatives of the handler's frame are its reference's (the stored paths' replay), and so
    is the primal a JVP returns: the light colours' gradient of a loss of the image and the
    JVP's primal are the reference's bit for bit (tests/test_render_grad.py checks the camera's
    and the materials' gradients of `render_image`, this frame, against finite differences)."""
    from fovjax.render._frame import _frame_of_rays, camera_frame

    arrays, bvh, rig = corridor
    rig = dataclasses.replace(rig, eye_width=16, eye_height=12)
    config = RenderConfig(max_depth=2, integrator="native")
    cameras = rig.eye_cameras(None)
    weights = jnp.linspace(0.5, 1.5, 12 * 32 * 3).reshape(12, 32, 3)

    def image(frame, colour):
        a = dataclasses.replace(arrays, light_color=colour)
        return frame(a, bvh, cameras, jax.random.key(3), spp=1, config=config)[0]

    def both(colour):  # one program
        grads = [
            jax.grad(lambda c, f=f: jnp.sum(weights * image(f, c)))(colour)
            for f in (camera_frame, _frame_of_rays)
        ]
        ones = jnp.ones_like(colour)
        primal, _ = jax.jvp(functools.partial(image, camera_frame), (colour,), (ones,))
        return grads, primal, image(_frame_of_rays, colour), image(camera_frame, colour)

    (native, reference), primal, of_rays, plain = jax.jit(both)(jnp.asarray(arrays.light_color))
    assert np.abs(np.asarray(reference)).max() > 0
    np.testing.assert_array_equal(np.asarray(native), np.asarray(reference))
    np.testing.assert_array_equal(np.asarray(primal), np.asarray(of_rays))
    assert_native_radiance(primal, plain, arrays)


def test_camera_frame_keeps_the_reference_for_draws_it_does_not_make(corridor):
    """A key of another PRNG (rbg): the plan says why not, and the frame is the reference's
    program (no handler call) and image."""
    from fovjax.render._frame import _frame_of_rays, camera_frame, camera_frame_why_not
    from fovjax.render._native import FRAME_TARGET

    arrays, bvh, rig = corridor
    rig = dataclasses.replace(rig, eye_width=16, eye_height=12)
    cameras = rig.eye_cameras(None)
    config = RenderConfig(max_depth=1, integrator="native")
    key = jax.random.key(0, impl="rbg")
    assert "threefry2x32" in camera_frame_why_not(config, key, 16, 12, 4)
    assert camera_frame_why_not(config, jax.random.key(0), 16, 12, 4) == ""
    fn = jax.jit(lambda a, k: camera_frame(a, bvh, cameras, k, spp=4, config=config)[0])
    assert FRAME_TARGET not in fn.lower(arrays, key).as_text()
    reference = jax.jit(lambda a, k: _frame_of_rays(a, bvh, cameras, k, spp=4, config=config)[0])
    np.testing.assert_array_equal(np.asarray(fn(arrays, key)), np.asarray(reference(arrays, key)))


def test_integrator_setting_is_checked():
    with pytest.raises(ValueError, match="integrator must be one of .* got 'fast'"):
        RenderConfig(integrator="fast")


def test_native_with_another_ray_backend_is_an_error_naming_it(featured):
    _, arrays, bvh, rig = featured
    with pytest.raises(
        ValueError, match="integrator 'native' needs the native handlers, but the ray backend is 'jax'"
    ):
        _radiance_config(arrays, bvh, rig, RenderConfig(integrator="native", backend="jax"))


def test_other_ray_backends_keep_the_jax_integrator(featured):
    """'auto' with backend 'jax' is the JAX integrator throughout (the JAX traversal is the
    portable reference): the integrator='jax' program itself (the same StableHLO, so bit for bit
    the same frame for any rays; compared lowered, not compiled), without the native integrator."""
    from fovjax.render._native import WHITTED_TARGET

    _, arrays, bvh, rig = featured
    rays = stereo_sample_rays(rig, None, 1, jax.random.key(3))

    def lowered(config):
        program = jax.jit(lambda a, o, d: radiance(a, bvh, o, d, config=config))
        return program.lower(arrays, rays.origins, rays.directions).as_text()

    auto = lowered(RenderConfig(max_depth=1, backend="jax"))
    assert auto == lowered(RenderConfig(max_depth=1, backend="jax", integrator="jax"))
    assert WHITTED_TARGET not in auto
    assert WHITTED_TARGET in lowered(RenderConfig(max_depth=1))  # the text shows the native call


def _radiance_config(arrays, bvh, rig, config):
    rays = stereo_sample_rays(rig, None, 1, jax.random.key(3))
    return jax.jit(lambda a, o, d: radiance(a, bvh, o, d, config=config))(
        arrays, rays.origins, rays.directions
    )


def test_a_hit_face_out_of_range_is_an_error_naming_it(featured):
    """Scene arrays whose faces name vertices that do not exist (the BVH traced the original
    faces): the native call fails with a message saying so, rather than reading past the
    vertices."""
    _, arrays, bvh, rig = featured
    faces = np.array(arrays.faces, copy=True)
    faces[:, 0] = np.asarray(arrays.vertices).shape[0] + 5
    broken = dataclasses.replace(arrays, faces=faces)
    with pytest.raises(jax.errors.JaxRuntimeError, match="names a vertex or a material out of range"):
        jax.block_until_ready(
            _radiance_config(broken, bvh, rig, RenderConfig(max_depth=1, integrator="native"))
        )


def test_image_rays_in_4x4_tiles_cover_every_ray(featured):
    """Camera rays laid out as an image 300 wide (blocks of 256 columns and a last one of 44,
    4×4 packets) against the same rays as a flat list traced one by one: every ray's radiance,
    none left out or traced twice."""
    scene, arrays, bvh, _ = featured
    camera = fovjax.scenes.default_camera(scene)
    rig = StereoRig.from_pose(camera, eye_width=300, eye_height=8)
    rays = stereo_sample_rays(rig, None, 1, None)
    tiled = RenderConfig(max_depth=DEPTH, integrator="native")  # packets: 8x8 tiles (an image)
    flat = RenderConfig(max_depth=DEPTH, integrator="native", packet=None)
    a = jax.jit(lambda a, o, d: radiance(a, bvh, o, d, config=tiled))(arrays, rays.origins, rays.directions)
    o, d = rays.origins.reshape(-1, 3), rays.directions.reshape(-1, 3)
    b = jax.jit(lambda a, o, d: radiance(a, bvh, o, d, config=flat))(arrays, o, d)
    rgb_a, rgb_b = np.asarray(a.rgb).reshape(-1, 3), np.asarray(b.rgb)
    assert np.isfinite(rgb_a).all() and rgb_a.std() > 0.05
    # One handler's arithmetic either way; only the traversal (packets or single rays) differs.
    assert_native_radiance(rgb_a, rgb_b, arrays)
    assert_same_counts(a.counts, b.counts)
    assert int(a.counts.primary) == 2 * 300 * 8


GAZE = ((0.3, 0.4), (0.35, 0.45))
SELECTION_CASES = [
    # (eye width, height, spp, rule, blocks, budget or None for every sample, per-region spp, gaze)
    (40, 24, 1, "either", (2, 4), None, None, GAZE),
    (37, 29, 4, "either", (2, 4), 300, None, GAZE),  # odd sizes; the budget drops samples
    (37, 29, 4, "strict", (1, 3), None, None, GAZE),
    # Over 8192 pixels an eye (two chunks of the compaction), 8×8 tiles cut by both edges, and
    # a whole tile's 64 locality ranks, some of them traced, across the chunks' boundary.
    (113, 73, 4, "either", (1, 3), None, None, GAZE),
    (40, 24, 4, "thesis-measured", (2, 4), 500, None, GAZE),
    (40, 24, 4, "either", (2, 4), None, (4, 1, 2), GAZE),  # each region's samples per pixel
    # The fovea at the left edge: rows that begin where P(ω) is 1 and draw beyond it.
    (40, 24, 4, "either", (2, 4), None, None, ((0.0, 0.5), (0.01, 0.5))),
]


@pytest.mark.parametrize(
    "case", SELECTION_CASES, ids=lambda c: f"{c[0]}x{c[1]}-{c[3]}-spp{c[2]}-{c[5]}-{c[6]}-x{c[7][0][0]}"
)
def test_native_sample_selection_is_the_jax_selection(featured, case):
    """The native handler's classes, counts, compaction (the listed samples, in order), traced
    mask and per-pixel counts are the JAX selection's, integer for integer."""
    from fovjax.foveate import Fidelity
    from fovjax.foveate._frame import eccentricities, selection_with_mask

    w, h, spp, rule, blocks, budget, per_region, gaze = case
    fidelity = None if per_region is None else tuple(Fidelity(spp=s) for s in per_region)
    fov = Foveation(5.0, 10.0, spp=spp, rule=rule, blocks=blocks, fidelity=fidelity)
    scene = featured[0]
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=w, eye_height=h)
    ecc = eccentricities(rig.eye_cameras(jnp.zeros(3)), jnp.asarray(gaze), fov)
    budget = budget or 2 * spp * w * h

    def both(ecc, key):
        select = functools.partial(selection_with_mask, ecc, key, foveation=fov, budget=budget)
        return select(native=False), select(native=True)

    lowered = jax.jit(both).lower(ecc, jax.random.key(11))
    assert "fovjax_select_samples" in lowered.as_text()  # the native branch is the one compiled
    in_jax, native = lowered.compile()(ecc, jax.random.key(11))
    (sel_jax, mask_jax, n_jax, by_jax), (sel_native, mask_native, n_native, by_native) = in_jax, native
    listed = int(sel_jax.counts[0] + sel_jax.counts[1])
    assert 0 < int(sel_jax.n_traced) <= budget
    np.testing.assert_array_equal(sel_native.order[:listed], sel_jax.order[:listed])
    assert not np.asarray(sel_native.order[listed:]).any()  # the handler's slots past the list: zeros
    for name in ("region", "classes", "counts", "n_traced"):
        np.testing.assert_array_equal(getattr(sel_native, name), getattr(sel_jax, name), err_msg=name)
    np.testing.assert_array_equal(mask_native, mask_jax)
    np.testing.assert_array_equal(n_native, n_jax)
    np.testing.assert_array_equal(by_native, by_jax)
    assert int(by_native.sum()) == int(mask_native.sum())
    if budget < listed:  # the drops are the budget's
        assert int(mask_native.sum()) == budget


FILL_CASES = [
    # (width, height, spp, rule, blocks, budget, blur_fovea)
    (40, 24, 1, "either", (2, 4), None, False),  # every blank pixel's top-left traced: native
    (37, 29, 4, "either", (2, 4), 300, False),  # drops leave top-lefts blank: the JAX fallback
    (37, 29, 4, "strict", (1, 3), None, False),
    (37, 29, 4, "either", (2, 4), None, False),  # means of up to 4 samples, native
    (40, 24, 1, "either", (2, 4), None, True),  # the blur over every pixel
]


@pytest.mark.parametrize("case", FILL_CASES, ids=lambda c: f"{c[3]}-spp{c[2]}-{c[5]}-blur{int(c[6])}")
def test_native_fill_and_blur_is_the_jax_path(featured, case):
    """The native reconstruction (pixel means, bad pixels, the fill from block top-lefts, the
    blur and its blend by eccentricity, side by side) against the JAX functions, on a real
    selection and random sums, bad pixels among them, and its derivative (the JAX path's). It
    reports a blank top-left where the JAX path's pull-push would fill, and the frame then takes
    the JAX path. The two agree to float
    rounding (the blur's ten-term sums, summed in the same order; XLA may round a product or a
    sum its own way: a few ulps, far below any display step)."""
    from fovjax.foveate._fill import FOVEA_BLEND_DEG, gaussian_taps
    from fovjax.foveate._frame import eccentricities, fill_and_blur_sums, selection_with_mask
    from fovjax.foveate._native import native_fill_and_blur

    w, h, spp, rule, blocks, budget, blur_fovea = case
    fov = Foveation(5.0, 10.0, spp=spp, rule=rule, blocks=blocks, blur_fovea=blur_fovea)
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(featured[0]), eye_width=w, eye_height=h)
    ecc = eccentricities(rig.eye_cameras(jnp.zeros(3)), jnp.asarray([[0.3, 0.4], [0.35, 0.45]]), fov)
    budget = budget or 2 * spp * w * h
    sel, _, n, _ = selection_with_mask(ecc, jax.random.key(3), foveation=fov, budget=budget, native=False)
    rng = np.random.default_rng(5)
    n_np = np.asarray(n)
    sums = (rng.random((2, h, w, 3)) * n_np[..., None]).astype(np.float32).reshape(-1, 3)
    bad = np.zeros(2 * h * w, bool)
    # Some traced pixels had a NaN sample: every 7th, so at every place in a row of flags.
    bad[np.flatnonzero(n_np > 0)[::7]] = True
    carry = (jnp.asarray(sums), jnp.asarray(bad), jnp.int32(int(bad.sum())))
    assert bad.any()
    complete_expected = rule == "either" and budget >= 2 * spp * w * h

    def both(carry, n, sel):
        fill = functools.partial(fill_and_blur_sums, carry, n, sel, fov, bad_color=(1.0, 0.0, 1.0))
        native = fill(top_lefts_traced=complete_expected, native=True)
        _, complete = native_fill_and_blur(
            carry[0],
            n,
            carry[1],
            sel.region,
            sel.eccentricity,
            (1.0, 0.0, 1.0),
            gaussian_taps(fov.blur_sigma),
            fov.fovea_deg,
            blocks=blocks,
            blend_deg=FOVEA_BLEND_DEG,
            blur_fovea=blur_fovea,
        )

        def derivative(native):  # d image / d sums along `tangent`: the JAX path's everywhere
            def image(rgb):
                return fill_and_blur_sums(
                    (rgb, *carry[1:]),
                    n,
                    sel,
                    fov,
                    bad_color=(1.0, 0.0, 1.0),
                    top_lefts_traced=complete_expected,
                    native=native,
                )

            return jax.jvp(image, (carry[0],), (tangent,))[1]

        return (
            fill(top_lefts_traced=complete_expected, native=False),
            native,
            complete,
            derivative(False),
            derivative(True),
        )

    tangent = jnp.asarray(rng.standard_normal(sums.shape), jnp.float32)
    lowered = jax.jit(both).lower(carry, n, sel)
    assert "fovjax_fill_and_blur" in lowered.as_text()
    in_jax, native, complete, d_jax, d_native = lowered.compile()(carry, n, sel)
    assert in_jax.shape == (h, 2 * w, 3)
    assert bool(complete) == complete_expected
    np.testing.assert_allclose(np.asarray(native), np.asarray(in_jax), rtol=1e-6, atol=1e-7)
    assert np.abs(np.asarray(d_native)).max() > 0  # the image does depend on the sums
    # Both are the JAX path's derivative, compiled in two places of one program: XLA may round
    # them apart, so float rounding, as the images.
    np.testing.assert_allclose(np.asarray(d_native), np.asarray(d_jax), rtol=1e-6, atol=1e-7)


def test_native_fill_blends_rows_with_an_infinite_mean(featured):
    """A traced pixel whose sum overflowed to inf (not a bad sample), in a row beyond the
    blend, and one in the fovea's row: the native blend gives what the JAX path's does there
    (inf·0 in the blend: NaN), not the blurred row the handler keeps where every weight is 1 and
    every sharp value finite; everywhere else the two agree to float rounding, rows whose
    weights are all between 1/2 and 1 among them (96 rows: about half a degree each)."""
    from fovjax.foveate._fill import FOVEA_BLEND_DEG
    from fovjax.foveate._frame import eccentricities, fill_and_blur_sums, selection_with_mask

    w, h = 40, 96
    fov = Foveation(5.0, 10.0, spp=1, rule="either", blocks=(2, 4))
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(featured[0]), eye_width=w, eye_height=h)
    ecc = eccentricities(rig.eye_cameras(jnp.zeros(3)), jnp.asarray([[0.3, 0.4], [0.35, 0.45]]), fov)
    sel, _, n, _ = selection_with_mask(ecc, jax.random.key(3), foveation=fov, budget=2 * w * h, native=False)
    n_np, ecc_np = np.asarray(n), np.asarray(ecc)
    sums = (np.random.default_rng(5).random((2, h, w, 3)) * n_np[..., None]).astype(np.float32)
    far_rows = np.flatnonzero(ecc_np[0].min(axis=1) > fov.fovea_deg + 2.0)  # every weight 1
    near = int(np.argmin(ecc_np[0].min(axis=1)))  # the fovea's row
    assert far_rows.size and ecc_np[0, near].min() < fov.fovea_deg
    row_t = (ecc_np.min(axis=2) - fov.fovea_deg) / FOVEA_BLEND_DEG
    assert ((row_t >= 0.5) & (row_t < 1.0)).any()  # rows blended, though every weight is at least 1/2
    for y in (far_rows[0], near):
        sums[0, y, int(np.flatnonzero(n_np[0, y] > 0)[0])] = np.inf
    carry = (jnp.asarray(sums.reshape(-1, 3)), jnp.zeros(2 * h * w, bool), jnp.int32(0))

    def both(carry, n, sel):
        fill = functools.partial(fill_and_blur_sums, carry, n, sel, fov, bad_color=(1.0, 0.0, 1.0))
        return fill(top_lefts_traced=True, native=False), fill(top_lefts_traced=True, native=True)

    lowered = jax.jit(both).lower(carry, n, sel)
    assert "fovjax_fill_and_blur" in lowered.as_text()  # the native branch is the one compiled
    in_jax, native = (np.asarray(a) for a in lowered.compile()(carry, n, sel))
    assert np.isnan(in_jax).any() and np.isinf(in_jax).any()  # the case is what it says
    np.testing.assert_allclose(native, in_jax, rtol=1e-6, atol=1e-7)  # NaN where NaN, inf where inf


def _featured_selection(featured, w, h, spp):
    """The featured scene's eye cameras (a head pose off the default) at w×h and one foveated
    selection (5°/10°, the JAX selection): (cameras, selection, traced samples per pixel,
    slot budget)."""
    from fovjax.foveate._frame import eccentricities, selection_with_mask

    scene = featured[0]
    fov = Foveation(5.0, 10.0, spp=spp)
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=w, eye_height=h)
    cameras = rig.eye_cameras(jnp.asarray([2.0, -1.0, 0.5]))
    ecc = eccentricities(cameras, jnp.asarray([[0.3, 0.4], [0.35, 0.45]]), fov)
    budget = 2 * spp * w * h
    sel, _, n, _ = selection_with_mask(ecc, jax.random.key(3), foveation=fov, budget=budget, native=False)
    return cameras, sel, n, budget


SLOTS_CASES = [
    # (eye width, height, spp, jittered, the derivative too)
    (37, 29, 4, True, True),  # odd sizes, strata with jitter
    (40, 24, 1, False, False),  # pixel centres
]


@pytest.mark.parametrize("case", SLOTS_CASES, ids=lambda c: f"{c[0]}x{c[1]}-spp{c[2]}-jitter{int(c[3])}")
def test_slots_in_one_native_call_are_the_chunked_path(featured, case):
    """`traced_sums`: the native handler that makes every live slot's ray, traces it and adds it
    to its pixel in one call, against the chunk loop it replaces (`trace_selection` with the
    sample adder, the JAX integrator): the same pixel sums to float rounding (ray directions
    are rounded by the two compilers apart), the same bad pixels and ray counts (within the
    file's agreement), and its derivative (a replay of the paths it stored) is the chunked path's."""
    from fovjax.foveate._frame import traced_sums

    w, h, spp, jittered, derivative = case
    _, arrays, bvh, _ = featured
    cameras, sel, n, budget = _featured_selection(featured, w, h, spp)
    key = jax.random.key(8) if jittered else None
    tangent = jax.random.normal(jax.random.key(1), np.shape(arrays.kd), jnp.float32)

    def both(kd):
        def sums(kd, integrator):
            # One reflection level: the paths are the same at every level (compile time).
            config = RenderConfig(max_depth=1, integrator=integrator)
            a = dataclasses.replace(arrays, kd=kd)
            out = traced_sums(a, bvh, cameras, key, sel, config=config, budget=budget)
            return out.consumed, jnp.stack([out.primary, out.shadow, out.reflection])

        native, counts_native = sums(kd, "native")
        chunked, counts_jax = sums(kd, "jax")
        if not derivative:  # one case: each derivative is a program of its own to compile
            return native, counts_native, None, chunked, counts_jax, None
        # Under differentiation the native side's derivative is its stored paths' replay.
        _, (d_native, _) = jax.jvp(lambda k: sums(k, "native"), (kd,), (tangent,))
        _, (d_jax, _) = jax.jvp(lambda k: sums(k, "jax"), (kd,), (tangent,))
        return native, counts_native, d_native, chunked, counts_jax, d_jax

    lowered = jax.jit(both).lower(jnp.asarray(arrays.kd))
    assert "fovjax_whitted_slots" in lowered.as_text()  # the one-call path is the one compiled
    native, counts_native, d_native, chunked, counts_jax, d_jax = lowered.compile()(jnp.asarray(arrays.kd))
    (sums_n, bad_n, n_bad_n), (sums_j, bad_j, n_bad_j) = native, chunked
    traced = np.asarray(n).reshape(-1) > 0
    assert traced.sum() > 0 and np.asarray(sums_j)[traced].std() > 0.05
    per_pixel = np.maximum(np.asarray(n).reshape(-1, 1), 1)  # pixel means: a sample's bound holds
    assert_native_radiance(np.asarray(sums_n) / per_pixel, np.asarray(sums_j) / per_pixel, arrays)
    assert (np.asarray(sums_n)[~traced] == 0).all()  # untraced pixels hold no sum
    np.testing.assert_array_equal(bad_n, bad_j)
    assert int(n_bad_n) == int(n_bad_j)
    assert int(counts_native[0]) == int(sel.n_traced)
    assert_same_counts(counts_native, counts_jax)
    if not derivative:
        return
    # Both derivatives are the chunked JAX path's, compiled in two places of one program.
    g_native, g_jax = np.asarray(d_native[0]), np.asarray(d_jax[0])
    assert np.abs(g_jax).max() > 0  # the sums depend on Kd
    np.testing.assert_allclose(g_native, g_jax, rtol=1e-5, atol=1e-6)


def test_first_points_native_and_their_derivatives_are_the_chunked_paths(featured):
    """Weier's points (`traced_sums` with `first_points`: each pixel's sub-sample 0's hit): on a
    CPU from the slots handler's own primary hits, their derivatives recomputed on the faces it
    stored; against the chunk loop's own queries (`first_hit_points`): the points to float
    rounding, and their JVP along a move of every vertex (nonzero on the hits, zero on a miss:
    its point lies a fixed distance along its ray)."""
    from fovjax.foveate._frame import traced_sums
    from fovjax.render.internal import scene_scale

    _, arrays, bvh, _ = featured
    cameras, sel, n, budget = _featured_selection(featured, 16, 12, 1)
    vertices = jnp.asarray(arrays.vertices)
    tangent = jax.random.normal(jax.random.key(1), vertices.shape, jnp.float32)

    def points(v, integrator):
        config = RenderConfig(max_depth=1, integrator=integrator)
        a = dataclasses.replace(arrays, vertices=v)
        out = traced_sums(a, bvh, cameras, None, sel, config=config, budget=budget, first_points=MISS)
        return out.consumed[3]

    def both(v):
        return [jax.jvp(lambda v, i=i: points(v, i), (v,), (tangent,)) for i in ("native", "jax")]

    lowered = jax.jit(both).lower(vertices)
    assert "fovjax_whitted_slots" in lowered.as_text()
    (p_native, d_native), (p_jax, d_jax) = (tuple(map(np.asarray, r)) for r in lowered.compile()(vertices))
    size = float(scene_scale(arrays))
    traced = np.asarray(n).reshape(-1) > 0
    far = np.linalg.norm(p_jax - np.asarray(cameras[0].position), axis=-1) > 0.5 * MISS * size
    assert traced.sum() > 0 and (traced & ~far).any() and (traced & far).any()  # hits and misses
    assert (p_jax[~traced] == 0).all() and (p_native[~traced] == 0).all()
    np.testing.assert_allclose(p_native, p_jax, rtol=1e-5, atol=1e-5 * size)
    assert np.abs(d_jax[traced & ~far]).min(axis=-1).max() > 0 and (d_jax[far] == 0).all()
    np.testing.assert_allclose(d_native, d_jax, rtol=1e-4, atol=1e-5 * np.abs(d_jax).max())
