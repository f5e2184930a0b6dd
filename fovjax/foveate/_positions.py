"""Sub-pixel sample positions of the traced samples only.

The foveated frame traces ~9% of a frame's samples at 5°/10°, but the full render's
positions (`fovjax.scene.pixel_sample_positions`) are one uniform draw per sample and axis over
the whole screen: at 2 × 1280 × 1024 a 21 MB array of threefry draws every frame, of which
the frame reads a tenth. `positions_at` computes the same values, bit for bit, for the listed
samples only.

That rests on how JAX draws uniforms with its default PRNG (threefry2x32, with
`jax_threefry_partitionable`, the default since JAX 0.5): element i of
`jax.random.uniform(key, shape)` is threefry2x32 of the key and the 64-bit counter i (hi, lo
words), the two output words xor-ed, and its top 23 bits as the mantissa of a float in [1, 2),
minus 1. Where that does not hold (another PRNG implementation, the flag off), `positions_at`
falls back to the full-screen draw and a gather; `tests/test_foveate_positions.py` checks the
two against each other.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int, UInt

from ..scene import pixel_sample_positions, stratified_offsets
from ..scene.internal import key_words, per_sample_threefry

# Threefry-2x32's rotations, alternating by group of four rounds, and its key-schedule constant.
_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))
_PARITY = np.uint32(0x1BD11BDA)


def threefry_xor(data: UInt[Array, " 2"], lo: UInt[Array, "*batch"]) -> UInt[Array, "*batch"]:
    """The two output words of threefry2x32 xor-ed, for the key `data` (2,) uint32 and the
    64-bit counters (hi 0, `lo`): the same bits as `jax.extend.random.threefry_2x32`'s. Written
    out round by round, because JAX lowers that primitive on a CPU as a loop over its five
    groups of rounds (small programs, but each group a pass over memory, with copies of the
    loop's carry); unrolled, XLA fuses the twenty rounds into one pass."""
    k0, k1 = data[0], data[1]
    ks = (k0, k1, k0 ^ k1 ^ _PARITY)
    x0 = jnp.zeros_like(lo) + ks[0]
    x1 = lo + ks[1]
    for group in range(5):
        for r in _ROTATIONS[group % 2]:
            x0 = x0 + x1
            x1 = (x1 << np.uint32(r)) | (x1 >> np.uint32(32 - r))
            x1 = x0 ^ x1
        x0 = x0 + ks[(group + 1) % 3]
        x1 = x1 + ks[(group + 2) % 3] + np.uint32(group + 1)
    return x0 ^ x1


def uniform_at(key, index: Int[Array, "*batch"]) -> Float[Array, "*batch"]:
    """`jax.random.uniform(key, shape).reshape(-1)[index]` (float32 in [0, 1)) for any shape of
    fewer than 2**31 elements, computed at `index` only. Only where `per_sample_threefry(key)`."""
    data = key_words(key)
    lo = jnp.asarray(index, jnp.uint32).reshape(-1)
    bits = threefry_xor(data, lo)  # counter (hi 0, lo)
    mantissa = (bits >> np.uint32(9)) | np.uint32(0x3F800000)  # [1, 2)
    floats = jax.lax.bitcast_convert_type(mantissa, jnp.float32) - jnp.float32(1.0)
    return jnp.maximum(jnp.float32(0.0), floats).reshape(jnp.shape(index))


def positions_at(
    key, sample: Int[Array, " N"], pixel: Int[Array, " N"], *, spp: int, h: int, w: int
) -> Float[Array, "N 2"]:
    """`pixel_sample_positions(w, h, spp, key)[sample, pixel // w, pixel % w]`, the same values,
    computed for those samples only where the key's PRNG allows it (`key` None: cell centres)."""
    with jax.ensure_compile_time_eval():  # a constant, as XLA folds the screen's (not re-folded)
        grid = np.asarray(stratified_offsets(spp))  # (spp, 2) cell centres
    n = int(round(spp**0.5))
    y, x = pixel // w, pixel % w
    corner = jnp.stack([x.astype(jnp.float32), y.astype(jnp.float32)], axis=-1)
    if key is None:
        return corner + jnp.asarray(grid)[sample]
    size = spp * h * w * 2
    if not per_sample_threefry(key) or size >= 2**31:  # int32 indices
        return pixel_sample_positions(w, h, spp, key).reshape(spp, h * w, 2)[sample, pixel]
    first = ((sample * h + y) * w + x) * 2  # flat index of the sample's x draw
    jitter = uniform_at(key, first[:, None] + jnp.arange(2, dtype=first.dtype))
    return corner + (jnp.asarray(grid)[sample] + (jitter - 0.5) / n)
