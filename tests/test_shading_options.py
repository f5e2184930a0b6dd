"""The shading options of `RenderConfig` that read the thesis literally, and spot lights, in both
integrators (the JAX one, the oracle, and the native one, fovjax/render/_whitted.cc):

- `specular_payload`: the specular term times n·l, as §4.4.3's shadow payload multiplies it;
- `specular="phong"`: eq. 1's (r·v)^Ns beside the Blinn–Phong (n·h)^Ns;
- `min_contribution`: §2.5.2's contribution cut-off of reflection rays;
- SPOT_LIGHT (§2.3.4): a point light focused in a cone.

Single pixels are checked against hand computation (float64), the cut-off against the depth it
must amount to, and the native integrator against the JAX one on a corridor of facing mirrors
(inter-reflection to depth 5) lit by a point, a spot and a directional light with every option
on: the same rays traced, kind by kind, and every sample equal to float rounding.
"""

from __future__ import annotations

import dataclasses
import functools

import _extras
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fovjax
from fovjax.render import RenderConfig, radiance, scene_arrays
from fovjax.scene import DIRECTIONAL_LIGHT, POINT_LIGHT, SPOT_LIGHT
from fovjax.trace import build_bvh

SIZE = 15  # odd: the centre pixel's ray is the optical axis; every one-quad scene's image
# Float rounding between two programs: a sample of radiance ~1 through a few dozen float32
# operations, its specular power amplifying the rounding of n·h by up to Ns (at most 64 here).
RTOL, ATOL = 64 * 2.0**-20, 2.0**-20


def native_available() -> bool:
    """Whether the native integrator can run here: False (the native half of a test skips)
    without embreex or a built handler, and a failure under FOVJAX_REQUIRE_EXTRAS=1."""
    if not _extras.have("embreex"):
        return False
    from fovjax.native import status

    if not status():
        if _extras.required():
            pytest.fail(f"the native handlers are unavailable: {status().reason}", pytrace=False)
        return False
    return True


def integrators() -> list[str]:
    return ["jax", "native"] if native_available() else ["jax"]


def _quad(corners):
    return np.asarray(corners, np.float32), np.array([[0, 1, 2], [0, 2, 3]])


def _scene(quads, materials, lights, ambient=(0.0, 0.0, 0.0)):
    vertices, faces, face_material, base = [], [], [], 0
    for corners, material in quads:
        v, f = _quad(corners)
        vertices.append(v)
        faces.append(f + base)
        face_material += [material, material]
        base += len(v)
    return fovjax.make_scene(
        np.concatenate(vertices),
        np.concatenate(faces),
        face_material=np.asarray(face_material),
        materials=fovjax.make_materials(materials),
        lights=lights,
        ambient=ambient,
    )


@functools.cache
def _program(config):
    """One compiled program per configuration, shared by the scenes of one shape."""
    return jax.jit(lambda a, bvh, o, d: radiance(a, bvh, o, d, config=config))


def _radiance(scene, camera, config):
    o, d, _ = camera.sample_rays(1, None)
    return _program(config)(scene_arrays(scene), build_bvh(scene, cache=False), o, d)


# ---- the specular "payload" of §4.4.3 and Phong's eq. 1 on one pixel -------------------------

# A plane z = 0 seen head-on, lit by a directional light with n·l = 0.8 (from (0.6, 0, 0.8));
# Ks = 1, Ns = 10, no diffuse, ambient or mirror: the pixel is the specular term alone.
# Blinn–Phong: n·h = cos(½·acos 0.8), (n·h)^10 = ((1 + 0.8) / 2)^5 = 0.9^5 = 0.59049; §4.4.3 read
# literally multiplies it by the payload n·l: 0.472392. Phong: r = 2(n·l)n − l = (−0.6, 0, 0.8),
# r·v = 0.8, 0.8^10 = 0.107374; with the payload 0.0858993.
PAYLOAD_PIXEL = {
    ("blinn-phong", False): 0.9**5,
    ("blinn-phong", True): 0.9**5 * 0.8,
    ("phong", False): 0.8**10,
    ("phong", True): 0.8**10 * 0.8,
}


