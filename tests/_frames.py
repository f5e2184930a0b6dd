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
