"""Foveation methods (`Foveation(method=...)`): the catalog and its checks, and Weier et al.
2016's temporal frame against independent oracles: a fovea covering the screen is the full
render; on a still view the history reproduces the full render while tracing far fewer rays;
pixels disoccluded by a camera move (found by tracing the scene directly) are traced, not
taken from the history; a reset forgets the history. One compiled program serves the module
(a card before a wall, depth 0, SPP 4, pixel-cell centres: the sample positions do not move
between frames, so a reprojected sample is the very value the full render has)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import fovjax
from fovjax.foveate import Fidelity, FoveatedRenderer, Foveation, _api
from fovjax.foveate._methods import METHODS, Thesis, Weier2016
from fovjax.render import RenderConfig, StereoRig, render_stereo

EYE_W, EYE_H, SPP = 48, 32, 4
CONFIG = RenderConfig(max_depth=0)
CENTRE = ((0.5, 0.5), (0.5, 0.5))
ENTRY = "foveated-weier2016"


def _card_scene():
    """A lit card (1.2 wide, at z = -2) in front of a wall (z = -5): moving the viewer sideways
    uncovers a strip of the wall behind the card's edge."""
    wall = [[-50, -50, -5], [50, -50, -5], [50, 50, -5], [-50, 50, -5]]
    card = [[-0.6, -0.6, -2], [0.6, -0.6, -2], [0.6, 0.6, -2], [-0.6, 0.6, -2]]
    return fovjax.make_scene(
        np.asarray(wall + card, np.float32),
        [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]],
        materials=fovjax.make_materials(
            [{"kd": (0.2, 0.3, 0.8)}, {"kd": (0.9, 0.5, 0.1), "ks": (0.3, 0.3, 0.3), "ns": 20.0}]
        ),
        face_material=[0, 0, 1, 1],
        lights=fovjax.make_lights([[0.5, 1.0, 0.0]], [[1, 1, 1]]),
        name="card",
    )


def _rig(shift=0.0):
    """The viewer at (shift, 0, 0) looking down -z."""
    return StereoRig.look_at((shift, 0, 0), (shift, 0, -1), eye_width=EYE_W, eye_height=EYE_H)


@pytest.fixture(scope="module")
def weier():
    scene = _card_scene()
    renderer = FoveatedRenderer(scene, _rig(), Foveation(fovea_deg=5, spp=SPP, method="weier2016"), CONFIG)
    return scene, renderer


def test_methods_are_named_cited_and_checked():
    assert Foveation().method == Thesis() == Foveation(method="thesis").method
    assert Foveation(method="weier2016").method == Weier2016()
    assert Foveation(method=Weier2016(retrace_tolerance=0.2)).method.retrace_tolerance == 0.2
    for cls in METHODS.values():
        c = cls.citation
        assert c.authors and c.title and c.venue and 1990 < c.year < 2030
        assert c.doi is None or c.doi.startswith("10.")
    with pytest.raises(ValueError, match="method must be one of"):
        Foveation(method="guenter")
    with pytest.raises(ValueError, match="retrace_tolerance"):
        Weier2016(retrace_tolerance=0.0)
    with pytest.raises(ValueError, match="fidelity apply to the thesis's method only"):
        Foveation(method="weier2016", fidelity=(Fidelity(),) * 3)


def test_full_fovea_is_the_full_render(weier):
    scene, renderer = weier
    full = render_stereo(scene, renderer.rig, spp=SPP, config=CONFIG)
    every = 2 * SPP * EYE_W * EYE_H
    traces = None
    for k in range(2):  # the second frame has a history, but the fovea covers every pixel
        frame = renderer.render(CENTRE, thresholds=(180.0, 180.0), reset=k == 0)
        assert frame.stats.primary_rays == every and frame.foveation.reused == 0
        assert frame.stats.shadow_rays == full.stats.shadow_rays
        # Same rays and shading, two programs (a flat slot list vs the image): float32
        # rounding only (as the thesis's frame, tests/test_foveate_frame.py).
        np.testing.assert_allclose(frame.image, full.image, rtol=1e-4, atol=1e-5)
        traces = _api.TRACE_COUNTS[ENTRY] if traces is None else traces
    assert _api.TRACE_COUNTS[ENTRY] == traces


