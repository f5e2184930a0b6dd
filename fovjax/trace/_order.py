"""Ray order for packets of rays given in no useful order (`packet="sorted"`).

Rays that are coherent in space but arrive in an order that is not (shadow rays from scattered
surface points towards a light, a compacted list of an image's hits) trace well in packets only
once neighbours are consecutive. The order here is a Morton (Z-order) code of each ray's origin
within the live rays' bounding box, sorted within blocks of consecutive rays.

Why blocks: XLA:CPU sorts a single int32 operand several times faster than a (key, index)
pair, so the key and the ray's index within its block share one int32: the block's index bits
below, as many of the Morton code's leading bits as fit above. Blocks of 2^14 rays keep 17 bits
of the code, which packs the atrium's shadow rays into packets nearly as well as a full sort
(`benchmarks/trace_throughput.py`, row "shadow sorted", times the whole call).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

MAX_BLOCK_BITS = 14
MORTON_BITS = 10  # per axis


def _spread_bits(x):
    """The low 10 bits of x with two zero bits after each (x → x0 0 0 x1 0 0 …)."""
    x = x & 0x3FF
    x = (x | (x << 16)) & 0x030000FF
    x = (x | (x << 8)) & 0x0300F00F
    x = (x | (x << 4)) & 0x030C30C3
    return (x | (x << 2)) & 0x09249249


def morton_codes(points: Float[Array, "n 3"], live: Bool[Array, " n"]) -> Int[Array, " n"]:
    """30-bit Morton codes of the points within the live points' bounding box (int32, ≥ 0)."""
    inside = live[:, None] & jnp.isfinite(points)
    lo = jnp.min(jnp.where(inside, points, jnp.inf), axis=0)
    hi = jnp.max(jnp.where(inside, points, -jnp.inf), axis=0)
    extent = jnp.where(hi > lo, hi - lo, 1.0)
    cells = 1 << MORTON_BITS
    q = jnp.floor((points - lo) / extent * cells)
    q = jnp.clip(jnp.where(inside, q, 0.0), 0, cells - 1).astype(jnp.int32)
    return _spread_bits(q[:, 0]) | (_spread_bits(q[:, 1]) << 1) | (_spread_bits(q[:, 2]) << 2)


def block_bits(n: int) -> int:
    """log2 of the sort's block size for n rays: the smallest power of two ≥ n, at most 2^14."""
    return min(MAX_BLOCK_BITS, max(int(n - 1).bit_length(), 1))


def spatial_order(origins: Float[Array, "n 3"], live: Bool[Array, " n"]) -> Int[Array, " n"]:
    """A permutation of the rays (gather indices) that puts each block of 2^`block_bits(n)`
    consecutive rays in Morton order of their origins; rays that are not live go to the end
    of their block. Blocks stay where they are, so the order is local and the sort cheap."""
    n = origins.shape[0]
    bits = block_bits(n)
    size = 1 << bits
    pad = (-n) % size
    key_bits = 31 - bits  # the sign bit stays clear
    code = morton_codes(origins, live) >> (3 * MORTON_BITS - key_bits)
    code = jnp.where(live, code, (1 << key_bits) - 1)
    code = jnp.pad(code, (0, pad), constant_values=(1 << key_bits) - 1)
    index = jnp.arange(n + pad, dtype=jnp.int32)
    within = index & (size - 1)
    packed = jax.lax.sort((code << bits | within).reshape(-1, size), dimension=1).reshape(-1)
    order = (index & ~(size - 1)) | (packed & (size - 1))
    # The padding (only in the last block, keys maximal, indices beyond n) sorts after that
    # block's rays, so the first n entries are a permutation of 0..n-1.
    return order[:n]


def inverse_order(order: Int[Array, " n"]) -> Int[Array, " n"]:
    """The gather indices that undo `order`."""
    n = order.shape[0]
    return jnp.zeros(n, jnp.int32).at[order].set(jnp.arange(n, dtype=jnp.int32), unique_indices=True)
