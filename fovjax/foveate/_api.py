"""`render_foveated`: one foveated frame through a `FoveatedRenderer` made for it (the renderer
prepares the scene; the compiled program is shared by every renderer of the same configuration:
one per rig, SPP, render config and scene shapes; gaze, head pose, key and the fovea/periphery
thresholds are traced)."""

from __future__ import annotations

import jax

from ..render import TRACE_COUNTS as TRACE_COUNTS  # shared by every entry point
from ..render import HeadPoseLike, RenderConfig, SceneArrays, StereoRig
from ..scene import LODLevels, Scene
from ..trace import BVH
from ._config import Foveation, GazeLike
from ._frame import DIAGNOSTICS, DiagnosticsLike
from ._renderer import CENTRE_GAZE, FoveatedFrame, FoveatedRenderer
from ._renderer import _budget_for as _budget_for  # the budget of every entry point
from ._renderer import fovea_tile as fovea_tile
from ._renderer import uncapped as uncapped


def render_foveated(
    scene: Scene | SceneArrays,
    rig: StereoRig | None = None,
    *,
    gaze: GazeLike = CENTRE_GAZE,
    foveation: Foveation | None = None,
    head_pose: HeadPoseLike = None,
    key: jax.Array | None = None,
    config: RenderConfig | None = None,
    bvh: BVH | None = None,
    lod_levels: LODLevels | None = None,
    diagnostics: DiagnosticsLike = DIAGNOSTICS,
) -> FoveatedFrame:
    """Render a foveated stereo frame (thesis chapter 4; the steps in `fovjax.foveate._frame`).

    Compiled once per configuration (resolution, spp, render config, scene array shapes, the
    foveation's static options); a new gaze, head pose, key, or fovea and periphery thresholds
    within `foveation.max_periphery_deg` reuse the program. A frame whose samples overflow a
    capped budget warns (the blocks left without a sample are filled by pull-push).

    Args:
        scene: a `fovjax.Scene` or its `SceneArrays`.
        rig: the `StereoRig` (default: the thesis HMD at the scene's default viewpoint).
        gaze: per eye (x, y) in normalised display coordinates, (0, 0) the top-left of each eye's
            display. NaN or off-screen gaze is rejected here (the tracking layer decides
            fallbacks).
        foveation: the `Foveation` (default `Foveation()`).
        head_pose: (yaw, pitch, roll) degrees or a `fovjax.devices.HeadPose`.
        key: the frame's PRNG key (sub-pixel jitter and sampling draws); None renders pixel-cell
            centres and a fixed sampling pattern.
        config: the `fovjax.render.RenderConfig`.
        bvh: a prebuilt BVH.
        lod_levels: the scene's levels of detail (`fovjax.scene.lod_levels`) that `Fidelity.lod`
            indexes; None: `lod_levels(scene)` at its default ratios (cached on disk) when a region
            asks for a level. Only a `Scene` has levels (not a `SceneArrays`).
        diagnostics: the per-pixel outputs besides the image (names of `DIAGNOSTICS`: "traced" →
            `sample_mask`, "region" → `regions`, "eccentricity", "prefill" → `outputs.prefill`;
            default all; `DEBUG_VIEW_DIAGNOSTICS` for `debug_view`). A static choice (another set
            is another compiled program): on a CPU every screen-sized output is fresh memory each
            frame, so a frame loop asks only for what it reads.

    An environment map for the rays that miss: `FoveatedRenderer(..., envmap=)` (the way to
    render frames in a loop), or a `SceneArrays` made with one (`scene_arrays(scene, envmap=)`)
    as `scene`, with `bvh`.

    Returns:
        The `FoveatedFrame`.

    Raises:
        ValueError: a bad gaze (naming the eye and the value) or foveation.
    """
    renderer = FoveatedRenderer(
        scene,
        rig,
        foveation,
        config,
        bvh=bvh,
        lod_levels=lod_levels,
        diagnostics=diagnostics,
    )
    return renderer.render(gaze, head_pose=head_pose, key=key)