def test_still_view_reuses_the_history_and_stays_the_full_render(weier):
    scene, renderer = weier
    full = render_stereo(scene, renderer.rig, spp=SPP, config=CONFIG)
    every = 2 * SPP * EYE_W * EYE_H
    first = renderer.render(CENTRE, reset=True)
    assert first.stats.primary_rays == every  # no history: every pixel is traced
    np.testing.assert_allclose(first.image, full.image, rtol=1e-4, atol=1e-5)
    traces = _api.TRACE_COUNTS[ENTRY]
    for gaze in (CENTRE, ((0.3, 0.6), (0.35, 0.6))):
        frame = renderer.render(gaze)
        assert frame.stats.compile_seconds == 0.0
        # The fovea and the refresh draws are traced; the rest comes from the history.
        assert 0 < frame.stats.primary_rays < every / 2
        assert frame.foveation.reused == EYE_W * EYE_H * 2 - frame.stats.primary_rays // SPP
        assert frame.sample_mask.transpose(1, 0, 2, 3)[:, frame.regions == 0].all()  # fovea: traced
        np.testing.assert_allclose(frame.image, full.image, rtol=1e-4, atol=1e-5)
    assert _api.TRACE_COUNTS[ENTRY] == traces


def _disoccluded(renderer, before, after):
    """Per eye and pixel of the rig `after`: whether the surface point its centre ray sees was
    hidden from the same eye of the rig `before` (another surface nearer along the ray from
    that eye to it, or outside that eye's view): traced with `fovjax.trace.closest_hit`."""
    from fovjax.trace import closest_hit

    scene = renderer.arrays
    out = []
    for cam_b, cam_a in zip(after.eye_cameras(), before.eye_cameras(), strict=True):
        o, d = cam_b.primary_rays()
        t = closest_hit(renderer.bvh, o, d, vertices=scene.vertices).t
        p = o + jnp.where(jnp.isfinite(t), t, 1e3)[..., None] * d
        xy, depth = cam_a.project(p)
        inside = (depth > 0) & (xy[..., 0] >= 0) & (xy[..., 0] < EYE_W) & (xy[..., 1] >= 0)
        inside = inside & (xy[..., 1] < EYE_H)
        to_p = p - cam_a.position
        dist = jnp.linalg.norm(to_p, axis=-1)
        t_a = closest_hit(renderer.bvh, cam_a.position, to_p / dist[..., None], vertices=scene.vertices).t
        seen = inside & (t_a > dist * (1 - 1e-3))
        out.append(np.asarray(~seen & jnp.isfinite(t)))
    return np.stack(out)


def test_disoccluded_pixels_are_traced_not_smeared(weier):
    scene, renderer = weier
    before, after = renderer.rig, _rig(shift=1.0)
    renderer.render(CENTRE, reset=True)
    moved = renderer.with_rig(after)
    frame = moved.render(CENTRE)
    hidden = _disoccluded(renderer, before, after)
    # Pixels whose whole 3×3 neighbourhood was hidden: no sample of the history can land there
    # by the rounding of a sample position to a pixel.
    pad = np.pad(hidden, ((0, 0), (1, 1), (1, 1)))
    interior = np.ones_like(hidden)
    for dy in range(3):
        for dx in range(3):
            interior &= pad[:, dy : dy + EYE_H, dx : dx + EYE_W]
    assert interior.sum() >= 20, interior.sum()  # the move reveals something to test
    traced = frame.sample_mask.any(axis=1)
    assert traced[interior].all()
    full = render_stereo(scene, after, spp=SPP, config=CONFIG)
    eyes = np.stack(np.split(frame.image, 2, axis=1)), np.stack(np.split(full.image, 2, axis=1))
    np.testing.assert_allclose(eyes[0][interior], eyes[1][interior], rtol=1e-4, atol=1e-5)
    # And most of the frame came from the history (the camera moved a little).
    assert frame.foveation.reused > 0.5 * 2 * EYE_W * EYE_H


def test_reset_forgets_the_history(weier):
    _, renderer = weier
    renderer.render(CENTRE, reset=True)
    assert renderer.render(CENTRE).foveation.reused > 0
    again = renderer.render(CENTRE, reset=True)
    assert again.foveation.reused == 0 and again.stats.primary_rays == 2 * SPP * EYE_W * EYE_H
    renderer.reset_history()
    assert renderer.render(CENTRE).foveation.reused == 0
    with pytest.raises(ValueError, match="one after another"):
        renderer.render_batch([CENTRE])


# ---- Guenter et al. 2012 ----


