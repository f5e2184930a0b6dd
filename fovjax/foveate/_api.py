"""Host-side entry point of foveated rendering: compiled once per configuration."""

from __future__ import annotations

import collections
import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

from ._budget import plan_budget
from ._config import Foveation, check_gaze
from ._frame import FoveatedOutputs, FoveationStats, foveated_stereo, region_view

_COMPILED: dict = {}
TRACE_COUNTS: collections.Counter = collections.Counter()
_BUDGETS: dict = {}


def _program(scene, bvh, rig, head_pose, gaze, key, foveation, **static):
    TRACE_COUNTS["foveated"] += 1
    return foveated_stereo(scene, bvh, rig, head_pose, gaze, key, foveation=foveation, **static)


def _signature(args) -> tuple:
    leaves, treedef = jax.tree.flatten(args)
    return treedef, tuple((x.shape, x.dtype, getattr(x, "weak_type", False)) for x in leaves)


def _budget_for(rig, head_pose, foveation: Foveation) -> int:
    """Static budget of both eyes (cached per rig intrinsics and configuration)."""
    key = (
        rig.eye_width,
        rig.eye_height,
        float(rig.fov_deg),
        rig.fov_axis,
        tuple(np.asarray(rig.offsets).reshape(-1).tolist()),
        foveation.fovea_deg,
        foveation.periphery_deg,
        foveation.spp,
        foveation.blocks,
        foveation.rule,
        foveation.eccentricity,
        foveation.eye_display_mm,
        foveation.pixel_pitch_mm,
        foveation.ray_budget,
        # Any acuity callable: scalar parameters or arrays (a tabulated curve, a batch of fits).
        tuple(
            (np.shape(x), tuple(np.asarray(x).reshape(-1).tolist()))
            for x in jax.tree.leaves(foveation.acuity)
        ),
        type(foveation.acuity).__name__,
    )
    budget = _BUDGETS.get(key)
    if budget is None:
        budget = _BUDGETS[key] = sum(plan_budget(cam, foveation) for cam in rig.eye_cameras(head_pose))
    return budget


@dataclasses.dataclass(frozen=True)
class FoveatedFrame:
    """A foveated stereo frame: the side-by-side `image` (H, 2W, 3) linear RGB, `stats` (the
    renderer's `FrameStats`: rays actually traced, times), `foveation` (`FoveationStats`), and
    the per-eye `sample_mask` (2, spp, H, W) of traced samples, `regions` (2, H, W: 0 fovea,
    1 periphery, 2 outside) and `eccentricity` (2, H, W, degrees)."""

    image: np.ndarray
    stats: object
    foveation: FoveationStats
    sample_mask: np.ndarray
    regions: np.ndarray
    eccentricity: np.ndarray
    outputs: FoveatedOutputs

    @property
    def debug_view(self) -> np.ndarray:
        """Regions and traced samples per eye (thesis figures 58-59), side by side."""
        return np.asarray(region_view(self.outputs))

    def save(self, path, **kwargs):
        from .._image import save_image

        return save_image(path, self.image, **kwargs)

    def eyes(self):
        half = self.image.shape[1] // 2
        return self.image[:, :half], self.image[:, half:]


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
) -> FoveatedFrame:
    """Render a foveated stereo frame (see `fovjax.foveate._frame`). `gaze`: per eye (x, y) in
    normalised display coordinates, (0, 0) the top-left of each eye's display; NaN or
    off-screen gaze is rejected here (the tracking layer decides fallbacks). `key`: the frame's
    PRNG key (sub-pixel jitter and sampling draws); None renders pixel-cell centres and a fixed
    sampling pattern. Compiled once per configuration (resolution, spp, foveation thresholds,
    render config, scene array shapes); a new gaze, head pose or key reuses it."""
    from ..render import RayCounts, StereoRig
    from ..render._arrays import SceneArrays, scene_arrays
    from ..render._config import DEFAULT_CONFIG
    from ..render._frame import FrameStats, _bvh_for
    from ..render._stereo import head_pose_angles

    foveation = foveation or Foveation()
    config = config or DEFAULT_CONFIG
    # Compacted rays are scattered over the screen: one-by-one traversal beats packets there.
    config = dataclasses.replace(config, packet=None)
    gaze = check_gaze(gaze)
    if rig is None:
        from ..scenes import default_camera

        rig = StereoRig.from_pose(default_camera(scene))
    bvh = _bvh_for(scene, bvh)
    arrays = (
        scene
        if isinstance(scene, SceneArrays)
        else scene_arrays(scene, envmap=envmap, background=config.background)
    )
    jitter = key is not None
    key = key if jitter else jax.random.key(0)
    angles = np.asarray(head_pose_angles(head_pose), np.float32)
    budget = _budget_for(rig, angles, foveation)
    # The foveation config is an argument: its thresholds and options are static fields (part of
    # the tree structure), its acuity model's parameters arrays (a refitted model recompiles
    # nothing).
    static = {"spp": foveation.spp, "jitter": jitter, "config": config, "budget": budget}
    args = jax.tree.map(jnp.asarray, (arrays, bvh, rig, angles, gaze, key, foveation))
    cache_key = (tuple(static.items()), _signature(args))
    compiled = _COMPILED.get(cache_key)
    compile_s = 0.0
    if compiled is None:
        t0 = time.perf_counter()
        compiled = jax.jit(_program, static_argnames=tuple(static)).lower(*args, **static).compile()
        compile_s = time.perf_counter() - t0
        _COMPILED[cache_key] = compiled
    t0 = time.perf_counter()
    out: FoveatedOutputs = jax.block_until_ready(compiled(*args))
    render_s = time.perf_counter() - t0

    counts = RayCounts(*(int(c) for c in out.counts))
    image = np.asarray(out.image)
    stats = FrameStats(
        primary_rays=counts.primary,
        shadow_rays=counts.shadow,
        reflection_rays=counts.reflection,
        bad_samples=counts.bad,
        bad_pixels=0,
        compile_seconds=compile_s,
        render_seconds=render_s,
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
        fovea_deg=foveation.fovea_deg,
        periphery_deg=foveation.periphery_deg,
    )
    return FoveatedFrame(
        image=image,
        stats=stats,
        foveation=fstats,
        sample_mask=np.asarray(out.traced),
        regions=np.asarray(out.region),
        eccentricity=np.asarray(out.eccentricity),
        outputs=out,
    )