def payload_scene():
    plane = ([(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)], 0)
    material = {"ka": 0.0, "kd": 0.0, "ks": 1.0, "ns": 10.0, "kr": 0.0}
    lights = fovjax.make_lights([(0.6, 0.0, 0.8)], [(1.0, 1.0, 1.0)], kind=[DIRECTIONAL_LIGHT])
    return _scene([plane], [material], lights)


def test_the_specular_payload_pixel_by_hand():
    """The pixel the issue measured: fovjax's default gives 0.5905 where the literal reading of
    §4.4.3 (the specular times the shadow ray's payload n·l) gives 0.4724, in both
    integrators; Phong's eq. 1 on the same pixel, with and without the payload."""
    scene = payload_scene()
    camera = fovjax.Camera.look_at((0.0, 0.0, 4.0), (0.0, 0.0, 0.0), vfov_deg=20.0, width=SIZE, height=SIZE)
    for integrator in integrators():
        for (specular, payload), expected in PAYLOAD_PIXEL.items():
            config = RenderConfig(
                max_depth=0, specular=specular, specular_payload=payload, integrator=integrator
            )
            rgb = np.asarray(_radiance(scene, camera, config).rgb)[0, SIZE // 2, SIZE // 2]
            np.testing.assert_allclose(rgb, expected, rtol=1e-5, err_msg=f"{integrator} {specular} {payload}")
    assert round(PAYLOAD_PIXEL["blinn-phong", False], 4) == 0.5905
    assert round(PAYLOAD_PIXEL["blinn-phong", True], 4) == 0.4724


def test_defaults_are_fovjaxs_and_each_option_is_checked():
    config = RenderConfig()
    assert (config.specular, config.specular_payload, config.min_contribution) == ("blinn-phong", False, 0.0)
    with pytest.raises(ValueError, match="specular must be one of .* got 'cook-torrance'"):
        RenderConfig(specular="cook-torrance")
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match=r"min_contribution must be a number in \[0, 1\]"):
            RenderConfig(min_contribution=bad)
    doc = " ".join(RenderConfig.__doc__.split())
    for item in ("`specular`:", "`specular_payload`:", "`min_contribution`:", "§4.4.3", "§2.5.2", "eq. 1"):
        assert item in doc, item


# ---- the corridor: facing mirrors, three kinds of light ---------------------------------------

HALF_WIDTH = 1.0
KR = 0.5  # every mirror's: a path's weight after k bounces is 0.5^k exactly


def corridor_scene(*, spot_cone=(15.0, 30.0)):
    """Two facing mirrors (x = ±1, Kr 0.5 grey, a glossy tint) over a diffuse floor, a back
    wall, a point light, a spot light shining down on the floor and a directional light."""
    w = HALF_WIDTH
    quads = [
        ([(-w, 0, -9), (-w, 0, 2), (-w, 2.5, 2), (-w, 2.5, -9)], 0),  # left mirror, facing +x
        ([(w, 0, -9), (w, 2.5, -9), (w, 2.5, 2), (w, 0, 2)], 1),  # right mirror, facing -x
        ([(-w, 0, -9), (w, 0, -9), (w, 0, 2), (-w, 0, 2)], 2),  # floor, facing +y
        ([(-w, 0, -9), (-w, 2.5, -9), (w, 2.5, -9), (w, 0, -9)], 3),  # back wall, facing +z
    ]
    mirror = {"kd": (0.05, 0.06, 0.04), "ks": 0.4, "ns": 48.0, "kr": KR}
    materials = [
        mirror,
        {**mirror, "kd": (0.04, 0.05, 0.07)},
        {"kd": (0.6, 0.55, 0.5), "ka": (0.6, 0.55, 0.5), "ks": 0.2, "ns": 16.0},
        {"kd": (0.3, 0.5, 0.4), "ka": (0.3, 0.5, 0.4), "ks": 0.3, "ns": 32.0},
    ]
    lights = fovjax.make_lights(
        [(0.2, 2.2, -1.5), (-0.3, 2.3, -5.0), (0.3, 1.0, 0.4)],
        [(0.6, 0.6, 0.55), (0.9, 0.8, 0.6), (0.25, 0.25, 0.3)],
        kind=[POINT_LIGHT, SPOT_LIGHT, DIRECTIONAL_LIGHT],
        direction=[(0, 0, 0), (0.2, -1.0, 0.1), (0, 0, 0)],
        cone_deg=[(180, 180), spot_cone, (180, 180)],
    )
    return _scene(quads, materials, lights, ambient=(0.1, 0.1, 0.1))


