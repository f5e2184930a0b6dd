"""Host-side entry point of foveated rendering: one compiled program per rig, SPP, render
config and scene shapes; gaze, head pose, key and the fovea/periphery thresholds are traced."""

from __future__ import annotations

import dataclasses
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from ..render import TRACE_COUNTS as TRACE_COUNTS  # shared by every entry point
from ._budget import plan_budget
from ._config import (
    Foveation,
    check_gaze,
    max_region_spp,
    program_fidelity,
    region_spp,
    uses_texture_lod,
)
from ._frame import (
    DIAGNOSTICS,
    FoveatedOutputs,
    FoveationStats,
    diagnostics_tuple,
    foveated_stereo,
    region_view,
)
from ._lod import check_levels, lod_needed, prepare_levels

_BUDGETS: dict = {}


def _budget_for(rig, head_pose, foveation: Foveation) -> int:
    """Static slot count of both eyes (cached per rig intrinsics and configuration): every
    sample when `max_periphery_deg` is None (any thresholds fit), else `plan_budget` at the
    maximum thresholds (or the configured `ray_budget`)."""
    full = 2 * max_region_spp(foveation) * rig.eye_width * rig.eye_height
    if foveation.ray_budget is None and foveation.max_periphery_deg is None:
        return full
    key = (
        rig.eye_width,
        rig.eye_height,
        float(rig.fov_deg),
        rig.fov_axis,
        tuple(np.asarray(rig.offsets).reshape(-1).tolist()),
        foveation.max_periphery_deg,
        foveation.spp,
        foveation.blocks,
        foveation.rule,
        foveation.eccentricity,
        foveation.eye_display_mm,
        foveation.pixel_pitch_mm,
        foveation.ray_budget,
        region_spp(foveation),  # texture level of detail and samples per pixel per region
        # Any acuity callable: scalar parameters or arrays (a tabulated curve, a batch of fits).
        tuple(
            (np.shape(x), tuple(np.asarray(x).reshape(-1).tolist()))
            for x in jax.tree.leaves(foveation.acuity)
        ),
        type(foveation.acuity).__name__,
    )
    budget = _BUDGETS.get(key)
    if budget is None:
        # The worst case of any thresholds up to the maximum: everything within it is foveal.
        m = foveation.max_periphery_deg
        widest = foveation if m is None else dataclasses.replace(foveation, fovea_deg=m, periphery_deg=m)
        budget = _BUDGETS[key] = sum(plan_budget(cam, widest) for cam in rig.eye_cameras(head_pose))
    return budget


def uncapped(rig, foveation: Foveation, budget: int) -> bool:
    """Whether the budget is every sample (image tiles need it: their samples are never dropped)."""
    return budget >= 2 * max_region_spp(foveation) * rig.eye_width * rig.eye_height


