"""Renderer oracles: hand-computed pixels, shadows, mirrors, acne, env-map axes, stereo geometry,
head pose, sample convergence, bad colour, recompilation, images and the CLI.

Every JAX render here uses the oracle scene at 15 x 15 (or two 15 x 12 eyes) with max_depth 1,
so the whole file compiles three programs (mono spp 1, mono spp 16 — shared with the reference
test — and stereo spp 1); per-test variations are array values (materials, lights, cameras,
background), which do not recompile.
"""

from __future__ import annotations

import dataclasses
import math

import _extras
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_render_reference import FLOOR, LIGHT, SIZE, SPHERE, TARGET, envmap_image, oracle_scene

import fovjax
from fovjax.render import (
    RenderConfig,
    StereoRig,
    compile_cache_info,
    envmap_lookup,
    head_rotation,
    latlong_uv,
    render,
    render_stereo,
    resolve,
    scene_arrays,
    stereo_sample_rays,
)
from fovjax.render._frame import TRACE_COUNTS
from fovjax.trace import build_bvh

CONFIG = RenderConfig(max_depth=1)
BACKGROUND = np.array(fovjax.render.THESIS_BACKGROUND, np.float32)


@pytest.fixture(scope="module")
def oracle():
    scene = oracle_scene()
    return scene, build_bvh(scene, cache=False)


def arrays_with(scene, *, background=BACKGROUND, envmap=None, **changes):
    """The oracle's SceneArrays with some arrays replaced (same shapes: no recompile)."""
    envmap = np.asarray(background, np.float32).reshape(1, 1, 3) if envmap is None else envmap
    arrays = scene_arrays(scene, envmap=envmap)
    return dataclasses.replace(arrays, **changes) if changes else arrays


def material(arrays, name, row, value):
    table = np.array(getattr(arrays, name), copy=True)
    table[row] = value
    return table


def shade(arrays, m, p, n, view_dir, light_pos=LIGHT, light_color=(1, 1, 1), kd=None):
    """Blinn–Phong at point p with unit normal n, seen along view_dir, by hand (no shadow)."""
    ka, ks, ns = (np.asarray(getattr(arrays, k), np.float64)[m] for k in ("ka", "ks", "ns"))
    kd = np.asarray(arrays.kd, np.float64)[m] if kd is None else kd
    amb = np.asarray(arrays.ambient, np.float64)
    to_l = np.asarray(light_pos, np.float64) - p
    l_dir = to_l / np.linalg.norm(to_l, axis=-1, keepdims=True)
    ndl = np.sum(n * l_dir, -1, keepdims=True)
    h = l_dir - view_dir
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    ndh = np.sum(n * h, -1, keepdims=True)
    lit = ndl > 0
    return ka * amb + np.where(lit, kd * ndl + ks * np.maximum(ndh, 0) ** ns, 0.0) * np.asarray(light_color)


# ---- single pixels against hand computation ------------------------------------------------