def corridor_camera(width=32, height=24):
    # Looking obliquely at the left mirror: the rays bounce from mirror to mirror down the corridor.
    return fovjax.Camera.look_at(
        (0.6, 1.2, 1.5), (-1.0, 0.9, -2.5), vfov_deg=50.0, width=width, height=height
    )


# fovjax's defaults, and every option the other way (each option alone is checked against hand
# computation above and below).
ALL_OPTIONS = [{}, {"specular": "phong", "specular_payload": True, "min_contribution": 0.1}]


@pytest.mark.parametrize(
    "options", ALL_OPTIONS, ids=lambda o: "-".join(f"{k}={v}" for k, v in o.items()) or "defaults"
)
def test_native_equals_the_jax_integrator_with_every_option(options):
    """Every option and the spot light in both integrators: the same rays traced, kind by kind,
    and every sample to float rounding; the scene reflects to depth 5 and its spot light lights
    part of the floor."""
    if not native_available():
        pytest.skip("the native integrator is not built here")
    scene, camera = corridor_scene(), corridor_camera()
    out = {
        name: _radiance(scene, camera, RenderConfig(max_depth=5, integrator=name, **options))
        for name in ("native", "jax")
    }
    native, reference = out["native"], out["jax"]
    np.testing.assert_allclose(np.asarray(native.rgb), np.asarray(reference.rgb), rtol=RTOL, atol=ATOL)
    assert [int(c) for c in native.counts] == [int(c) for c in reference.counts]
    assert int(reference.counts.reflection) > int(reference.counts.primary)  # bounces down the corridor
    assert np.asarray(reference.rgb).std() > 0.05


@pytest.mark.parametrize("integrator", ["jax", "native"])
def test_the_cut_off_is_the_depth_its_weight_allows(integrator):
    """Every mirror's Kr is 0.5 grey, so a path's weight after k bounces is 0.5^k: a cut-off of
    0.1 keeps bounces 1-3 (0.125 >= 0.1 > 0.0625), so at max_depth 5 the ray counts are those of
    max_depth 3 without a cut-off, exactly, and the image the same to float rounding (the
    programs differ, and XLA may sum a pixel's bounces in another order); and they are not
    max_depth 5's (the corridor's deeper bounces change the image)."""
    if integrator == "native" and not native_available():
        pytest.skip("the native integrator is not built here")
    scene, camera = corridor_scene(), corridor_camera()

    def frame(depth, cut):
        return _radiance(
            scene, camera, RenderConfig(max_depth=depth, min_contribution=cut, integrator=integrator)
        )

    deep, cut, shallow = frame(5, 0.0), frame(5, 0.1), frame(3, 0.0)
    np.testing.assert_allclose(np.asarray(cut.rgb), np.asarray(shallow.rgb), rtol=2.0**-20, atol=2.0**-24)
    assert [int(c) for c in cut.counts] == [int(c) for c in shallow.counts]
    assert int(cut.counts.reflection) < int(deep.counts.reflection)
    assert np.abs(np.asarray(cut.rgb) - np.asarray(deep.rgb)).max() > 1e-3


