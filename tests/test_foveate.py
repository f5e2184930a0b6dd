"""Foveated sampling: eccentricity, regions, the P(ω) draws, block top-lefts, compaction, fill."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import fovjax
from fovjax.foveate import (
    FOVEA,
    OUTSIDE,
    PERIPHERY,
    Constant,
    Foveation,
    LinearFalloff,
    check_gaze,
    display_pixel_pitch_mm,
    eccentricity_map,
    fill_and_blur,
    regions,
)
from fovjax.foveate.internal import (
    MANDATORY,
    OPTIONAL,
    SKIPPED,
    compaction_order,
    plan_budget,
    top_left,
)
from fovjax.foveate.internal import sample_classes as _sample_classes

# Compiled once per image shape and foveation, as inside a frame program (eagerly, each call
# compiled its sampling loop again).
sample_classes = eqx.filter_jit(_sample_classes)

W, H = 320, 256
HFOV = 90.0


@pytest.fixture(scope="module")
def camera():
    vfov = 2 * np.degrees(np.arctan(np.tan(np.radians(HFOV / 2)) * H / W))
    return fovjax.Camera.look_at((0, 0, 0), (0, 0, -1), vfov_deg=vfov, width=W, height=H)


def test_angle_eccentricity_against_hand_computed_angles(camera):
    f = Foveation()
    ecc = np.asarray(eccentricity_map(camera, np.array([0.5, 0.5]), f))
    # Centre row, gaze at the centre: the angle of pixel x is atan((2(x+0.5)/W - 1) tan(hfov/2)).
    x = np.arange(W) + 0.5
    expected = np.degrees(np.abs(np.arctan((2 * x / W - 1) * np.tan(np.radians(HFOV / 2)))))
    row = H // 2  # pixel centre y = H/2 + 0.5: a small vertical angle too
    vy = (2 * (row + 0.5) / H - 1) * np.tan(np.radians(HFOV / 2)) * H / W
    dirs = np.stack([(2 * x / W - 1) * np.tan(np.radians(HFOV / 2)), -np.full(W, vy), -np.ones(W)], -1)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    exact = np.degrees(np.arccos(np.clip(-dirs[:, 2], -1, 1)))
    np.testing.assert_allclose(ecc[row], exact, atol=2e-3)
    assert abs(expected[-1] - 45 + np.degrees(np.arctan(np.tan(np.radians(45)) / W))) < 0.1
    # Gaze at the left edge: the far right edge is 90 degrees away (both at +-45 degrees).
    ecc_edge = np.asarray(eccentricity_map(camera, np.array([0.0, 0.5]), f))
    assert abs(ecc_edge[row, -1] - 90.0) < 0.5


@pytest.mark.parametrize("gaze", [(0.37, 0.61), (0.0, 0.0), (1.0, 0.5)])
def test_angle_eccentricity_is_the_world_space_angle_between_rays(gaze):
    """Taken on the image plane, the eccentricity is still the angle between the two rays in
    the world: against float64 directions of a turned, tilted camera with a projection offset
    (as a stereo eye's), every pixel within 1e-4° (float32 rounding of values up to 90°:
    ~1e-5°; an axis or sign mixed up is off by degrees)."""
    cam = fovjax.Camera.look_at(
        (0.3, 1.2, 2.0),
        (-1.0, 0.4, -3.0),
        (0.1, 1.0, 0.0),
        vfov_deg=64.0,
        width=W,
        height=H,
        offset=(0.08, -0.03),
    )
    ecc = np.asarray(eccentricity_map(cam, np.asarray(gaze, np.float32), Foveation()), np.float64)

    def world_directions(px, py):
        tan_half = np.tan(np.radians(np.float64(cam.vfov_deg)) / 2)
        sx = (2 * px / W - 1 + np.float64(cam.offset[0])) * tan_half * W / H
        sy = (1 - 2 * py / H + np.float64(cam.offset[1])) * tan_half
        d = np.stack(np.broadcast_arrays(sx, sy, -1.0), -1) @ np.asarray(cam.rotation, np.float64).T
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    d = world_directions(*np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5))
    g = world_directions(np.float32(gaze[0]) * np.float64(W), np.float32(gaze[1]) * np.float64(H))
    exact = np.degrees(np.arctan2(np.linalg.norm(np.cross(d, g), axis=-1), d @ g))
    np.testing.assert_allclose(ecc, exact, rtol=0, atol=1e-4)


def test_eccentricity_arctangent_matches_float64_atan2():
    """The eccentricity's own atan2 (y >= 0, every octant, zeros, tiny and huge ratios) against
    NumPy's in float64: within a few float32 roundings of a value up to pi (1e-6 rad), and
    relatively accurate near 0, where the eccentricity of the fovea lives."""
    from fovjax.foveate._eccentricity import _atan2_nonnegative

    rng = np.random.default_rng(3)
    y = np.concatenate([rng.uniform(0, 1, 20000) ** 4, [0, 0, 0, 1, 1e-30, 1e-8, 3.0, 0.5]])
    x = np.concatenate([rng.uniform(-1, 1, 20000), [1, -1, 0, 0, 1, 1, 3.0, -0.5]])
    y32, x32 = y.astype(np.float32), x.astype(np.float32)
    got = np.asarray(jax.jit(_atan2_nonnegative)(y32, x32), np.float64)
    want = np.arctan2(y32.astype(np.float64), x32.astype(np.float64))
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)
    small = want < 1e-3
    assert small.sum() > 100
    np.testing.assert_allclose(got[small], want[small], rtol=1e-6, atol=0)


def test_planar_eccentricity_is_the_thesis_formula(camera):
    f = Foveation(eccentricity="planar")
    ecc = np.asarray(eccentricity_map(camera, np.array([0.5, 0.5]), f))
    pitch = float(display_pixel_pitch_mm(camera, 24.0))
    assert pitch == pytest.approx(2 * 24.0 * np.tan(np.radians(HFOV / 2)) / W, rel=1e-5)
    y, x = 10, 200
    s = np.hypot(x + 0.5 - W / 2, y + 0.5 - H / 2) * pitch
    assert ecc[y, x] == pytest.approx(np.degrees(2 * np.arctan(s / 48.0)), rel=1e-5)
    f2 = Foveation(eccentricity="planar", pixel_pitch_mm=0.05)
    ecc2 = np.asarray(eccentricity_map(camera, np.array([0.5, 0.5]), f2))
    assert ecc2[y, x] == pytest.approx(
        np.degrees(2 * np.arctan(np.hypot(x + 0.5 - W / 2, y + 0.5 - H / 2) * 0.05 / 48))
    )


def test_regions_and_presets():
    ecc = jnp.array([[0.0, 5.0, 5.01, 10.0, 10.01, 40.0]])
    f = Foveation.thesis(0)
    np.testing.assert_array_equal(
        np.asarray(regions(ecc, f)), [[FOVEA, FOVEA, PERIPHERY, PERIPHERY, OUTSIDE, OUTSIDE]]
    )
    assert (Foveation.thesis(3).fovea_deg, Foveation.thesis(3).periphery_deg) == (12.5, 25.0)
    assert Foveation.thesis((6, 9)).periphery_deg == 9


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"fovea_deg": -1}, "fovea_deg"),
        ({"fovea_deg": 10, "periphery_deg": 5}, "periphery_deg"),
        ({"spp": 3}, "spp"),
        ({"blocks": (2, 3)}, "multiple"),
        ({"rule": "sometimes"}, "rule"),
        ({"eccentricity": "radial"}, "eccentricity"),
        ({"blur_sigma": 0}, "blur_sigma"),
        ({"acuity": 0.5}, "callable"),
    ],
)
@pytest.mark.no_typecheck
def test_bad_configuration(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Foveation(**kwargs)


def test_gaze_validation():
    np.testing.assert_allclose(check_gaze((0.4, 0.5, 0.6, 0.5)), [[0.4, 0.5], [0.6, 0.5]], rtol=1e-6)
    with pytest.raises(ValueError, match="NaN"):
        check_gaze([[0.5, np.nan], [0.5, 0.5]])
    with pytest.raises(ValueError, match="right eye.*off-screen"):
        check_gaze([[0.5, 0.5], [1.2, 0.5]])
    with pytest.raises(ValueError, match="shape"):
        check_gaze([0.5, 0.5])


def test_probability_models():
    f = Foveation.thesis(0)
    p = np.asarray(f.probability(jnp.array([0.0, 4.9, 5.0, 6.0, 10.0])))
    assert p[0] == p[1] == p[2] == 1.0
    assert p[3] == pytest.approx(0.90964 * np.exp(-6 / 2.9661) + 0.00792, rel=1e-5)
    lin = Foveation(acuity=LinearFalloff(5.0, 30.0, 0.1))
    assert float(lin.probability(17.5)) == pytest.approx(0.55, rel=1e-5)
    assert float(Foveation(acuity=Constant(0.3)).probability(20.0)) == pytest.approx(0.3)


@pytest.mark.parametrize("rule", ["either", "strict"])
def test_traced_fraction_matches_probability(camera, rule):
    """Binomial test per eccentricity band: the traced fraction of the probabilistic samples
    equals the mean P(ω) of the band (two-sided, each band at significance 1e-3, fixed key)."""
    f = Foveation.thesis(0, spp=4, rule=rule)
    ecc = eccentricity_map(camera, np.array([0.3, 0.6]), f)
    cls, region = sample_classes(ecc, f, jax.random.key(1))
    cls, region, ecc = map(np.asarray, (cls, region, ecc))
    _, _, _ = top_left(jnp.asarray(region), f)
    p = np.broadcast_to(np.asarray(f.probability(ecc)), cls.shape)
    ty, tx, _ = top_left(jnp.asarray(region), f)
    is_tl = np.zeros(region.shape, bool)
    is_tl[np.asarray(ty), np.asarray(tx)] = True
    is_tl = np.broadcast_to(is_tl, cls.shape)
    eligible = (region != FOVEA)[None] & (~is_tl if rule == "either" else is_tl)
    eligible = np.broadcast_to(eligible, cls.shape)
    band = np.broadcast_to(np.digitize(ecc, [5, 7, 10, 15, 25, 45]), cls.shape)
    for b in np.unique(band[eligible]):
        sel = eligible & (band == b)
        k, n = int((cls[sel] == OPTIONAL).sum()), int(sel.sum())
        if n < 50:
            continue
        mean_p = float(p[sel].mean())
        # P(ω) varies inside a band: the count is Poisson-binomial; compare with its normal
        # approximation (exact variance), which is conservative against the binomial.
        var = float((p[sel] * (1 - p[sel])).sum())
        z = (k - n * mean_p) / max(np.sqrt(var), 1e-9)
        assert abs(z) < stats.norm.isf(0.5e-3), (b, k, n, mean_p)


def test_every_block_top_left_is_traced(camera):
    f = Foveation.thesis(1, spp=4)
    for gaze in ([0.5, 0.5], [0.02, 0.97], [0.8, 0.1]):
        ecc = eccentricity_map(camera, np.array(gaze), f)
        cls, region = sample_classes(ecc, f, jax.random.key(2))
        ty, tx, _ = top_left(region, f)
        cls, ty, tx = map(np.asarray, (cls, ty, tx))
        assert (cls[:, ty, tx] == MANDATORY).all()
        assert (cls[:, np.asarray(region) == FOVEA] == MANDATORY).all()
        # Blocks: 2x2 in the periphery, 4x4 outside, aligned to the pixel grid.
        r = np.asarray(region)
        assert (np.asarray(ty)[r == OUTSIDE] % 4 == 0).all() and (
            np.asarray(tx)[r == PERIPHERY] % 2 == 0
        ).all()


def test_fixed_key_is_stable_and_fresh_key_is_not(camera):
    f = Foveation.thesis(0)
    ecc = eccentricity_map(camera, np.array([0.5, 0.5]), f)
    a, _ = sample_classes(ecc, f, jax.random.key(3))
    b, _ = sample_classes(ecc, f, jax.random.key(3))
    c, _ = sample_classes(ecc, f, jax.random.key(4))
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert (np.asarray(a) != np.asarray(c)).any()


@pytest.mark.parametrize(
    ("n", "classes"),
    [
        (1000, (0, 1, 2)),  # within one block of the running sums
        (5000, (0, 1, 2)),  # several blocks, the last one partial
        (4096, (0, 1)),  # whole blocks of the two counted classes only: each count up to the block
        (3072, (1,)),  # every entry in the high half of the packed running sum
    ],
)
def test_compaction_order_is_a_stable_partition(n, classes):
    """Oracle: numpy's counts and stable order, and the rank the inverse permutation."""
    rng = np.random.default_rng(n)
    cls = rng.choice(np.asarray(classes, np.int32), n)
    order, counts, rank = compaction_order(jnp.asarray(cls), with_rank=True)
    order = np.asarray(order)
    assert sorted(order.tolist()) == list(range(n))
    np.testing.assert_array_equal(np.asarray(rank)[order], np.arange(n))
    np.testing.assert_array_equal(order, np.argsort(cls, kind="stable"))
    np.testing.assert_array_equal(np.asarray(counts), [(cls == c).sum() for c in range(3)])
    ordered = cls[order]
    assert (np.diff(ordered) >= 0).all()
    for c in (MANDATORY, OPTIONAL, SKIPPED):
        assert (np.diff(order[ordered == c]) > 0).all()  # original order kept inside a class