def test_lit_sphere_centre_pixel_by_hand(oracle):
    scene, bvh = oracle
    arrays = arrays_with(scene)
    camera = fovjax.Camera.look_at((0.0, 1.0, 6.0), (0.0, 1.0, 0.0), vfov_deg=30.0, width=SIZE, height=SIZE)
    frame = fovjax.render(arrays, camera, config=CONFIG, bvh=bvh)  # the subpackage is callable
    # The centre ray meets the sphere's front pole (0, 1, 1), an icosphere vertex with normal +z;
    # the mirror direction there (+z) escapes to the background.
    p, n, view = np.array([0.0, 1.0, 1.0]), np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])
    expected = shade(arrays, SPHERE, p, n, view) + np.asarray(arrays.kr)[SPHERE] * BACKGROUND
    np.testing.assert_allclose(frame.image[SIZE // 2, SIZE // 2], expected, atol=2e-5)
    assert frame.stats.primary_rays == SIZE * SIZE
    assert frame.stats.bad_pixels == 0


def test_specular_is_not_scaled_by_n_dot_l_a_stated_departure(oracle):
    """fovjax.render's docstring states it: per light Kd·(n·l) + Ks·(n·h)^Ns, where the thesis's
    §4.4.3 scales both terms by n·l. A light 80° from the normal at the sphere's front pole
    (n·l = 0.17), Kd = 0, Ns = 1: the highlight is Ks·(n·h), six times the thesis's."""
    scene, bvh = oracle
    base = scene_arrays(scene)
    p, n, view = np.array([0.0, 1.0, 1.0]), np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])
    to_light = np.array([0.0, np.sin(np.radians(80.0)), np.cos(np.radians(80.0))])
    light = (p + 9.0 * to_light)[None].astype(np.float32)  # above the pole: nothing in between
    arrays = arrays_with(
        scene,
        kd=material(base, "kd", SPHERE, 0.0),
        kr=material(base, "kr", SPHERE, 0.0),
        ns=material(base, "ns", SPHERE, 1.0),
        light_position=light,
    )
    camera = fovjax.Camera.look_at((0.0, 1.0, 6.0), (0.0, 1.0, 0.0), vfov_deg=30.0, width=SIZE, height=SIZE)
    pixel = np.asarray(fovjax.render(arrays, camera, config=CONFIG, bvh=bvh).image[SIZE // 2, SIZE // 2])
    ambient = np.asarray(arrays.ka, np.float64)[SPHERE] * np.asarray(arrays.ambient, np.float64)
    half = to_light - view
    n_dot_h, n_dot_l = float(n @ half / np.linalg.norm(half)), float(n @ to_light)
    ks = np.asarray(arrays.ks, np.float64)[SPHERE]
    np.testing.assert_allclose(pixel, ambient + ks * n_dot_h, atol=2e-5)
    thesis = ambient + ks * n_dot_h * n_dot_l
    assert np.all(pixel - thesis > 0.2)


def test_default_miss_colour_is_the_constant_background_a_stated_departure():
    """Without an environment map a miss sees RenderConfig.background (the thesis's OptiX
    "bg color"), not an environment map as the thesis's miss program samples: stated in
    fovjax.render's docstring and `fovjax render --envmap`'s help."""
    from fovjax.cli import build_parser

    assert RenderConfig().background == fovjax.render.THESIS_BACKGROUND == (0.34, 0.55, 0.85)
    environment = np.asarray(scene_arrays(oracle_scene()).environment)
    np.testing.assert_array_equal(environment.reshape(-1, 3), np.float32([fovjax.render.THESIS_BACKGROUND]))
    doc = " ".join(fovjax.render.__doc__.split())
    assert "the thesis's miss program (§4.4.4) samples an environment map" in doc
    assert "the specular term is not multiplied by n·l" in doc
    render_parser = build_parser()._subparsers._group_actions[0].choices["render"]
    (envmap,) = [a for a in render_parser._actions if "--envmap" in a.option_strings]
    assert "constant background colour" in envmap.help and "not an environment map" in envmap.help


def test_shadowed_point_under_occluder_is_ambient_only(oracle):
    scene, bvh = oracle
    arrays = arrays_with(scene, kr=material(scene_arrays(scene), "kr", FLOOR, 0.0))
    # Shadow of the shelf's centre (-5, 2, 3) cast by the light (2, 8, 2) on the floor y = 0.
    t = LIGHT[1] / (LIGHT[1] - 2.0)
    shadow = np.array([LIGHT[0] + t * (-5.0 - LIGHT[0]), 0.0, LIGHT[2] + t * (3.0 - LIGHT[2])])
    camera = fovjax.Camera.look_at(shadow + (0.0, 5.0, 6.0), shadow, vfov_deg=10.0, width=SIZE, height=SIZE)
    image = render(arrays, camera, config=CONFIG, bvh=bvh).image
    centre = image[SIZE // 2, SIZE // 2]
    ka_amb = np.asarray(arrays.ka)[FLOOR] * np.asarray(arrays.ambient)
    np.testing.assert_allclose(centre, ka_amb, atol=1e-6)
    # the same floor point without the shelf's shadow would be lit
    view = shadow - camera.position
    lit = shade(arrays, FLOOR, shadow, np.array([0.0, 1.0, 0.0]), view / np.linalg.norm(view), kd=0.0)
    assert np.all(lit >= ka_amb) and (lit - ka_amb).max() > 0.01  # specular alone is visible
    # and a wide view of the same spot shows the shadow's outline: lit floor around it
    wide = fovjax.Camera.look_at(shadow + (0.0, 5.0, 6.0), shadow, vfov_deg=60.0, width=SIZE, height=SIZE)
    around = render(arrays, wide, config=CONFIG, bvh=bvh).image
    assert around.max() > centre.max() + 0.2


def test_mirror_shows_the_target_at_the_expected_pixel(oracle):
    scene, bvh = oracle
    arrays = arrays_with(scene)
    # From (2, 1.5, 4) the ray to the mirror's centre (6, 1.5, 0) reflects along (-1, 0, -1) and
    # meets the target plane z = -5 at x = 1, inside the emissive green quad.
    camera = fovjax.Camera.look_at((2.0, 1.5, 4.0), (6.0, 1.5, 0.0), vfov_deg=20.0, width=SIZE, height=SIZE)
    image = render(arrays, camera, config=CONFIG, bvh=bvh).image
    np.testing.assert_allclose(image[SIZE // 2, SIZE // 2], [0.0, 1.0, 0.0], atol=1e-6)


def test_no_acne_on_a_flat_plane_under_grazing_light(oracle):
    scene, bvh = oracle
    base = scene_arrays(scene)
    light = np.array([[20.0, 1.0, 7.0]], np.float32)  # low and far: shadow rays graze the floor
    arrays = arrays_with(scene, kr=material(base, "kr", FLOOR, 0.0), light_position=light)
    camera = fovjax.Camera.look_at((5.5, 5.0, 10.0), (5.5, 0.0, 7.0), vfov_deg=35.0, width=SIZE, height=SIZE)
    image = render(arrays, camera, config=CONFIG, bvh=bvh).image
    # every pixel sees open floor lit by the light: compare with the unshadowed shading by hand
    o, d, _ = camera.sample_rays(1)
    o, d = np.asarray(o[0], np.float64), np.asarray(d[0], np.float64)
    p = o - (o[..., 1:2] / d[..., 1:2]) * d
    tex = fovjax.render.internal.bilinear_wrap(
        jnp.asarray(scene.textures[0]), jnp.asarray(p[..., [0, 2]] / 4.0)
    )
    kd = np.asarray(base.kd, np.float64)[FLOOR] * np.asarray(tex, np.float64)
    expected = shade(arrays, FLOOR, p, np.array([0.0, 1.0, 0.0]), d, light_pos=light[0], kd=kd)
    assert np.all(p[..., 0] > 0) and np.all(p[..., 2] > 4)  # open floor: every occluder is at z <= 4
    np.testing.assert_allclose(image, expected, atol=1e-4)


def test_directional_light_and_exception_colour(oracle):
    scene, bvh = oracle
    base = scene_arrays(scene)
    camera = fovjax.Camera.look_at((0.0, 1.0, 6.0), (0.0, 1.0, 0.0), vfov_deg=30.0, width=SIZE, height=SIZE)
    # a directional light straight along +z (towards the camera side) at the front pole
    arrays = arrays_with(
        scene,
        light_position=np.array([[0.0, 0.0, 1.0]], np.float32),
        light_kind=np.array([fovjax.DIRECTIONAL_LIGHT], np.int32),
    )
    image = render(arrays, camera, config=CONFIG, bvh=bvh).image
    kd, ks, ka = (np.asarray(getattr(base, k))[SPHERE] for k in ("kd", "ks", "ka"))
    expected = ka * 0.2 + kd + ks + np.asarray(base.kr)[SPHERE] * BACKGROUND
    np.testing.assert_allclose(image[SIZE // 2, SIZE // 2], expected, atol=2e-5)
    # a NaN light colour poisons every lit sample: those pixels become magenta, counted
    poisoned = arrays_with(scene, light_color=np.array([[np.nan, 1.0, 1.0]], np.float32))
    frame = render(poisoned, camera, config=CONFIG, bvh=bvh)
    assert np.isfinite(frame.image).all()
    bad = np.all(frame.image == np.array(CONFIG.bad_color, np.float32), axis=-1)
    assert frame.stats.bad_pixels == bad.sum() > 0
    assert frame.stats.bad_samples == frame.stats.bad_pixels  # spp 1
    assert bad[SIZE // 2, SIZE // 2]


def test_inactive_rays_cost_nothing_and_return_zero(oracle):
    scene, bvh = oracle
    arrays = arrays_with(scene)
    camera = fovjax.Camera.look_at((-3.0, 4.0, 9.0), (1.0, 1.0, 0.0), vfov_deg=70.0, width=SIZE, height=SIZE)
    o, d, _ = camera.sample_rays(1)
    active = jnp.zeros((1, SIZE, SIZE), bool).at[0, ::3, ::2].set(True)
    # depth 0: primary and shadow rays only (and a program that compiles quickly)
    config = RenderConfig(max_depth=0)
    run = jax.jit(lambda a, o, d, m: fovjax.render.radiance(a, bvh, o, d, m, config=config))
    full = run(arrays, o, d, jnp.ones_like(active))
    part = run(arrays, o, d, active)
    assert int(part.counts.primary) == int(active.sum()) and int(full.counts.primary) == SIZE * SIZE
    assert 0 < int(part.counts.shadow) < int(full.counts.shadow)
    assert int(full.counts.reflection) == 0
    np.testing.assert_array_equal(np.asarray(part.rgb)[~np.asarray(active)], 0.0)
    np.testing.assert_allclose(
        np.asarray(part.rgb)[np.asarray(active)], np.asarray(full.rgb)[np.asarray(active)]
    )


# ---- environment map -----------------------------------------------------------------------


def test_envmap_mapping_along_the_six_axes():
    axes = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float32)
    uv = np.asarray(latlong_uv(axes))
    # theta = atan2(dx, dz), phi = pi/2 - acos(dy); u = (theta + pi)/2pi, v = (1 + sin phi)/2
    expected_u = [0.75, 0.25, 0.5, 0.5, 0.5, 0.0]  # poles: theta taken as 0
    expected_v = [0.5, 0.5, 1.0, 0.0, 0.5, 0.5]
    np.testing.assert_allclose(uv[:, 1], expected_v, atol=1e-6)
    np.testing.assert_allclose(uv[[0, 1, 4], 0], np.array(expected_u)[[0, 1, 4]], atol=1e-6)
    assert uv[5, 0] == pytest.approx(0.0, abs=1e-6) or uv[5, 0] == pytest.approx(1.0, abs=1e-6)
    # a map with one colour per column band: each horizontal axis reads its own texel centre
    env = np.zeros((4, 8, 3), np.float32)
    env[..., 0] = np.arange(8)[None, :]  # column index in red
    env[..., 1] = np.arange(4)[:, None]  # row index in green
    horizon = np.array([[1, 0, 0], [-1, 0, 0], [0, 0, 1]], np.float32)
    got = np.asarray(envmap_lookup(jnp.asarray(env), horizon))
    # u = 0.75, 0.25, 0.5 → x = u * 8 - 0.5 = 5.5, 1.5, 3.5 (between two columns); v = 0.5 → rows 1.5
    np.testing.assert_allclose(got[:, 0], [5.5, 1.5, 3.5], atol=1e-5)
    np.testing.assert_allclose(got[:, 1], [1.5, 1.5, 1.5], atol=1e-5)
    up, down = np.asarray(envmap_lookup(jnp.asarray(env), np.array([[0, 1, 0], [0, -1, 0]], np.float32)))
    assert up[1] == 0.0 and down[1] == 3.0  # the top row is the zenith, clamped
    np.testing.assert_allclose(
        envmap_lookup(jnp.asarray(BACKGROUND.reshape(1, 1, 3)), horizon), [BACKGROUND] * 3
    )


@_extras.needs("cv2")
def test_envmap_loads_from_hdr_and_ldr_files(tmp_path):
    env = np.random.default_rng(0).uniform(0, 4, (4, 8, 3)).astype(np.float32)
    fovjax.save_image(tmp_path / "sky.exr", env)
    np.testing.assert_array_equal(fovjax.render.load_envmap(tmp_path / "sky.exr"), env)
    fovjax.save_image(tmp_path / "sky.hdr", env)
    np.testing.assert_allclose(fovjax.render.load_envmap(tmp_path / "sky.hdr"), env, atol=0.04)  # RGBE
    fovjax.save_image(tmp_path / "sky.png", env / 4)
    np.testing.assert_allclose(fovjax.render.load_envmap(tmp_path / "sky.png"), env / 4, atol=0.01)
    with pytest.raises(ValueError, match="no such file"):
        fovjax.render.load_envmap(tmp_path / "missing.hdr")


# ---- stereo rig and head pose --------------------------------------------------------------

EYE_W, EYE_H, EYE_FOV = 41, 30, 60.0
# every stereo frame here jitters its samples (one compiled program for all of them)
KEY = jax.random.key(7)


def marker_arrays(scene):
    """Everything black except the sphere, which glows red: a marker for projections."""
    base = scene_arrays(scene)
    zero = np.zeros_like(np.asarray(base.kd))
    ke = zero.copy()
    ke[SPHERE] = (1.0, 0.0, 0.0)
    return arrays_with(
        scene,
        background=np.zeros(3),
        ka=zero,
        kd=zero,
        ks=zero,
        kr=zero,
        ke=ke,
        ambient=np.zeros(3, np.float32),
    )


def red_centroid(eye_image):
    mask = eye_image[..., 0] > 0.5
    rows, cols = np.nonzero(mask)
    return cols.mean() + 0.5, rows.mean() + 0.5, mask.sum()


def test_stereo_rig_thesis_defaults():
    rig = StereoRig.look_at((0.0, 1.7, 0.0), (0.0, 1.7, -1.0))
    assert (rig.eye_width, rig.eye_height, rig.width, rig.height) == (1280, 1024, 2560, 1024)
    assert float(rig.ipd) == pytest.approx(0.064) and float(rig.toe_out_deg) == 13.0
    left, right = rig.eye_cameras()
    np.testing.assert_allclose(np.asarray(right.position - left.position), [0.064, 0, 0], atol=1e-7)
    # 90 degrees horizontal per eye: the image plane's half-width is tan(45°) = 1
    half_w = math.tan(math.radians(float(left.vfov_deg)) / 2) * 1280 / 1024
    assert half_w == pytest.approx(1.0, rel=1e-5)
    # toe-out: the left eye looks 13 degrees to the left of the head's forward (-z)
    fwd_l = -np.asarray(left.rotation)[:, 2]
    fwd_r = -np.asarray(right.rotation)[:, 2]
    assert math.degrees(math.atan2(-fwd_l[0], -fwd_l[2])) == pytest.approx(13.0, abs=1e-4)
    assert math.degrees(math.atan2(fwd_r[0], -fwd_r[2])) == pytest.approx(13.0, abs=1e-4)
    with pytest.raises(ValueError, match="fov_axis"):
        StereoRig.look_at((0, 0, 0), (0, 0, -1), fov_axis="diagonal")


def test_head_rotation_matches_the_intersense_euler_convention():
    # InertiaCube: x forward, y right, z down; R = Rz(yaw) Ry(pitch) Rx(roll). Our head frame:
    # x right, y up, z backward. Conjugating by the axis map must give head_rotation.
    def rz(a):
        c, s = math.cos(a), math.sin(a)
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])

    def ry(a):
        c, s = math.cos(a), math.sin(a)
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])

    def rx(a):
        c, s = math.cos(a), math.sin(a)
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])

    # columns: the InertiaCube axes (forward, right, down) in head coordinates
    axes = np.array([[0, 1, 0], [0, 0, -1], [-1, 0, 0]], np.float64)
    for yaw, pitch, roll in [(30, 0, 0), (0, 20, 0), (0, 0, 15), (40, -25, 10), (-120, 60, -30)]:
        r_ic = rz(math.radians(yaw)) @ ry(math.radians(pitch)) @ rx(math.radians(roll))
        expected = axes @ r_ic @ axes.T
        np.testing.assert_allclose(np.asarray(head_rotation((yaw, pitch, roll))), expected, atol=1e-6)
    forward = np.array([0.0, 0.0, -1.0])
    assert (np.asarray(head_rotation((30, 0, 0))) @ forward)[0] > 0  # yaw right
    assert (np.asarray(head_rotation((0, 20, 0))) @ forward)[1] > 0  # pitch up
    assert (np.asarray(head_rotation((0, 0, 15))) @ np.array([1.0, 0, 0]))[1] < 0  # right ear down
    from fovjax.devices import HeadPose

    np.testing.assert_allclose(head_rotation(HeadPose(0.0, 40, -25, 10)), head_rotation((40, -25, 10)))


@pytest.fixture(scope="module")
def stereo_setup(oracle):
    scene, bvh = oracle
    ipd = 1.0  # a wide rig, so the parallax is many pixels
    rig = StereoRig.look_at(
        (0.0, 1.0, 8.0), (0.0, 1.0, 0.0), eye_width=EYE_W, eye_height=EYE_H, fov_deg=EYE_FOV, ipd=ipd
    )
    return scene, bvh, rig, marker_arrays(scene)


def test_stereo_disparity_of_a_point_at_known_depth(stereo_setup):
    scene, bvh, rig, arrays = stereo_setup
    frame = render_stereo(arrays, rig, key=KEY, config=CONFIG, bvh=bvh)
    assert frame.image.shape == (EYE_H, 2 * EYE_W, 3) and frame.stats.stereo
    left, right = frame.eyes()
    (xl, yl, nl), (xr, yr, nr) = red_centroid(left), red_centroid(right)
    assert nl > 3 and nr > 3
    # sphere centre 8 m ahead; each eye 0.5 m off the axis and toed out 13 degrees:
    # the centre lies atan(0.5 / 8) + 13° to the right of the left eye's axis (left of the right's)
    angle = math.atan(0.5 / 8.0) + math.radians(13.0)
    shift = EYE_W / 2 * math.tan(angle) / math.tan(math.radians(EYE_FOV / 2))
    assert xl == pytest.approx(EYE_W / 2 + shift, abs=0.5)
    assert xr == pytest.approx(EYE_W / 2 - shift, abs=0.5)
    assert xl - xr == pytest.approx(2 * shift, abs=0.6)  # the disparity
    assert yl == pytest.approx(EYE_H / 2, abs=0.3) and yr == pytest.approx(EYE_H / 2, abs=0.3)
    # Camera.project agrees with the rendered position
    cams = rig.eye_cameras()
    xy = [np.asarray(c.project(jnp.array([0.0, 1.0, 0.0]))[0]) for c in cams]
    assert xy[0][0] == pytest.approx(EYE_W / 2 + shift, abs=1e-3)
    assert xy[1][0] == pytest.approx(EYE_W / 2 - shift, abs=1e-3)


def test_head_yaw_90_shows_what_was_to_the_side(stereo_setup):
    scene, bvh, rig, arrays = stereo_setup
    # the same head looking along -x: the sphere is 90 degrees to its right
    side = StereoRig.look_at(
        (0.0, 1.0, 8.0), (-5.0, 1.0, 8.0), eye_width=EYE_W, eye_height=EYE_H, fov_deg=EYE_FOV, ipd=1.0
    )
    ahead = render_stereo(arrays, side, key=KEY, config=CONFIG, bvh=bvh)
    assert ahead.image[..., 0].max() < 0.5  # nothing red in view
    turned = render_stereo(arrays, side, head_pose=(90.0, 0.0, 0.0), key=KEY, config=CONFIG, bvh=bvh)
    straight = render_stereo(arrays, rig, key=KEY, config=CONFIG, bvh=bvh)
    same = np.all(np.abs(turned.image - straight.image) < 1e-3, axis=-1)
    assert same.mean() > 0.98  # identical up to a rounding-flipped edge pixel
    assert red_centroid(turned.eyes()[0])[2] > 3


def test_second_stereo_frame_does_not_recompile(stereo_setup):
    scene, bvh, rig, arrays = stereo_setup
    first = render_stereo(
        arrays, rig, head_pose=(5.0, 0.0, 0.0), key=jax.random.key(1), config=CONFIG, bvh=bvh
    )
    traces, programs = TRACE_COUNTS["stereo"], compile_cache_info()["stereo"]
    brighter = dataclasses.replace(arrays, light_color=np.array([[0.5, 0.2, 0.9]], np.float32))
    from fovjax.devices import HeadPose

    second = render_stereo(
        brighter, rig, head_pose=HeadPose(1.0, -7.0, 3.0, 2.0), key=jax.random.key(2), config=CONFIG, bvh=bvh
    )
    assert second.stats.compile_seconds == 0.0
    assert TRACE_COUNTS["stereo"] == traces and compile_cache_info()["stereo"] == programs
    assert first.stats.render_seconds > 0 and not np.array_equal(first.image, second.image)


def test_stereo_sample_rays_layout(stereo_setup):
    _, _, rig, _ = stereo_setup
    rays = stereo_sample_rays(rig, (10.0, 5.0, 0.0), spp=4, key=jax.random.key(0))
    assert rays.origins.shape == rays.directions.shape == (2, 4, EYE_H, EYE_W, 3)
    assert rays.pixel_xy.shape == (4, EYE_H, EYE_W, 2)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(rays.directions), axis=-1), 1.0, atol=1e-6)
    cell = np.floor(np.asarray(rays.pixel_xy) * 2) % 2  # stratified: sample s in cell (s % 2, s // 2)
    np.testing.assert_array_equal(
        cell[..., 0], np.array([0, 1, 0, 1])[:, None, None] + np.zeros((EYE_H, EYE_W))
    )
    np.testing.assert_array_equal(
        cell[..., 1], np.array([0, 0, 1, 1])[:, None, None] + np.zeros((EYE_H, EYE_W))
    )


