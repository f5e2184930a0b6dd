"""The banded blur-and-blend of the foveated frame (`blur_and_blend`: 5×5 Gaussian in bands of
rows, blended with the sharp image by eccentricity) against the whole-screen separable
convolution it replaces, itself checked against scipy's float64 correlation."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage

from fovjax.foveate import Foveation
from fovjax.foveate._fill import BAND_ROWS, FOVEA_BLEND_DEG, blur_and_blend, gaussian_taps


def separable_reference(image, taps):
    """The oracle: the whole image convolved with `taps` along rows, then columns, borders
    reflected without repeating the edge (`jnp.pad(mode="reflect")`), 5 shifted adds per axis:
    every screen-sized intermediate materialised (what `blur_and_blend` computes band by band)."""
    r = len(taps) // 2
    h, w = image.shape[:2]
    padded = jnp.pad(image, ((r, r), (0, 0), (0, 0)), mode="reflect")
    image = sum(float(t) * padded[i : i + h] for i, t in enumerate(taps))
    padded = jnp.pad(image, ((0, 0), (r, r), (0, 0)), mode="reflect")
    return sum(float(t) * padded[:, i : i + w] for i, t in enumerate(taps))


def blend_reference(image, ecc, foveation):
    """Per eye: the sharp image blended into the whole-screen blur by a smoothstep of
    eccentricity over FOVEA_BLEND_DEG beyond the fovea (the blur alone with `blur_fovea`)."""
    blurred = separable_reference(image, gaussian_taps(foveation.blur_sigma))
    if foveation.blur_fovea:
        return blurred
    t = jnp.clip((ecc - foveation.fovea_deg) / FOVEA_BLEND_DEG, 0.0, 1.0)
    weight = (t * t * (3 - 2 * t))[..., None]
    return image * (1 - weight) + blurred * weight


def eccentricity_maps(h, w, rng):
    """Named (2, H, W) maps in degrees: random on both sides of the fovea, a ramp across its
    edge and blend band (different per eye), all foveal, all beyond the blend."""
    ramp = np.linspace(0.0, 12.0, w, dtype=np.float32)
    return {
        "random": rng.uniform(0.0, 20.0, (2, h, w)).astype(np.float32),
        "ramp": np.stack([np.broadcast_to(ramp, (h, w)), np.broadcast_to(ramp[::-1], (h, w))]),
        "fovea": np.zeros((2, h, w), np.float32),
        "beyond": np.full((2, h, w), 30.0, np.float32),
    }


def test_reference_is_scipys_mirror_correlation():
    rng = np.random.default_rng(0)
    image = rng.uniform(0.0, 1.0, (23, 17, 3)).astype(np.float32)
    taps = gaussian_taps(1.0)
    expected = image.astype(np.float64)
    for axis in (0, 1):  # scipy's "mirror" reflects about the edge pixel: jnp's "reflect"
        expected = ndimage.correlate1d(expected, taps.astype(np.float64), axis=axis, mode="mirror")
    np.testing.assert_allclose(np.asarray(separable_reference(jnp.asarray(image), taps)), expected, atol=2e-7)


@pytest.mark.parametrize("h, w", [(2 * BAND_ROWS + 22, 37), (BAND_ROWS, 9), (11, 29)])
@pytest.mark.parametrize("blur_fovea", [False, True])
def test_banded_blur_equals_the_whole_screen_blur(h, w, blur_fovea):
    """Both eyes, several bands (the last overlapping its neighbour), one band, fewer rows
    than a band; side by side or stacked; each eccentricity map: equal to the whole-screen
    blend within float32 rounding."""
    rng = np.random.default_rng(h * 1000 + w)
    foveation = Foveation.thesis((5.0, 10.0), blur_fovea=blur_fovea)
    images = rng.uniform(0.0, 1.0, (2, h, w, 3)).astype(np.float32)
    images[1, ::3] *= 4.0  # the eyes differ, with some high-contrast rows
    for name, ecc in eccentricity_maps(h, w, rng).items():
        expected = np.stack([blend_reference(jnp.asarray(images[i]), ecc[i], foveation) for i in range(2)])
        stacked = np.asarray(blur_and_blend(jnp.asarray(images), jnp.asarray(ecc), foveation))
        side = np.asarray(blur_and_blend(jnp.asarray(images), jnp.asarray(ecc), foveation, side_by_side=True))
        np.testing.assert_allclose(stacked, expected, rtol=1e-6, atol=1e-6, err_msg=name)
        np.testing.assert_array_equal(side, np.concatenate([stacked[0], stacked[1]], axis=1), err_msg=name)
        if name == "fovea" and not blur_fovea:  # foveal pixels stay sharp, bit for bit
            np.testing.assert_array_equal(stacked, images)
        if name == "beyond" or blur_fovea:  # a real blur: the image changed
            assert np.abs(stacked - images).max() > 0.05
