"""A `FoveatedRenderer` frame through a method other than the thesis's (`Foveation.method`):
the same prepared scene and compile path (`run_compiled`, one program per configuration), the
method's frame program, and its history carried from frame to frame when the method keeps one."""

from __future__ import annotations

import numpy as np


def program_of(method):
    """(compile-cache entry, frame program) of a method."""
    if method.name == "weier2016":
        from ._weier import weier_stereo

        return "foveated-weier2016", weier_stereo
    if method.name == "guenter2012":
        from ._guenter import guenter_stereo

        return "foveated-guenter2012", guenter_stereo
    if method.name == "patney2016":
        from ._patney import patney_stereo

        return "foveated-patney2016", patney_stereo
    raise ValueError(f"no frame program for foveation method {method.name!r}")


def initial_history(method, rig):
    """The method's history after a reset (None: the method keeps none)."""
    if method.name == "weier2016":
        from ._weier import empty_history

        return empty_history(rig.eye_height, rig.eye_width)
    if method.name == "patney2016":
        from ._patney import empty_history as empty_taa_history

        return empty_taa_history(rig.eye_height, rig.eye_width)
    return None


def render_with_method(renderer, foveation, frame_args, *, jitter, diagnostics, reset: bool):
    """Run the method's frame program on the renderer's prepared inputs and this frame's
    (head pose, gaze, key) `frame_args`; a temporal method starts from the renderer's history
    (or a fresh one when `reset` or none yet) and leaves this frame's there. Returns (outputs,
    pixels reused from the history, compile seconds, render seconds)."""
    import jax
    import jax.numpy as jnp

    from ...render.internal import run_compiled

    method = foveation.method
    entry, program = program_of(method)
    arrays, bvh, rig = renderer._scene_inputs
    history = renderer._history.value
    if reset or history is None:
        history = jax.tree.map(jnp.asarray, initial_history(method, renderer.rig))
    from .._frame import FrameOptions

    options = FrameOptions(spp=foveation.spp, jitter=jitter, config=renderer.config, diagnostics=diagnostics)
    static = {"options": options}
    args = (arrays, bvh, rig, *frame_args, foveation, history)
    (out, reused, history), compile_s, render_s = run_compiled(entry, program, args, static)
    if method.temporal:
        renderer._history.value = history
    return out, int(np.asarray(reused)), compile_s, render_s