# ---- samples per pixel ---------------------------------------------------------------------


def test_spp_16_converges_on_an_edge_where_spp_1_cannot(oracle):
    scene, bvh = oracle
    base = scene_arrays(scene)
    zero = np.zeros_like(np.asarray(base.kd))
    ke = zero.copy()
    ke[TARGET] = (0.0, 1.0, 0.0)
    black = {"ka": zero, "kd": zero, "ks": zero, "kr": zero, "ke": ke, "ambient": np.zeros(3, np.float32)}
    arrays = arrays_with(scene, background=np.zeros(3), **black)
    # the reference test's map shape for spp 16: the same compiled program
    arrays16 = arrays_with(scene, envmap=np.zeros_like(envmap_image()), **black)
    # look at the target's top-left corner (-1, 3, -5) with a rolled camera: slanted edges
    camera = fovjax.Camera.look_at(
        (-0.8, 2.8, 1.0), (-0.8, 2.8, -5.0), up=(0.3, 1.0, 0.0), vfov_deg=6.0, width=SIZE, height=SIZE
    )
    config = RenderConfig(max_depth=2)  # the reference test's program (spp 16, depth 2)
    one = render(arrays, camera, spp=1, config=CONFIG, bvh=bvh).image[..., 1]
    sixteen = render(arrays16, camera, spp=16, config=config, bvh=bvh).image[..., 1]
    # exact coverage of each pixel by the quad, from a 64 x 64 sub-grid (plane z = -5)
    k = 64
    sub = (np.arange(k) + 0.5) / k
    xs = np.arange(SIZE)[:, None] + sub[None, :]
    px, py = np.meshgrid(xs.reshape(-1), xs.reshape(-1))
    d = np.asarray(camera.ray_directions(jnp.asarray(np.stack([px, py], -1), jnp.float32)), np.float64)
    o = np.asarray(camera.position, np.float64)
    p = o + ((-5.0 - o[2]) / d[..., 2])[..., None] * d
    inside = (p[..., 0] >= -1) & (p[..., 0] <= 5) & (p[..., 1] >= 0) & (p[..., 1] <= 3)
    coverage = inside.reshape(SIZE, k, SIZE, k).mean(axis=(1, 3))
    edge = (coverage > 0) & (coverage < 1)
    assert edge.sum() >= 10
    err1 = np.abs(one - coverage)[edge]
    err16 = np.abs(sixteen - coverage)[edge]
    assert err16.max() <= 0.2 and err16.mean() < 0.05
    assert err1.mean() > 2.5 * err16.mean()
    # away from the edge both are exact
    np.testing.assert_allclose(sixteen[~edge], coverage[~edge], atol=1e-6)


