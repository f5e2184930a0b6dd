"""The traced samples' sub-pixel positions, computed per sample (`positions_at`), are the full
render's (`pixel_sample_positions`), bit for bit."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fovjax.foveate._positions import per_sample_threefry, positions_at, uniform_at
from fovjax.scene import pixel_sample_positions


@pytest.mark.parametrize("spp", [1, 4, 9])
@pytest.mark.parametrize("make_key", [jax.random.key, jax.random.PRNGKey, None], ids=["key", "raw", "none"])
def test_positions_at_are_the_full_render_positions(spp, make_key):
    w, h = 37, 23
    key = None if make_key is None else make_key(7)
    # Both jitted, as in the frames (XLA may turn a division by a constant into a product).
    screen = jax.jit(lambda k: pixel_sample_positions(w, h, spp, k))(key)
    screen = np.asarray(screen).reshape(spp, h * w, 2)
    rng = np.random.default_rng(0)
    sample = rng.integers(0, spp, 500).astype(np.int32)
    pixel = rng.integers(0, h * w, 500).astype(np.int32)
    got = jax.jit(lambda k, s, p: positions_at(k, s, p, spp=spp, h=h, w=w))(key, sample, pixel)
    np.testing.assert_array_equal(np.asarray(got), screen[sample, pixel])


def test_the_default_prng_takes_the_per_sample_path():
    # Otherwise the frame falls back to the full-screen draw (still exact, not cheaper).
    assert per_sample_threefry(jax.random.key(0))
    assert per_sample_threefry(jax.random.PRNGKey(0))


def test_uniform_at_is_jax_random_uniform():
    key = jax.random.key(123)
    shape = (3, 50, 41)
    full = np.asarray(jax.random.uniform(key, shape)).reshape(-1)
    index = jnp.asarray([0, 1, 2, 4097, full.size - 1, 1234], jnp.int32)
    np.testing.assert_array_equal(np.asarray(uniform_at(key, index)), full[np.asarray(index)])


def test_threefry_written_out_is_jax_threefry():
    """The unrolled hash gives the bits of JAX's threefry2x32 primitive (counter hi 0, lo)."""
    from jax.extend.random import threefry_2x32

    from fovjax.foveate._positions import threefry_xor

    rng = np.random.default_rng(0)
    lo = np.concatenate([[0, 1, 2**31, 2**32 - 1], rng.integers(0, 2**32, 2000)]).astype(np.uint32)
    for data in ([0, 0], [2**32 - 1, 2**32 - 1], rng.integers(0, 2**32, 2)):
        data = jnp.asarray(np.asarray(data, np.uint64).astype(np.uint32))
        words = threefry_2x32(data, jnp.concatenate([jnp.zeros_like(lo), jnp.asarray(lo)]))
        expected = np.asarray(words[: lo.size] ^ words[lo.size :])
        np.testing.assert_array_equal(np.asarray(jax.jit(threefry_xor)(data, jnp.asarray(lo))), expected)


def test_another_prng_falls_back_to_the_screen():
    key = jax.random.key(5, impl="rbg")
    assert not per_sample_threefry(key)
    w, h, spp = 16, 8, 4
    screen = np.asarray(jax.jit(lambda k: pixel_sample_positions(w, h, spp, k))(key))
    screen = screen.reshape(spp, h * w, 2)
    sample = np.arange(spp * h * w, dtype=np.int32) % spp
    pixel = np.arange(spp * h * w, dtype=np.int32) // spp
    got = positions_at(key, jnp.asarray(sample), jnp.asarray(pixel), spp=spp, h=h, w=w)
    np.testing.assert_array_equal(np.asarray(got), screen[sample, pixel])


@pytest.mark.parametrize("shape", [(1, 130, 70), (4, 64, 33), (2, 7, 5)])
def test_uniform_draws_in_bands_are_jax_random_uniform(shape):
    from fovjax.foveate._sampling import uniform_draws

    key = jax.random.key(11)
    want = np.asarray(jax.random.uniform(key, shape, jnp.float32))
    np.testing.assert_array_equal(np.asarray(jax.jit(uniform_draws, static_argnums=1)(key, shape)), want)
