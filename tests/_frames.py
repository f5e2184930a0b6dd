"""Comparing frames that two different compiled programs compute the same way.

Two programs that compute one radiance need not round alike: XLA fuses them differently and
LLVM chooses instructions per program (a multiply and an add fused into one rounding, or not),
more so as the suite compiles (conftest: LLVM's lowest optimisation level). Each such choice
moves a float32 value by about an ulp (6e-8 at 0.5); a frame's chain of a few dozen of them stays well
below SAME_RADIANCE, which in turn lies far below one 8-bit display step (1/255 = 3.9e-3) and
below every change these tests guard against (a wrong level, class, sample or region moves a
pixel by 1e-3 or more). Bit-for-bit claims stay `np.array_equal` where one program computes both
values (the same program run twice, a value only copied)."""

import os

import numpy as np

SAME_RADIANCE = 1e-5

# What conftest adds to XLA_FLAGS for a shorter compile: LLVM's lowest optimisation level and
# XLA:CPU's loop emitters.
FAST_COMPILE_FLAGS = ("--xla_backend_optimization_level=0", "--xla_cpu_use_fusion_emitters=false")


def users_xla_flags() -> str:
    """XLA_FLAGS as the user set them, without the suite's FAST_COMPILE_FLAGS."""
    return " ".join(f for f in os.environ.get("XLA_FLAGS", "").split() if f not in FAST_COMPILE_FLAGS)


def assert_same_radiance(actual, expected) -> None:
    """The two images are the same up to float32 rounding (see the module's note)."""
    np.testing.assert_allclose(
        np.asarray(actual), np.asarray(expected), rtol=SAME_RADIANCE, atol=SAME_RADIANCE
    )


# Blinn-Phong's specular term (n·h)^ns turns a relative difference e of n·h between the two
# programs into ns·e of the term, which is part of the sample (every term is non-negative):
# n and h are unit vectors normalised apart (1/sqrt in C++, XLA's rsqrt estimate refined once)
# from hit points that round apart, a few ulp each, and their dot product adds two more. A
# bound of 8 ulp for e.
N_DOT_H_ULPS = 8


def native_rtol(arrays) -> float:
    """The relative tolerance of a native sample against the JAX one: SAME_RADIANCE (two
    programs' rounding, tests/_frames.py) plus the specular exponent's amplification at the
    scene's largest exponent. Its absolute floor is SAME_RADIANCE."""
    return SAME_RADIANCE + N_DOT_H_ULPS * 2.0**-24 * float(np.max(np.asarray(arrays.ns)))


def assert_native_radiance(native, reference, arrays) -> None:
    """Every sample (or pixel: a mean of samples keeps the bound) of `native` is `reference`'s
    to float rounding (`native_rtol`)."""
    np.testing.assert_allclose(
        np.asarray(native), np.asarray(reference), rtol=native_rtol(arrays), atol=SAME_RADIANCE
    )
