// What every native source of fovjax shares: the standard headers, XLA's FFI API and the
// vectorisation switches. Built as one translation unit: fovjax/native/csrc/library.cc.
#pragma once

#include <dlfcn.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <string>
#include <type_traits>
#include <unordered_map>
#include <utility>
#include <vector>

#include "xla/ffi/api/ffi.h"

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define FOVJAX_AVX512_LANES 1
#endif

namespace ffi = xla::ffi;

// A plain loop over lanes or pixels built for the widest vector unit the CPU has (chosen when
// the library loads), which the compiler vectorises.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define FOVJAX_VECTOR_CLONES __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define FOVJAX_VECTOR_CLONES
#endif
