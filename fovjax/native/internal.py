"""What the packages with native stages share and users do not need: the plan (`plan_native`),
the choice per platform (`on_platforms`), the handlers' FFI calls (`handler`) and the layout the
handlers read (`_layout`'s constants)."""

from __future__ import annotations

import jax

from . import _layout as layout
from ._dispatch import NativePlan as NativePlan
from ._dispatch import jvp_of as jvp_of
from ._dispatch import on_platforms as on_platforms
from ._dispatch import other_platforms as other_platforms
from ._dispatch import plan_native as plan_native
from ._library import HANDLERS
from ._library import status as _status


def handler(target: str, result_shapes, *, what: str, **kwargs):
    """`jax.ffi.ffi_call` of the native handler `target` (one of `HANDLERS`), after checking that
    the handlers are loaded: otherwise a RuntimeError naming `what` needed them and why they are
    unavailable."""
    if target not in HANDLERS:
        raise ValueError(f"no native handler {target!r}; the handlers are {sorted(HANDLERS)}")
    found = _status()
    if not found:
        raise RuntimeError(f"{what} needs the native handlers, which are unavailable: {found.reason}")
    return jax.ffi.ffi_call(target, result_shapes, **kwargs)


__all__ = [
    "HANDLERS",
    "NativePlan",
    "handler",
    "jvp_of",
    "layout",
    "on_platforms",
    "other_platforms",
    "plan_native",
]
