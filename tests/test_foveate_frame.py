"""The foveated stereo frame end to end: compaction traces exactly the generated rays, a fovea
covering the screen is the full render, hand-countable ray counts, no recompiles."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _frames import assert_same_radiance

import fovjax
from fovjax.foveate import Constant, Foveation, render_foveated
from fovjax.foveate import _api as fov_api
from fovjax.render import RenderConfig, StereoRig, render_stereo

EYE_W, EYE_H = 96, 64
CONFIG = RenderConfig(max_depth=1)  # one reflection bounce keeps the compile short


@pytest.fixture(scope="module")
def atrium_small():
    scene = fovjax.scenes.atrium(triangles=20_000)
    pose = fovjax.scenes.default_camera(scene)
    return scene, StereoRig.from_pose(pose, eye_width=EYE_W, eye_height=EYE_H)


def test_traces_exactly_the_selected_samples_and_no_recompile(atrium_small):
    scene, rig = atrium_small
    f = Foveation.thesis(0, spp=4)
    first = render_foveated(
        scene, rig, gaze=((0.5, 0.5), (0.5, 0.5)), foveation=f, key=jax.random.key(0), config=CONFIG
    )
    traces = fov_api.TRACE_COUNTS["foveated"]
    s = first.foveation
    assert s.dropped == 0
    assert first.stats.primary_rays == s.mandatory + s.optional == int(first.sample_mask.sum())
    assert sum(s.primary_by_region) == first.stats.primary_rays
    assert s.padding == s.budget - first.stats.primary_rays
    assert first.stats.primary_rays < 0.5 * 2 * 4 * EYE_W * EYE_H
    # Every region is present and the fovea is fully sampled.
    fovea = first.regions == 0
    assert fovea.any() and (first.sample_mask.transpose(1, 0, 2, 3)[:, fovea]).all()
    # What the frame program relies on to leave the pull-push fill out (the rule "either", no
    # sample dropped): every pixel's block top-left has a traced sample.
    from fovjax.foveate._sampling import top_left

    assert f.rule == "either"
    for eye in range(2):
        ty, tx, _ = top_left(jnp.asarray(first.regions[eye]), f)
        assert first.sample_mask[eye].any(axis=0)[np.asarray(ty), np.asarray(tx)].all()
    assert np.isfinite(first.image).all() and first.image.shape == (EYE_H, 2 * EYE_W, 3)
    # A new gaze, head pose and key reuse the compiled program.
    second = render_foveated(
        scene,
        rig,
        gaze=(0.2, 0.8, 0.3, 0.7),
        foveation=f,
        head_pose=(10, -5, 2),
        key=jax.random.key(1),
        config=CONFIG,
    )
    assert fov_api.TRACE_COUNTS["foveated"] == traces
    assert second.stats.compile_seconds == 0.0
    assert (second.regions != first.regions).any()


def test_diagnostics_choose_the_per_pixel_outputs_not_the_frame():
    """`diagnostics` selects which per-pixel outputs the frame program returns: the image,
    counts and statistics are the same with none of them; the others are None and the debug
    view says what it lacks; the regions are int8; a set in any order is one program; an
    unknown name fails before any compile. (Depth 0 and two programs keep the compile short;
    the default, every output, is what the other tests render.)"""
    scene = fovjax.scenes.cornell_box()
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=40, eye_height=32)
    common = {"foveation": Foveation.thesis(0, spp=4), "config": RenderConfig(max_depth=0)}
    common["gaze"] = ((0.3, 0.4), (0.35, 0.4))
    lean = render_foveated(scene, rig, key=jax.random.key(3), diagnostics=(), **common)
    debug = render_foveated(
        scene, rig, key=jax.random.key(3), diagnostics=("prefill", "region", "traced"), **common
    )
    assert_same_radiance(lean.image, debug.image)
    assert lean.foveation == debug.foveation and lean.stats.rays == debug.stats.rays
    assert lean.sample_mask is None and lean.regions is None and lean.eccentricity is None
    assert lean.outputs.prefill is None and lean.outputs.traced is None
    with pytest.raises(ValueError, match=r"without the diagnostics \['traced', 'region', 'prefill'\]"):
        _ = lean.debug_view
    assert debug.regions.dtype == np.int8 and set(np.unique(debug.regions)) == {0, 1, 2}
    assert debug.sample_mask.shape == (2, 4, 32, 40) and debug.outputs.prefill.shape == (2, 32, 40, 3)
    assert debug.eccentricity is None
    view = debug.debug_view
    assert view.shape == (32, 80, 3) and np.isfinite(view).all()
    traces = fov_api.TRACE_COUNTS["foveated"]
    again = render_foveated(
        scene, rig, key=jax.random.key(4), diagnostics=["traced", "prefill", "region"], **common
    )
    assert again.stats.compile_seconds == 0.0 and fov_api.TRACE_COUNTS["foveated"] == traces
    # The package's entry point passes the choice on (the same program again).
    entry = fovjax.render_stereo(
        scene, rig, key=jax.random.key(4), diagnostics=("traced", "prefill", "region"), **common
    )
    assert entry.eccentricity is None and entry.stats.compile_seconds == 0.0
    np.testing.assert_array_equal(entry.image, again.image)
    with pytest.raises(ValueError, match=r"unknown diagnostics \['mask'\]"):
        render_foveated(scene, rig, key=jax.random.key(3), diagnostics=("region", "mask"), **common)
    # None: the annotation check's TypeError where it runs (the suite), else the function's own.
    with pytest.raises((TypeError, ValueError), match="diagnostics"):
        render_foveated(scene, rig, key=jax.random.key(3), diagnostics=None, **common)
    assert fov_api.TRACE_COUNTS["foveated"] == traces


def test_full_fovea_reproduces_the_full_render(atrium_small):
    scene, rig = atrium_small
    key = jax.random.key(3)
    everything = Foveation(fovea_deg=180.0, periphery_deg=180.0, spp=4)
    fov = render_foveated(scene, rig, foveation=everything, key=key, config=CONFIG)
    full = render_stereo(scene, rig, spp=4, key=key, config=CONFIG)
    assert fov.stats.primary_rays == full.stats.primary_rays == 2 * 4 * EYE_W * EYE_H
    assert fov.stats.shadow_rays == full.stats.shadow_rays
    assert fov.stats.reflection_rays == full.stats.reflection_rays
    # Same rays, same shading; the two programs are compiled separately (the foveated one
    # shades chunks of a flat slot list, the full one the image), so allow float32 rounding
    # of the shading arithmetic: a few ulps, except that the specular term (n·h)^Ns multiplies
    # the relative rounding of n·h by Ns (up to 300 in the atrium), so the few highlight
    # pixels may differ by ~Ns ulps. Nearly every value agrees to 1e-6.
    np.testing.assert_allclose(fov.image, full.image, rtol=1e-3, atol=1e-5)
    close = np.isclose(fov.image, full.image, rtol=1e-5, atol=1e-6)
    assert close.mean() > 0.99, close.mean()


def test_ray_counts_on_a_wall_are_hand_countable():
    """A lit wall filling the view, nothing reflective: every traced primary ray hits, spawns
    exactly one shadow ray (the light is in front) and no reflection."""
    v = np.array([[-50, -50, -5], [50, -50, -5], [50, 50, -5], [-50, 50, -5]], np.float32)
    scene = fovjax.make_scene(
        v,
        [[0, 1, 2], [0, 2, 3]],
        materials=fovjax.make_materials([{"kd": (0.7, 0.7, 0.7)}]),
        lights=fovjax.make_lights([[0, 0, 2]], [[1, 1, 1]]),
        name="wall",
    )
    rig = StereoRig.look_at((0, 0, 0), (0, 0, -1), eye_width=48, eye_height=32)
    f = Foveation.thesis(0, spp=1)
    frame = render_foveated(scene, rig, foveation=f, key=jax.random.key(4), config=CONFIG)
    n = int(frame.sample_mask.sum())
    assert frame.stats.primary_rays == n
    assert frame.stats.shadow_rays == n
    assert frame.stats.reflection_rays == 0
    # The count itself, from the definition: every fovea pixel, every block top-left, and
    # the probabilistic extras the key selected.
    assert n == frame.foveation.mandatory + frame.foveation.optional


def test_bad_gaze_is_rejected_before_rendering(atrium_small):
    scene, rig = atrium_small
    with pytest.raises(ValueError, match="NaN"):
        render_foveated(scene, rig, gaze=((np.nan, 0.5), (0.5, 0.5)), config=CONFIG)
    with pytest.raises(ValueError, match="off-screen"):
        render_foveated(scene, rig, gaze=((0.5, 0.5), (0.5, -0.1)), config=CONFIG)


class _Tabulated(eqx.Module):
    """An acuity curve given as a table (array leaves, not scalar parameters)."""

    omega: jax.Array
    p: jax.Array

    def __call__(self, omega):
        return jnp.interp(omega, self.omega, self.p)


def test_budget_of_an_array_valued_acuity_model(atrium_small):
    # A capped maximum plans the static budget, cached by the acuity's parameters; a table must
    # key it like scalars do.
    _, rig = atrium_small
    head = (0.0, 0.0, 0.0)
    flat = _Tabulated(jnp.array([0.0, 90.0]), jnp.array([0.25, 0.25]))
    steep = _Tabulated(jnp.array([0.0, 90.0]), jnp.array([1.0, 0.0]))
    budget = {
        name: fov_api._budget_for(
            rig, head, Foveation(fovea_deg=5, periphery_deg=10, max_periphery_deg=10, acuity=acuity)
        )
        for name, acuity in [("flat", flat), ("steep", steep), ("constant", Constant(0.25))]
    }
    assert budget["flat"] == budget["constant"]  # same P(ω) everywhere, same plan
    assert budget["steep"] != budget["flat"]  # a different table is not served from the cache


def _wall(materials):
    """A wall of two triangles (left and right halves of the view) filling a small rig's view,
    lit from in front."""
    v = np.array([[-50, -50, -5], [50, -50, -5], [50, 50, -5], [-50, 50, -5]], np.float32)
    scene = fovjax.make_scene(
        v,
        [[0, 1, 2], [0, 2, 3]],
        face_material=[0, 1],
        materials=fovjax.make_materials(materials),
        lights=fovjax.make_lights([[0, 0, 2]], [[1, 1, 1]]),
        name="wall2",
    )
    rig = StereoRig.look_at((0, 0, 0), (0, 0, -1), eye_width=48, eye_height=32)
    return scene, rig


def test_a_nan_pixel_of_a_foveated_frame_is_counted():
    """A material whose colour is NaN makes every sample that sees it bad: the foveated frame
    counts them (samples and pixels) and paints the pixels the bad colour, exactly where the
    full render does."""
    scene, rig = _wall([{"kd": (0.7, 0.7, 0.7)}, {"kd": (0.5, 0.5, 0.5)}])
    arrays = fovjax.render.scene_arrays(scene)
    arrays = eqx.tree_at(lambda a: a.kd, arrays, jnp.asarray(arrays.kd).at[1].set(jnp.nan))
    bvh = fovjax.trace.build_bvh(scene)
    key = jax.random.key(5)
    full = render_stereo(arrays, rig, spp=1, key=key, config=CONFIG, bvh=bvh)
    assert full.stats.bad_pixels > 0
    everything = Foveation(fovea_deg=180.0, periphery_deg=180.0, spp=1)
    fov_all = render_foveated(arrays, rig, foveation=everything, key=key, config=CONFIG, bvh=bvh)
    assert fov_all.stats.bad_pixels == full.stats.bad_pixels
    assert fov_all.stats.bad_samples == full.stats.bad_samples
    fov = render_foveated(arrays, rig, foveation=Foveation.thesis(0), key=key, config=CONFIG, bvh=bvh)
    traced_pixels = fov.sample_mask.any(axis=1)  # (2, H, W)
    bad = np.all(np.asarray(fov.outputs.prefill) == np.asarray(CONFIG.bad_color, np.float32), axis=-1)
    assert 0 < fov.stats.bad_pixels == int((bad & traced_pixels).sum())
    assert fov.stats.bad_samples == fov.stats.bad_pixels  # one sample per pixel at SPP 1


def test_budget_overflow_drops_samples_fills_them_and_warns():
    """A ray budget smaller than the samples wanted: the last samples are dropped and counted,
    the user is warned, exactly `budget` samples are traced, and every pixel of the image is
    still filled (pull-push from the traced ones): no blank pixel, traced fovea untouched."""
    import warnings

    scene, rig = _wall([{"kd": (0.7, 0.7, 0.7)}, {"kd": (0.3, 0.6, 0.9)}])
    key = jax.random.key(6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # within budget: nothing dropped, no warning
        roomy = render_foveated(scene, rig, foveation=Foveation.thesis(1), key=key, config=CONFIG)
    assert roomy.foveation.dropped == 0
    wanted = roomy.foveation.mandatory + roomy.foveation.optional
    # Room for 80% of the mandatory samples: some blocks lose their top-left too.
    capped = Foveation.thesis(1, ray_budget=int(0.4 * roomy.foveation.mandatory))
    with pytest.warns(RuntimeWarning, match="dropped"):
        frame = render_foveated(scene, rig, foveation=capped, key=key, config=CONFIG)
    s = frame.foveation
    assert s.budget == 2 * capped.ray_budget
    assert s.mandatory + s.optional == wanted  # the same plan, the same draws
    assert s.dropped == wanted - s.budget > 0
    assert frame.stats.primary_rays == int(frame.sample_mask.sum()) == s.budget
    assert frame.sample_mask.sum() < roomy.sample_mask.sum()
    assert not (frame.sample_mask & ~roomy.sample_mask).any()  # a subset of the plan
    image = frame.image
    assert np.isfinite(image).all() and (image.max(axis=-1) > 0).all()  # lit wall: no blank pixel
    # Some blocks had no traced sample at all (pull-push filled them).
    _, _, top_left = fovjax.foveate.internal.top_left(jnp.asarray(frame.regions[1]), capped)
    untraced_top_left = np.asarray(top_left) & ~frame.sample_mask[1].any(axis=0)
    assert untraced_top_left.any()
    # Traced foveal pixels keep their traced colour (the fill and blur leave the fovea alone).
    traced = frame.sample_mask.any(axis=1)
    eyes = np.stack(frame.eyes())
    prefill = np.asarray(frame.outputs.prefill)
    inner = traced & (frame.eccentricity < capped.fovea_deg - 0.01)
    assert inner.any()
    np.testing.assert_allclose(eyes[inner], prefill[inner], rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("shape", [(2, 64, 96), (2, 29, 37), (128,), (256, 1)])
def test_count_true_is_the_exact_count(shape):
    """`count_true` (uint8 sums of 128 entries where the size allows) against NumPy: every entry
    true (the uint8 sums at their largest), none, and a random mask."""
    from fovjax.foveate._frame import count_true

    rng = np.random.default_rng(0)
    f = jax.jit(count_true)
    for mask in (np.ones(shape, bool), np.zeros(shape, bool), rng.random(shape) < 0.3):
        assert int(f(jnp.asarray(mask))) == int(np.count_nonzero(mask))