# ---- spot lights --------------------------------------------------------------------------------

SPOT_APEX = (0.0, 2.0, 0.0)


def spot_floor_scene(cone_deg, kind=SPOT_LIGHT):
    """A floor y = 0 (Kd 0.5, nothing else) under one light at SPOT_APEX shining straight down."""
    floor = ([(-4, 0, -4), (-4, 0, 4), (4, 0, 4), (4, 0, -4)], 0)
    lights = fovjax.make_lights(
        [SPOT_APEX], [(1.0, 0.9, 0.8)], kind=[kind], direction=[(0.0, -1.0, 0.0)], cone_deg=[cone_deg]
    )
    return _scene([floor], [{"ka": 0.0, "kd": 0.5, "ks": 0.0, "kr": 0.0}], lights)


def floor_camera(size=SIZE):
    return fovjax.Camera.look_at(
        (0.0, 5.0, 0.0), (0.0, 0.0, 0.0), up=(0, 0, -1), vfov_deg=40.0, width=size, height=size
    )


def spot_by_hand(camera, cone_deg):
    """Each pixel's radiance under the spot light (float64), its cone factor and cos θ."""
    o, d, _ = camera.sample_rays(1, None)
    o, d = np.asarray(o[0], np.float64), np.asarray(d[0], np.float64)
    p = o - d * (o[..., 1:2] / d[..., 1:2])  # the floor y = 0
    to_light = np.asarray(SPOT_APEX) - p
    l_dir = to_light / np.linalg.norm(to_light, axis=-1, keepdims=True)
    cos = l_dir[..., 1]  # the angle from the axis (0, -1, 0); also n·l, n = +y
    inner, outer = np.cos(np.radians(cone_deg))
    factor = (
        np.clip((cos - outer) / max(inner - outer, 1e-300), 0.0, 1.0)
        if inner > outer
        else (cos >= inner) * 1.0
    )
    return 0.5 * cos[..., None] * factor[..., None] * np.asarray([1.0, 0.9, 0.8]), factor, cos


@pytest.mark.parametrize("cone_deg", [(20.0, 30.0), (25.0, 25.0)], ids=["falloff", "hard-cone"])
def test_spot_light_by_hand(cone_deg):
    """A spot light over a floor: each pixel's Kd·(n·l)·colour·factor (1 within the inner
    half-angle, 0 beyond the outer, linear in the cosine between; the thesis's hard-edged cone
    when they are equal), and a shadow ray only where the factor is above 0, in both
    integrators."""
    scene, camera = spot_floor_scene(cone_deg), floor_camera()
    expected, factor, cos = spot_by_hand(camera, cone_deg)
    assert 0 < (factor == 0).sum() and 0 < (factor == 1).sum()  # the image spans the cone's edge
    # Pixels within float rounding of the outer edge may take either side.
    edge = np.abs(cos - np.cos(np.radians(cone_deg[1]))) < 1e-5
    if cone_deg[0] == cone_deg[1]:
        edge |= np.abs(cos - np.cos(np.radians(cone_deg[0]))) < 1e-5
    for integrator in integrators():
        out = _radiance(scene, camera, RenderConfig(max_depth=0, integrator=integrator))
        rgb = np.asarray(out.rgb)[0]
        np.testing.assert_allclose(rgb[~edge], expected[~edge], atol=1e-5, err_msg=integrator)
        shadow = int(out.counts.shadow)
        assert int((factor > 0)[~edge].sum()) <= shadow <= int((factor > 0).sum() + edge.sum()), integrator