@pytest.mark.parametrize("rule", ["either", "strict"])
def test_fill_leaves_no_blank_and_keeps_traced_fovea(camera, rule):
    f = Foveation.thesis(0, spp=4, rule=rule)
    ecc = eccentricity_map(camera, np.array([0.4, 0.5]), f)
    cls, region = sample_classes(ecc, f, jax.random.key(5))
    traced = cls != SKIPPED
    rng = np.random.default_rng(6)
    colors = jnp.asarray(rng.uniform(0, 1, traced.shape + (3,)).astype(np.float32))
    image, blank = fill_and_blur(colors, traced, region, ecc, f)
    image = np.asarray(image)
    assert np.isfinite(image).all()
    pix = np.asarray(
        jnp.sum(jnp.where(traced[..., None], colors, 0), 0) / jnp.maximum(traced.sum(0), 1)[..., None]
    )
    fovea = np.asarray(region) == FOVEA
    np.testing.assert_array_equal(image[fovea], pix[fovea])
    # No pixel is left black (colours are in (0, 1), a blank pixel would stay 0).
    assert (image.max(-1) > 0).all()
    assert np.asarray(blank)[~fovea].any()
    # Blank pixels took their block's top-left value (before blur): check with blurring off far
    # from the fovea by comparing the unblurred fill in "either" mode.
    if rule == "either":
        ty, tx, _ = top_left(region, f)
        b = np.asarray(blank)
        np.testing.assert_array_equal(
            np.asarray(traced.sum(0))[np.asarray(ty)[b], np.asarray(tx)[b]] > 0, True
        )