def fovea_tile(rig, foveation: Foveation, budget: int) -> tuple[int, int] | None:
    """Static (rows, cols) of the fovea tile: a square over `foveation.fovea_tile_deg` of
    eccentricity at the display's pixels per degree at its centre (plus 10%: they grow off
    centre), in whole 8-pixel packets, within the eye's image; None without a tile or when the
    budget is capped (a tile's samples must never be dropped)."""
    if foveation.fovea_tile_deg is None or not uncapped(rig, foveation, budget):
        return None
    h, w = rig.eye_height, rig.eye_width
    per_degree = (h / 2) / np.tan(np.deg2rad(float(rig.vfov_deg())) / 2) * np.pi / 180
    edge = 2 * int(np.ceil(1.1 * foveation.fovea_tile_deg * per_degree))
    edge = -(-edge // 8) * 8
    return min(edge, h), min(edge, w)


@dataclasses.dataclass(frozen=True)
class FoveatedFrame:
    """A foveated stereo frame: the side-by-side `image` (H, 2W, 3) linear RGB, `stats` (the
    renderer's `FrameStats`: rays actually traced, times), `foveation` (`FoveationStats`), and
    the per-eye `sample_mask` (2, spp, H, W) of traced samples, `regions` (2, H, W int8: 0
    fovea, 1 periphery, 2 outside) and `eccentricity` (2, H, W, degrees): each None when the
    frame was rendered without it (`render_foveated(diagnostics=)`). `outputs`: the frame
    program's (`FoveatedOutputs`; its `prefill` is each pixel's mean of its traced samples)."""

    image: np.ndarray
    stats: object
    foveation: FoveationStats
    sample_mask: np.ndarray | None
    regions: np.ndarray | None
    eccentricity: np.ndarray | None
    outputs: FoveatedOutputs

    @property
    def debug_view(self) -> np.ndarray:
        """Regions and traced samples per eye (thesis figures 58-59), side by side (needs the
        diagnostics of `fovjax.foveate.DEBUG_VIEW_DIAGNOSTICS`)."""
        return np.asarray(region_view(self.outputs))

    def save(self, path, **kwargs):
        from ..files import save_image

        return save_image(path, self.image, **kwargs)

    def eyes(self):
        half = self.image.shape[1] // 2
        return self.image[:, :half], self.image[:, half:]


def _levels_of_detail(scene, arrays, bvh, foveation, rig, levels, top: int):
    """The merged scene arrays, BVH and `LODTables` of the levels `foveation` asks for; bad
    levels fail here, before any compile."""
    from ..scene import LODLevels, Scene
    from ..scene import lod_levels as make_levels

    if not isinstance(scene, Scene):
        raise ValueError(
            "render_foveated: Fidelity.lod needs a fovjax.Scene (levels of detail are decimated from "
            f"its geometry), got {type(scene).__name__}"
        )
    if levels is None:
        levels = make_levels(scene)
    elif not isinstance(levels, LODLevels):
        raise ValueError(
            f"render_foveated: lod_levels must be a fovjax.scene.LODLevels, got {type(levels).__name__}"
        )
    if levels.scenes[0].content_hash != scene.content_hash:
        raise ValueError(
            "render_foveated: lod_levels were made from another scene (their level 0 is not this scene)"
        )
    check_levels(foveation, levels)
    h = rig.eye_height
    per_degree = (h / 2) / np.tan(np.deg2rad(float(rig.vfov_deg())) / 2) * np.pi / 180
    return prepare_levels(scene, arrays, bvh, levels, top, float(per_degree))


def render_foveated(
    scene,
    rig=None,
    *,
    gaze=((0.5, 0.5), (0.5, 0.5)),
    foveation: Foveation | None = None,
    head_pose=None,
    key: jax.Array | None = None,
    config=None,
    envmap=None,
    bvh=None,
    lod_levels=None,
    diagnostics=DIAGNOSTICS,
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
        envmap: an environment map for rays that miss.
        bvh: a prebuilt BVH.
        lod_levels: the scene's levels of detail (`fovjax.scene.lod_levels`) that `Fidelity.lod`
            indexes; None: `lod_levels(scene)` at its default ratios (cached on disk) when a region
            asks for a level. Only a `Scene` has levels (not a `SceneArrays`).
        diagnostics: the per-pixel outputs besides the image (names of `DIAGNOSTICS`: "traced" →
            `sample_mask`, "region" → `regions`, "eccentricity", "prefill" → `outputs.prefill`;
            default all; `DEBUG_VIEW_DIAGNOSTICS` for `debug_view`). A static choice (another set
            is another compiled program): on a CPU every screen-sized output is fresh memory each
            frame, so a frame loop asks only for what it reads.

    Returns:
        The `FoveatedFrame`.

    Raises:
        ValueError: a bad gaze (naming the eye and the value) or foveation.
    """
    from ..render import (
        RenderConfig,
        SceneArrays,
        StereoRig,
        bvh_for,
        frame_stats,
        head_pose_angles,
        run_compiled,
        scene_arrays,
        with_texture_mips,
    )

    foveation = foveation or Foveation()
    config = config or RenderConfig()
    gaze = check_gaze(gaze)
    diagnostics = diagnostics_tuple(diagnostics)
    if rig is None:
        from ..scene import default_camera

        rig = StereoRig.from_pose(default_camera(scene))
    m = foveation.max_periphery_deg
    if m is not None and not foveation.periphery_deg <= m:
        raise ValueError(
            f"render_foveated: periphery_deg {foveation.periphery_deg} exceeds max_periphery_deg {m} "
            "(the maximum the compiled program serves)"
        )
    # A bad per-region depth fails before any work; depths and shadow modes are traced tables.
    program_foveation, shading = program_fidelity(foveation, config)
    bvh = bvh_for(scene, bvh)
    arrays = (
        scene
        if isinstance(scene, SceneArrays)
        else scene_arrays(scene, envmap=envmap, background=config.background)
    )
    if uses_texture_lod(foveation):  # mip pyramids on the host, once per texture
        arrays = with_texture_mips(arrays)
    jitter = key is not None
    key = key if jitter else jax.random.key(0)
    angles = np.asarray(head_pose_angles(head_pose), np.float32)
    budget = _budget_for(rig, angles, foveation)
    # The foveation config is an argument: its options are static fields (part of the tree
    # structure), its thresholds and acuity model's parameters arrays (new thresholds or a
    # refitted model recompile nothing).
    tile = fovea_tile(rig, foveation, budget)
    static = {"spp": foveation.spp, "jitter": jitter, "config": config, "budget": budget, "tile": tile}
    static["diagnostics"] = diagnostics
    static["grid"] = foveation.blocks[1] if foveation.grid_tile and uncapped(rig, foveation, budget) else None
    # --- geometry level of detail ---
    lod = None
    top = lod_needed(foveation)
    if top is not None:
        arrays, bvh, lod = _levels_of_detail(scene, arrays, bvh, foveation, rig, lod_levels, top)
    # --- end geometry level of detail ---
    args = (arrays, bvh, rig, angles, gaze, key, program_foveation, lod, shading)
    args = jax.tree.map(jnp.asarray, args)
    out, compile_s, render_s = run_compiled("foveated", foveated_stereo, args, static)
    image = np.asarray(out.image)
    stats = frame_stats(
        out.counts,
        out.bad_pixels,
        compile_s,
        render_s,
        width=image.shape[1],
        height=image.shape[0],
        spp=foveation.spp,
        stereo=True,
    )
    fstats = FoveationStats(
        primary_by_region=tuple(int(x) for x in out.primary_by_region),
        mandatory=int(out.mandatory),
        optional=int(out.optional),
        budget=budget,
        padding=int(out.padding),
        dropped=int(out.dropped),
        fovea_deg=float(foveation.fovea_deg),
        periphery_deg=float(foveation.periphery_deg),
    )
    if fstats.dropped:
        warnings.warn(
            f"render_foveated: {fstats.dropped:,} samples dropped (the ray budget of {budget:,} "
            f"slots was exceeded); blocks left without a traced sample were filled by pull-push",
            RuntimeWarning,
            stacklevel=2,
        )
    return FoveatedFrame(
        image=image,
        stats=stats,
        foveation=fstats,
        sample_mask=None if out.traced is None else np.asarray(out.traced),
        regions=None if out.region is None else np.asarray(out.region),
        eccentricity=None if out.eccentricity is None else np.asarray(out.eccentricity),
        outputs=out,
    )