def test_resolve_box_filter_and_bad_pixels():
    rgb = jnp.arange(4 * 2 * 3 * 3, dtype=jnp.float32).reshape(4, 2, 3, 3)
    bad = jnp.zeros((4, 2, 3), bool).at[2, 1, 1].set(True)
    image, bad_pixels = resolve(rgb, bad)
    np.testing.assert_allclose(np.asarray(image)[0, 0], np.asarray(rgb).mean(axis=0)[0, 0])
    np.testing.assert_array_equal(np.asarray(image)[1, 1], [1.0, 0.0, 1.0])
    assert int(bad_pixels.sum()) == 1


# ---- configuration, images, CLI ------------------------------------------------------------


@pytest.mark.no_typecheck
def test_config_and_argument_errors(oracle):
    scene, bvh = oracle
    with pytest.raises(ValueError, match="max_depth"):
        RenderConfig(max_depth=-1)
    with pytest.raises(ValueError, match="background"):
        RenderConfig(background=(1.0, 2.0))
    with pytest.raises(ValueError, match="backend"):
        RenderConfig(backend="optix")
    with pytest.raises(ValueError, match="hits must be one of"):
        RenderConfig(hits="embree")
    with pytest.raises(ValueError, match="packet"):
        RenderConfig(packet=(8, 0))
    camera = fovjax.Camera.look_at((0.0, 1.0, 6.0), (0.0, 1.0, 0.0), width=SIZE, height=SIZE)
    with pytest.raises(ValueError, match="spp must be a positive square"):
        render(scene, camera, spp=3, bvh=bvh)
    with pytest.raises(ValueError, match="head_pose"):
        render_stereo(scene, StereoRig.look_at((0, 1, 5), (0, 1, 0)), head_pose=(1.0, 2.0), bvh=bvh)
    other = build_bvh(fovjax.scenes.cornell_box())
    with pytest.raises(ValueError, match="triangles"):
        render(scene, camera, bvh=other)