def test_blur_fovea_blurs_everything(camera):
    f = Foveation.thesis(0, blur_fovea=True)
    ecc = eccentricity_map(camera, np.array([0.5, 0.5]), f)
    cls, region = sample_classes(ecc, f, jax.random.key(7))
    colors = jnp.asarray(np.random.default_rng(8).uniform(0, 1, cls.shape + (3,)).astype(np.float32))
    sharp, _ = fill_and_blur(colors, cls != SKIPPED, region, ecc, Foveation.thesis(0))
    blurred, _ = fill_and_blur(colors, cls != SKIPPED, region, ecc, f)
    fovea = np.asarray(region) == FOVEA
    assert np.abs(np.asarray(sharp)[fovea] - np.asarray(blurred)[fovea]).max() > 0.01


def test_budget_covers_every_gaze(camera):
    f = Foveation.thesis(0, spp=4)
    budget = plan_budget(camera, f)
    assert budget % 64 == 0 and budget < 4 * W * H
    for gaze in ([0.5, 0.5], [0.0, 0.0], [1.0, 0.37], [0.13, 0.88]):
        ecc = eccentricity_map(camera, np.array(gaze), f)
        for k in range(3):
            cls, _ = sample_classes(ecc, f, jax.random.key(k))
            assert int((np.asarray(cls) != SKIPPED).sum()) <= budget
    assert plan_budget(camera, Foveation(fovea_deg=200, periphery_deg=200)) == W * H
    assert plan_budget(camera, Foveation(ray_budget=1000)) == 1000