def test_magnify_is_bilinear_between_grid_pixels():
    """Bilinear interpolation reproduces a linear ramp exactly between grid pixels (and holds
    the last grid row and column beyond them); stride 1 is the identity."""
    from fovjax.foveate._methods._guenter import magnify

    h, w, s = 12, 16, 4
    y, x = np.mgrid[:h, :w].astype(np.float32)
    ramp = np.stack([x, y, 2 * x - y], axis=-1)[None]
    up = np.asarray(magnify(jnp.asarray(ramp), s))
    inside = (slice(None), slice(0, (h // s - 1) * s + 1), slice(0, (w // s - 1) * s + 1))
    np.testing.assert_allclose(up[inside], ramp[inside], atol=1e-5)
    last_row = (h // s - 1) * s
    np.testing.assert_allclose(up[0, last_row:, 0, 1], last_row)  # held beyond the last grid row
    assert np.array_equal(np.asarray(magnify(jnp.asarray(ramp), 1)), ramp)


@pytest.mark.parametrize(("h", "w", "stride"), [(13, 17, 2), (11, 10, 3), (9, 14, 4)])
def test_magnify_is_the_per_pixel_rule(h, w, stride):
    """Against a per-pixel loop: pixel (y, x) blends grid pixels y // s, x // s and the next
    (the last where there is none) by the fraction y / s - y // s (sizes the stride does not
    divide included)."""
    from fovjax.foveate._methods._guenter import magnify

    pix = np.random.default_rng(h * w + stride).random((2, h, w, 3), dtype=np.float32)
    grid = pix[:, ::stride, ::stride]
    hg, wg = grid.shape[1:3]
    want = np.zeros_like(pix)
    for y in range(h):
        for x in range(w):
            y0, x0 = y // stride, x // stride
            y1, x1 = min(y0 + 1, hg - 1), min(x0 + 1, wg - 1)
            fy, fx = y / stride - y0, x / stride - x0
            top = grid[:, y0, x0] * (1 - fx) + grid[:, y0, x1] * fx
            bottom = grid[:, y1, x0] * (1 - fx) + grid[:, y1, x1] * fx
            want[:, y, x] = top * (1 - fy) + bottom * fy
    np.testing.assert_allclose(np.asarray(magnify(jnp.asarray(pix), stride)), want, atol=1e-6)


def test_guenter_layer_rule_by_hand():
    from fovjax.foveate._methods import Guenter2012

    # MAR(ω) = p + m·ω reaches s pixels at ω = (s - 1)·p / m; m = 1.32' per degree.
    p = 0.1
    e1, e2 = Guenter2012().layer_radii(p)
    assert e1 == pytest.approx(1 * p / (1.32 / 60)) and e2 == pytest.approx(3 * p / (1.32 / 60))
    with pytest.raises(ValueError, match="strides"):
        Guenter2012(strides=(4, 2))


@pytest.fixture(scope="module")
def card_full():
    scene = _card_scene()
    return scene, render_stereo(scene, _rig(), spp=SPP, config=CONFIG)


def test_guenter_layers_at_equal_resolution_are_the_full_render(card_full):
    from fovjax.foveate._methods import Guenter2012

    scene, full = card_full
    f = Foveation(fovea_deg=5, periphery_deg=15, spp=SPP, method=Guenter2012(strides=(1, 1)))
    frame = FoveatedRenderer(scene, _rig(), f, CONFIG).render(((0.3, 0.4), (0.35, 0.4)))
    assert frame.stats.primary_rays == 2 * SPP * EYE_W * EYE_H
    np.testing.assert_allclose(frame.image, full.image, rtol=1e-4, atol=1e-5)


def test_guenter_full_fovea_and_coarse_grid_are_the_full_render(card_full):
    scene, full = card_full
    renderer = FoveatedRenderer(scene, _rig(), Foveation(spp=SPP, method="guenter2012"), CONFIG)
    everything = renderer.render(CENTRE, thresholds=(180.0, 180.0))
    assert everything.stats.primary_rays == 2 * SPP * EYE_W * EYE_H
    np.testing.assert_allclose(everything.image, full.image, rtol=1e-4, atol=1e-5)
    traces = _api.TRACE_COUNTS["foveated-guenter2012"]
    frame = renderer.render(CENTRE, thresholds=(3.0, 8.0))
    assert _api.TRACE_COUNTS["foveated-guenter2012"] == traces  # radii are traced
    assert frame.stats.primary_rays < 0.5 * 2 * SPP * EYE_W * EYE_H
    # Where only the outer layer shows (beyond the middle radius and its blend), its grid
    # pixels (every 4th row and column) are traced samples, shown as they are.
    outer_only = frame.eccentricity > 8.0 + 1.0
    grid = np.zeros((EYE_H, EYE_W), bool)
    grid[::4, ::4] = True
    check = outer_only & grid[None]
    assert check.sum() > 20
    eyes = np.stack(np.split(frame.image, 2, axis=1)), np.stack(np.split(full.image, 2, axis=1))
    np.testing.assert_allclose(eyes[0][check], eyes[1][check], rtol=1e-4, atol=1e-5)
    assert frame.sample_mask.any(axis=1)[check].all()


# ---- Patney et al. 2016 ----


def test_patney_is_cited_and_checked():
    from fovjax.foveate._methods import Patney2016

    assert Foveation(method="patney2016").method == Patney2016() and METHODS["patney2016"] is Patney2016
    assert Patney2016.temporal and Patney2016.citation.doi == "10.1145/2980179.2980246"
    for bad in ({"strides": (4, 2)}, {"taa_alpha": 0.0}, {"max_gain": 0.5}, {"blur_per_stride": -1.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            Patney2016(**bad)


def _bars(h=48, w=64, period=8):
    """A vertical bar grating (0.2 and 0.8, `period` pixels), tinted: a known image whose local
    contrast a blur of σ = period/4 mostly removes."""
    x = np.arange(w, dtype=np.float32)[None, :]
    g = 0.5 + 0.3 * np.sign(np.sin(2 * np.pi * (x + 0.5) / period))
    g = np.broadcast_to(g, (h, w))
    return jnp.asarray(g[None, ..., None] * np.array([1.0, 0.8, 0.6], np.float32))


def test_contrast_preserving_filter_keeps_constants_and_restores_contrast():
    from fovjax.foveate._methods._patney import (
        contrast_preserving_filter,
        gaussian_blur,
        local_std,
        luminance,
    )

    sigma, window = 2.0, 4.0
    flat = jnp.full((2, 16, 24, 3), 0.37, jnp.float32)
    out = contrast_preserving_filter(flat, sigma, window_sigma=window, max_gain=4.0)
    np.testing.assert_allclose(np.asarray(out), 0.37, rtol=1e-6)  # identity up to rounding

    def contrast(image):  # local std of luminance, away from the border
        return np.asarray(local_std(luminance(image), window))[0, 16:-16, 16:-16, 0]

    bars = _bars()
    ref = contrast(bars)
    blurred = contrast(gaussian_blur(bars, sigma)) / ref
    restored = contrast(contrast_preserving_filter(bars, sigma, window_sigma=window, max_gain=4.0)) / ref
    assert blurred.max() < 0.5  # the blur alone loses more than half the contrast
    assert 0.9 < restored.min() and restored.max() < 1.1  # the filter gives it back (within 10%)
    # Finer bars than the blur passes (it keeps under 1% of them): the gain stops at max_gain,
    # so the filter does not invent the detail back.
    fine = _bars(period=4)
    assert contrast(gaussian_blur(fine, sigma)).max() < 0.01 * contrast(fine).min()
    capped = contrast(contrast_preserving_filter(fine, sigma, window_sigma=window, max_gain=4.0))
    assert capped.max() < 0.1 * contrast(fine).min()


def test_taa_blend_is_the_clipped_exponential_average():
    from fovjax.foveate._methods._patney import TaaHistory, taa_blend

    rng = np.random.default_rng(0)
    current = jnp.asarray(rng.uniform(0, 1, (2, 8, 8, 3)).astype(np.float32))
    none = TaaHistory(jnp.zeros_like(current), jnp.zeros((2, 8, 8), bool))
    assert np.array_equal(np.asarray(taa_blend(current, none, alpha=0.1, gamma=1.0)), np.asarray(current))
    same = TaaHistory(current, jnp.ones((2, 8, 8), bool))  # a still image is a fixed point
    np.testing.assert_allclose(np.asarray(taa_blend(current, same, alpha=0.1, gamma=1.0)), current, atol=1e-6)
    flat = jnp.full_like(current, 0.5)  # a flat neighbourhood: the history is clipped to it
    far = TaaHistory(jnp.full_like(current, 3.0), jnp.ones((2, 8, 8), bool))
    np.testing.assert_allclose(np.asarray(taa_blend(flat, far, alpha=0.1, gamma=1.0)), 0.5, atol=1e-6)
    near = TaaHistory(flat + 0.0, jnp.ones((2, 8, 8), bool))
    np.testing.assert_allclose(np.asarray(taa_blend(flat, near, alpha=0.25, gamma=1.0)), 0.5, atol=1e-6)


@pytest.fixture(scope="module")
def patney():
    scene = _card_scene()
    renderer = FoveatedRenderer(scene, _rig(), Foveation(fovea_deg=5, spp=SPP, method="patney2016"), CONFIG)
    return scene, renderer


def test_patney_full_fovea_is_the_full_render(patney, card_full):
    _, full = card_full
    _, renderer = patney
    every = 2 * SPP * EYE_W * EYE_H
    traces = None
    for k in range(2):  # the second frame blends a history: a still image is its fixed point
        frame = renderer.render(CENTRE, thresholds=(180.0, 180.0), reset=k == 0)
        assert frame.stats.primary_rays == every
        assert frame.foveation.reused == (0 if k == 0 else EYE_W * EYE_H * 2)
        np.testing.assert_allclose(frame.image, full.image, rtol=1e-4, atol=1e-5)
        traces = _api.TRACE_COUNTS["foveated-patney2016"] if traces is None else traces
    assert _api.TRACE_COUNTS["foveated-patney2016"] == traces


def test_patney_coarse_periphery_traces_block_corners(patney, card_full):
    _, full = card_full
    _, renderer = patney
    frame = renderer.render(CENTRE, thresholds=(6.0, 12.0), reset=True)
    assert frame.stats.compile_seconds == 0.0  # thresholds are traced
    assert frame.stats.primary_rays < 0.5 * 2 * SPP * EYE_W * EYE_H
    traced = frame.sample_mask.any(axis=1)
    outer_only = frame.eccentricity > 12.0 + 1.0
    # Beyond the middle rate's radius and blend: every 4×4 block's top-left is traced, and no
    # pixel off the 2×2 grid (a 2×2 block reaching into the middle rate may still be traced).
    corner, grid2 = np.zeros((EYE_H, EYE_W), bool), np.zeros((EYE_H, EYE_W), bool)
    corner[::4, ::4] = True
    grid2[::2, ::2] = True
    assert (outer_only & corner[None]).sum() > 20
    assert traced[outer_only & corner[None]].all() and not traced[outer_only & ~grid2[None]].any()
    # The fovea (ω ≤ its radius: the fine rate alone, no filter) is the full render.
    eyes = np.stack(np.split(frame.image, 2, axis=1)), np.stack(np.split(full.image, 2, axis=1))
    fovea = frame.eccentricity <= 6.0
    assert fovea.sum() > 10
    np.testing.assert_allclose(eyes[0][fovea], eyes[1][fovea], rtol=1e-4, atol=1e-5)


def test_patney_history_converges_after_a_move_and_reset_forgets_it(patney, card_full):
    """After a camera move the history contracts to the new view's frame at least as fast as
    the exponential average (1 - taa_alpha per frame: the clip box holds the current pixel, so
    clipping never moves the history away from it); with reset the new view's first frame is
    the frame without history, whose fovea is the full render."""
    _, renderer = patney
    moved = renderer.with_rig(_rig(shift=0.3))
    first = moved.render(CENTRE, reset=True)
    assert first.foveation.reused == 0
    target = np.asarray(first.history.color)  # the shaded frame of the moved view
    renderer.render(CENTRE, reset=True)
    start = np.abs(np.asarray(renderer._history.value.color) - target)
    assert start.max() > 0.1  # the move changes what pixels see
    factor = 1.0 - renderer.foveation.method.taa_alpha
    for k in range(1, 4):
        frame = moved.render(CENTRE)
        assert frame.foveation.reused == 2 * EYE_W * EYE_H
        gap = np.abs(np.asarray(frame.history.color) - target)
        assert (gap <= factor**k * start + 1e-5).all()
    assert gap.max() > 0  # the history was blended, not dropped
    renderer.reset_history()
    again = moved.render(CENTRE)
    assert again.foveation.reused == 0
    np.testing.assert_allclose(again.image, first.image, rtol=1e-6, atol=1e-7)


def test_a_methods_label_names_the_parameters_it_sets():
    """Comparisons label a method by name and the parameters set apart from its defaults, so two
    settings of one method in a sweep are two rows, not one name twice."""
    from fovjax.foveate import method_label

    assert method_label(Foveation(method="weier2016").method) == "weier2016"
    assert method_label(Weier2016(widened_fovea="trace")) == "weier2016(widened_fovea='trace')"
    both = method_label(Weier2016(retrace_tolerance=0.05, widened_fovea="trace"))
    assert both == "weier2016(retrace_tolerance=0.05, widened_fovea='trace')"
    assert [method_label(Foveation(method=m).method) for m in METHODS] == list(METHODS)