def test_hits_from_the_backend_equal_the_recomputed_ones_and_differentiate_alike(oracle):
    """RenderConfig.hits="backend" takes t, u, v from the ray query instead of recomputing them
    from the vertices: the same faces, the same values up to float rounding, and the same
    derivatives with respect to the scene's vertices (the closed form either way)."""
    from fovjax.render._integrator import _trace_primary

    scene, bvh = oracle
    arrays = scene_arrays(scene)
    camera = fovjax.Camera.look_at((0.0, 1.0, 6.0), (0.0, 1.0, 0.0), width=SIZE, height=SIZE)
    o, d, _ = camera.sample_rays(1, None)
    alive = jnp.ones(o.shape[:-1], bool)

    def t_of(vertices, hits):
        a = dataclasses.replace(arrays, vertices=vertices)
        hit = _trace_primary(a, bvh, o, d, alive, packet=None, backend="auto", hits=hits)
        return hit.t, (hit.prim, hit.u, hit.v)

    vertices = jnp.asarray(arrays.vertices)
    tangent = jnp.asarray(np.random.default_rng(0).normal(size=vertices.shape), jnp.float32)
    out = {
        hits: jax.jit(lambda v, dv, hits=hits: jax.jvp(lambda x: t_of(x, hits), (v,), (dv,), has_aux=True))(
            vertices, tangent
        )
        for hits in ("recomputed", "backend")
    }
    (t_r, dt_r, (prim_r, u_r, v_r)), (t_b, dt_b, (prim_b, u_b, v_b)) = out["recomputed"], out["backend"]
    assert np.array_equal(prim_r, prim_b) and (np.asarray(prim_r) >= 0).any()
    hit = np.asarray(prim_r) >= 0
    for a, b in ((t_r, t_b), (u_r, u_b), (v_r, v_b)):  # float32 rounding of one intersection test
        np.testing.assert_allclose(np.asarray(a)[hit], np.asarray(b)[hit], rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(np.asarray(dt_r)[hit], np.asarray(dt_b)[hit], rtol=1e-4, atol=1e-5)
    assert np.isinf(np.asarray(t_b)[~hit]).all()


def test_png_is_tone_mapped_srgb_and_exr_is_linear(tmp_path):
    import imageio.v3 as iio

    image = np.array([[[0.0, 0.5, 1.0], [2.0, 0.0031308, 0.214]]], np.float32)
    fovjax.save_image(tmp_path / "a.png", image)
    png = iio.imread(tmp_path / "a.png")
    np.testing.assert_array_equal(png[0, 0], [0, 188, 255])  # sRGB(0.5) = 0.735
    np.testing.assert_array_equal(png[0, 1], [255, 10, 127])  # clipped; linear toe; 0.214 → 0.4995
    fovjax.save_image(tmp_path / "b.png", image, tonemap_curve="reinhard")
    assert iio.imread(tmp_path / "b.png")[0, 1, 0] < 255  # 2 → 2/3, not clipped
    _extras.require("cv2")
    fovjax.save_image(tmp_path / "a.exr", image)
    np.testing.assert_array_equal(fovjax.load_image(tmp_path / "a.exr"), image)
    with pytest.raises(ValueError, match="NaN"):
        fovjax.save_image(tmp_path / "c.png", np.full((1, 1, 3), np.nan, np.float32))


def test_cli_render_stereo_spheres(tmp_path, capsys):
    _extras.require("embreex")  # the Embree backend compiles in a second: a quick end-to-end run
    from fovjax.cli import main

    out = tmp_path / "s.png"
    args = ["render", "--scene", "spheres", "--width", "24", "--height", "16", "--max-depth", "1"]
    assert main([*args, "--head", "10,0,0", "--backend", "embree", "-o", str(out)]) == 0
    import imageio.v3 as iio

    png = iio.imread(out)
    assert png.shape == (16, 48, 3)
    captured = capsys.readouterr()
    assert "stereo 48x16 spp 1" in captured.out and "primary" in captured.out
    assert "ray queries: embree (Embree 4." in captured.out
    assert "integrator: native (" in captured.out
    assert "[3/6] foveated frame" in captured.err and "[6/6] writing" in captured.err
    assert main(["render", "--scene", "nowhere.obj", "-o", str(out)]) == 2
    assert "not a built-in scene" in capsys.readouterr().err


@pytest.mark.parametrize("n", [1, 5, 4099])
def test_live_first_is_a_stable_partition(n):
    """The queues' permutation (`_live_first`): the live entries first, each part in its order
    (NumPy's stable argsort of "not live"), and their count."""
    from fovjax.render._integrator import _live_first

    alive = np.random.default_rng(n).random(n) < 0.3
    alive[0] = n > 1  # a dead first entry where there is more than one
    count, order = _live_first(jnp.asarray(alive))
    assert int(count) == int(alive.sum())
    np.testing.assert_array_equal(np.asarray(order), np.argsort(~alive, kind="stable"))