def test_a_spot_of_180_degrees_is_the_point_light():
    """A cone of half-angle 180° takes in every direction: the image and ray counts are the
    point light's, bit for bit."""
    camera = floor_camera()
    for integrator in integrators():
        config = RenderConfig(max_depth=0, integrator=integrator)
        spot = _radiance(spot_floor_scene((180.0, 180.0)), camera, config)
        point = _radiance(spot_floor_scene((180.0, 180.0), kind=POINT_LIGHT), camera, config)
        np.testing.assert_array_equal(np.asarray(spot.rgb), np.asarray(point.rgb))
        assert [int(c) for c in spot.counts] == [int(c) for c in point.counts]


def test_the_spot_lights_axis_is_differentiable():
    """d(mean image)/d(the spot's axis) through the cone's falloff (the JAX integrator, whose
    derivatives both integrators share) against a central difference."""
    scene, camera = spot_floor_scene((10.0, 40.0)), floor_camera()
    arrays = scene_arrays(scene)
    o, d, _ = camera.sample_rays(1, None)
    bvh = build_bvh(scene, cache=False)
    config = RenderConfig(max_depth=0, integrator="jax")

    def mean_image(tilt):
        axis = jnp.stack([tilt, -1.0, 0.0 * tilt])
        axis = axis / jnp.linalg.norm(axis)
        a = dataclasses.replace(arrays, light_direction=axis[None])
        return jnp.mean(radiance(a, bvh, o, d, config=config).rgb)

    tilt, eps = jnp.float32(0.5), 1e-2  # the axis tilted 27°: the mean falls steeply
    derivative = float(jax.jit(jax.grad(mean_image))(tilt))
    f = jax.jit(mean_image)
    difference = (float(f(tilt + eps)) - float(f(tilt - eps))) / (2 * eps)
    assert abs(derivative) > 1e-2
    np.testing.assert_allclose(derivative, difference, rtol=0.05)


def test_spot_lights_are_checked_naming_the_light():
    position, color = [(0, 1, 0), (0, 2, 0)], [(1, 1, 1), (1, 1, 1)]
    kinds = [POINT_LIGHT, SPOT_LIGHT]
    with pytest.raises(ValueError, match="light 1 is a spot light and needs a direction"):
        fovjax.make_lights(position, color, kind=kinds, cone_deg=[30, 30])
    with pytest.raises(ValueError, match="light 1 is a spot light and needs cone_deg"):
        fovjax.make_lights(position, color, kind=kinds, direction=[(0, 0, 0), (0, -1, 0)])
    with pytest.raises(ValueError, match=r"spot light 1 has cone_deg \(inner 40, outer 30\)"):
        fovjax.make_lights(
            position, color, kind=kinds, direction=[(0, 0, 0), (0, -1, 0)], cone_deg=[(0, 0), (40, 30)]
        )
    with pytest.raises(
        ValueError, match=r"spot light 1 has direction \[0.0, 0.0, 0.0\], expected a nonzero axis"
    ):
        fovjax.make_lights(position, color, kind=kinds, direction=[(0, 0, 0), (0, 0, 0)], cone_deg=[30, 30])
    with pytest.raises(ValueError, match="light 0 has kind 7"):
        fovjax.make_lights(position, color, kind=[7, POINT_LIGHT])
    lights = fovjax.make_lights(
        position, color, kind=kinds, direction=[(0, 0, 0), (0, -2, 0)], cone_deg=[90, 30]
    )
    np.testing.assert_array_equal(lights.cone_deg[1], [30.0, 30.0])  # one angle: a hard-edged cone
    kept = lights.take([1])  # what `fovjax inspect`'s light-by-light frames use
    assert int(kept.kind[0]) == SPOT_LIGHT and np.allclose(kept.direction, [(0, -2, 0)])
    arrays = scene_arrays(spot_floor_scene((20.0, 30.0)))
    np.testing.assert_allclose(np.asarray(arrays.light_direction), [(0.0, -1.0, 0.0)])
    np.testing.assert_allclose(np.asarray(arrays.light_cone), [np.cos(np.radians([20.0, 30.0]))], rtol=1e-6)
