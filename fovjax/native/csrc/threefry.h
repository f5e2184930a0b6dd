// JAX's default PRNG, threefry2x32, as `jax.random.uniform` draws float32 uniforms with it
// (`jax_threefry_partitionable`, the default since JAX 0.5; fovjax/foveate/_positions.py says
// how): the sub-pixel jitter of `fovjax.scene.pixel_sample_positions` and the foveated frame's
// sample draws, reproduced bit for bit by the handlers that make those samples natively.
#pragma once

#include "native/csrc/common.h"

namespace {

// One lane's threefry2x32 (see UniformRun): the uniform float of counter `c`.
inline float UniformOne(const uint32_t ks[3], uint32_t c) {
  static constexpr int kRotations[2][4] = {{13, 15, 26, 6}, {17, 29, 16, 24}};
  uint32_t x0 = ks[0], x1 = c + ks[1];
  for (int group = 0; group < 5; ++group) {
    for (int j = 0; j < 4; ++j) {
      const int r = kRotations[group % 2][j];
      x0 += x1;
      x1 = (x1 << r) | (x1 >> (32 - r));
      x1 ^= x0;
    }
    x0 += ks[(group + 1) % 3];
    x1 += ks[(group + 2) % 3] + static_cast<uint32_t>(group + 1);
  }
  const uint32_t mantissa = ((x0 ^ x1) >> 9) | 0x3F800000u;
  float f;
  std::memcpy(&f, &mantissa, sizeof f);
  f -= 1.0f;
  return f > 0.0f ? f : 0.0f;
}

// The uniforms of n counters, `first + i` or `index[i]`: 64 lanes at a time, each round a
// loop over the lanes that the compiler vectorises. Each vector of lanes is one long chain of
// dependent rounds; 64 lanes keep several chains in flight on the vector unit.
template <bool kIndexed>
inline __attribute__((always_inline)) void UniformLanes(uint32_t k0, uint32_t k1, uint32_t first,
                                                        const uint32_t* __restrict__ index, int64_t n,
                                                        float* __restrict__ out) {
  static constexpr int kRotations[2][4] = {{13, 15, 26, 6}, {17, 29, 16, 24}};
  constexpr int kLanes = 64;
  const uint32_t ks[3] = {k0, k1, k0 ^ k1 ^ 0x1BD11BDAu};
  int64_t i = 0;
  for (; i + kLanes <= n; i += kLanes) {
    uint32_t x0[kLanes], x1[kLanes];
    for (int j = 0; j < kLanes; ++j) {
      x0[j] = ks[0];
      x1[j] = (kIndexed ? index[i + j] : first + static_cast<uint32_t>(i + j)) + ks[1];
    }
#pragma GCC unroll 5
    for (int group = 0; group < 5; ++group) {
#pragma GCC unroll 4
      for (int r4 = 0; r4 < 4; ++r4) {
        const int r = kRotations[group % 2][r4];
        for (int j = 0; j < kLanes; ++j) {
          x0[j] += x1[j];
          x1[j] = (x1[j] << r) | (x1[j] >> (32 - r));
          x1[j] ^= x0[j];
        }
      }
      const uint32_t a = ks[(group + 1) % 3], b = ks[(group + 2) % 3] + static_cast<uint32_t>(group + 1);
      for (int j = 0; j < kLanes; ++j) {
        x0[j] += a;
        x1[j] += b;
      }
    }
    for (int j = 0; j < kLanes; ++j) {
      const uint32_t mantissa = ((x0[j] ^ x1[j]) >> 9) | 0x3F800000u;
      float f;
      std::memcpy(&f, &mantissa, sizeof f);
      f -= 1.0f;
      out[i + j] = f > 0.0f ? f : 0.0f;
    }
  }
  for (; i < n; ++i) out[i] = UniformOne(ks, kIndexed ? index[i] : first + static_cast<uint32_t>(i));
}

// JAX's uniform float32 in [0, 1) at flat indices first..first+n-1 of the key (k0, k1):
// threefry2x32 of each 64-bit counter (hi 0, index), its two words xor-ed, the top 23 bits as a
// mantissa in [1, 2), minus 1. A plain loop over lanes that the compiler vectorises, built for
// the widest vector unit the CPU has (chosen when the library loads).
FOVJAX_VECTOR_CLONES
void UniformRun(uint32_t k0, uint32_t k1, uint32_t first, int64_t n, float* out) {
  UniformLanes<false>(k0, k1, first, nullptr, n, out);
}

// JAX's threefry2x32 uniform (see UniformRun) at each of n counters.
FOVJAX_VECTOR_CLONES
void UniformAt(uint32_t k0, uint32_t k1, const uint32_t* __restrict__ index, int64_t n,
               float* __restrict__ out) {
  UniformLanes<true>(k0, k1, 0, index, n, out);
}

}  // namespace
