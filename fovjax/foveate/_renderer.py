"""`FoveatedRenderer`: a foveated renderer prepared once, called per frame.

Everything a foveated frame needs besides the frame's own inputs is prepared when the renderer
is made, in one place: the scene's arrays (with texture mip pyramids when a region asks for a
texture level of detail), its BVH (with the native backend's scene behind it), the merged levels
of detail when a region asks for coarser geometry, the static ray budget, the fovea and grid
tiles, and the split of the foveation into the compiled program's static options and its
traced tables (`program_fidelity`). A frame then passes only gaze, head pose, key and, if they
change, the fovea and periphery thresholds: all traced values, so no frame after the first
compiles anything.

Every host entry point of a foveated frame goes through this object: `render_foveated` (one
frame), `fovjax.render_stereo(foveation=)`, `fovjax.eval.render_foveated_batch` (a batch sharded
over devices), the session loop, the viewer, `compare_thresholds` and the video study. The
compiled programs are kept by `fovjax.render.run_compiled` (keyed by the static configuration,
so two renderers of the same configuration share them).
"""

from __future__ import annotations

import copy
import dataclasses
import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Real

from ..render import (
    EnvmapLike,
    Frame,
    FrameBatch,
    FrameStats,
    HeadPoseLike,
    HeadPosesLike,
    KeysLike,
    RenderConfig,
    SceneArrays,
    StereoRig,
)
from ..scene import LODLevels, Scene
from ..trace import BVH
from ._budget import plan_budget
from ._config import (
    Foveation,
    GazeLike,
    check_gaze,
    max_region_spp,
    program_fidelity,
    region_spp,
    uses_texture_lod,
)
from ._frame import (
    DIAGNOSTICS,
    DiagnosticsLike,
    FoveatedOutputs,
    FoveationStats,
    diagnostics_tuple,
    region_view,
)
from ._lod import check_levels, lod_needed, prepare_levels
from ._methods import METHODS, FrameInputs

CENTRE_GAZE = ((0.5, 0.5), (0.5, 0.5))
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


def _pixels_per_degree(rig) -> float:
    """The display's pixels per degree at its centre, where a pixel subtends the most."""
    h = rig.eye_height
    return float((h / 2) / np.tan(np.deg2rad(float(rig.vfov_deg())) / 2) * np.pi / 180)


def fovea_tile(rig, foveation: Foveation, budget: int) -> tuple[int, int] | None:
    """Static (rows, cols) of the fovea tile: a square over `foveation.fovea_tile_deg` of
    eccentricity at the display's pixels per degree at its centre (plus 10%: they grow off
    centre), in whole 8-pixel packets, within the eye's image; None without a tile or when the
    budget is capped (a tile's samples must never be dropped)."""
    if foveation.fovea_tile_deg is None or not uncapped(rig, foveation, budget):
        return None
    h, w = rig.eye_height, rig.eye_width
    edge = 2 * int(np.ceil(1.1 * foveation.fovea_tile_deg * _pixels_per_degree(rig)))
    edge = -(-edge // 8) * 8
    return min(edge, h), min(edge, w)


@dataclasses.dataclass(frozen=True)
class FoveatedFrame:
    """A foveated stereo frame: the side-by-side `image` (H, 2W, 3) linear RGB, `stats` (the
    renderer's `FrameStats`: rays actually traced, times), `foveation` (`FoveationStats`), and
    the per-eye `sample_mask` (2, spp, H, W) of traced samples, `regions` (2, H, W int8: 0
    fovea, 1 periphery, 2 outside) and `eccentricity` (2, H, W, degrees): each None when the
    frame was rendered without it (`diagnostics`). `outputs`: the frame program's
    (`FoveatedOutputs`; its `prefill` is each pixel's mean of its traced samples)."""

    image: np.ndarray
    stats: FrameStats
    foveation: FoveationStats
    sample_mask: np.ndarray | None
    regions: np.ndarray | None
    eccentricity: np.ndarray | None
    outputs: FoveatedOutputs
    history: object = None  # a temporal method's history after this frame (else None)

    @property
    def debug_view(self) -> np.ndarray:
        """Regions and traced samples per eye (thesis figures 58-59), side by side (needs the
        diagnostics of `fovjax.foveate.DEBUG_VIEW_DIAGNOSTICS`)."""
        return np.asarray(region_view(self.outputs))

    def save(self, path: str | os.PathLike, **kwargs: Any) -> Path:
        """Save the image (see `fovjax.save_image`: PNG tone-mapped sRGB, EXR/HDR linear;
        `kwargs` are its options)."""
        from ..files import save_image

        return save_image(path, self.image, **kwargs)

    def eyes(self) -> tuple[np.ndarray, np.ndarray]:
        half = self.image.shape[1] // 2
        return self.image[:, :half], self.image[:, half:]


def _levels_of_detail(scene, arrays, bvh, foveation, rig, levels, top: int):
    """The merged scene arrays, BVH and `LODTables` of the levels `foveation` asks for; bad
    levels fail here, before any compile."""
    from ..scene import lod_levels as make_levels

    if not isinstance(scene, Scene):
        raise ValueError(
            "FoveatedRenderer: Fidelity.lod needs a fovjax.Scene (levels of detail are decimated from "
            f"its geometry), got {type(scene).__name__}"
        )
    if levels is None:
        levels = make_levels(scene)
    elif not isinstance(levels, LODLevels):
        raise ValueError(
            f"FoveatedRenderer: lod_levels must be a fovjax.scene.LODLevels, got {type(levels).__name__}"
        )
    if levels.scenes[0].content_hash != scene.content_hash:
        raise ValueError(
            "FoveatedRenderer: lod_levels were made from another scene (their level 0 is not this scene)"
        )
    check_levels(foveation, levels)
    return prepare_levels(scene, arrays, bvh, levels, top, _pixels_per_degree(rig))


class _History:
    """The history a temporal foveation method carries from frame to frame (None: none)."""

    def __init__(self):
        self.value = None


def _rig_shape(rig) -> tuple:
    """What the budget, the tiles and the levels of detail are planned from: a rig with other
    values here needs a new renderer (`with_rig` checks)."""
    offsets = tuple(np.asarray(rig.offsets, np.float32).reshape(-1).tolist())
    return rig.eye_width, rig.eye_height, rig.fov_axis, float(rig.fov_deg), offsets


def _batch_program(scene, bvh, rig, foveation, lod, shading, head_poses, gazes, raw_keys, *, options):
    def frame(xs):
        head_pose, gaze, key = xs
        key = jax.random.wrap_key_data(key)
        inputs = FrameInputs(scene, bvh, rig, head_pose, gaze, key, foveation, lod, shading)
        outputs, _, _ = foveation.method.frame(inputs, None, options=options)  # no history
        return outputs

    # One frame after another (lax.map), not vmap: a foveated frame skips the chunks of slots it
    # does not trace with lax.cond, which vmap would turn into a select that runs every chunk.
    return jax.lax.map(frame, (head_poses, gazes, raw_keys))


class FoveatedRenderer:
    """A foveated stereo renderer prepared once (see the module docstring) and called per frame.

    Args:
        scene: a `fovjax.Scene` (or its `SceneArrays` with `bvh`; levels of detail need a Scene).
        rig: the `StereoRig` (default: the thesis HMD at the scene's default viewpoint).
        foveation: the `Foveation` (default `Foveation()`); its thresholds are the frames'
            unless a frame passes its own.
        config: the `fovjax.render.RenderConfig` (default `RenderConfig()`).
        envmap: an environment map for rays that miss (a path or an array).
        bvh: a prebuilt BVH (default: built, or loaded from the disk cache).
        lod_levels: the scene's levels of detail (`fovjax.scene.lod_levels`) that `Fidelity.lod`
            indexes; None: `lod_levels(scene)` at its default ratios (cached on disk) when a region
            asks for a level.
        diagnostics: the per-pixel outputs besides the image a frame returns (names of
            `DIAGNOSTICS`; default all). A static choice: another set is another compiled program,
            and on a CPU every screen-sized output is fresh memory each frame, so a frame loop asks
            only for what it reads.

    Raises:
        TypeError: `foveation` is not a `Foveation`, `config` not a `RenderConfig`, `rig` not a
            `StereoRig`.
        ValueError: a bad level of detail, per-region fidelity or diagnostics name (before any
            compile); `fovjax.render.FrameTooLargeError`, a frame larger than the machine's
            free memory (`fovjax.render.frame_memory`; `FOVJAX_SIZE_CHECK=0` skips the check).

    Example:
        ```python
        renderer = fovjax.FoveatedRenderer(scene, rig, Foveation.thesis(0))
        for k, gaze in enumerate(gazes):
            frame = renderer.render(gaze, key=jax.random.key(k))  # compiles on the first frame only
        ```
    """

    def __init__(
        self,
        scene: Scene | SceneArrays,
        rig: StereoRig | None = None,
        foveation: Foveation | None = None,
        config: RenderConfig | None = None,
        *,
        envmap: EnvmapLike = None,
        bvh: BVH | None = None,
        lod_levels: LODLevels | None = None,
        diagnostics: DiagnosticsLike = DIAGNOSTICS,
    ) -> None:
        from ..render import scene_arrays
        from ..render.internal import bvh_for

        foveation = Foveation() if foveation is None else foveation
        config = RenderConfig() if config is None else config
        if not isinstance(foveation, Foveation):
            raise TypeError(
                f"FoveatedRenderer: foveation must be a Foveation, got {type(foveation).__name__}"
            )
        if not isinstance(config, RenderConfig):
            raise TypeError(f"FoveatedRenderer: config must be a RenderConfig, got {type(config).__name__}")
        if rig is None:
            from ..scene import default_camera

            if not isinstance(scene, Scene):
                raise ValueError("FoveatedRenderer: pass a rig when the scene is not a fovjax.Scene")
            rig = StereoRig.from_pose(default_camera(scene))
        elif not isinstance(rig, StereoRig):
            raise TypeError(f"FoveatedRenderer: rig must be a StereoRig, got {type(rig).__name__}")
        from ..render import check_frame_memory

        check_frame_memory(
            rig.eye_width,
            rig.eye_height,
            max_region_spp(foveation),
            foveated=True,
            config=config,
            where="FoveatedRenderer",
        )
        self.scene = scene
        # The full render's inputs (the scene without mips or merged levels, on the device once).
        self.bvh = bvh_for(scene, bvh)
        self.arrays = (
            scene
            if isinstance(scene, SceneArrays)
            else scene_arrays(scene, envmap=envmap, background=config.background)
        )
        self.config = config
        self.lod_levels = lod_levels
        self._full_inputs = jax.tree.map(jnp.asarray, (self.arrays, self.bvh))
        self._configure(rig, foveation, diagnostics)

    def _configure(self, rig: StereoRig, foveation: Foveation, diagnostics: DiagnosticsLike) -> None:
        """Everything that depends on the rig and the foveation (see the module docstring)."""
        from ..render.internal import with_texture_mips

        self.rig = rig
        self.foveation = foveation
        # A temporal method's history (`Foveation.method`): none yet. A holder, so that the
        # variants `with_rig` makes (the same renderer, moved) carry one history.
        self._history = _History()
        self.diagnostics = diagnostics_tuple(diagnostics, "FoveatedRenderer")
        # A bad per-region depth fails before any work; depths and shadow modes are traced tables.
        self._program_foveation, self._shading = program_fidelity(foveation, self.config)
        arrays, bvh = self.arrays, self.bvh
        if uses_texture_lod(foveation):  # mip pyramids on the host, once per texture
            arrays = with_texture_mips(arrays)
        self.budget = _budget_for(rig, np.zeros(3, np.float32), foveation)
        self.tile = fovea_tile(rig, foveation, self.budget)
        self.grid = (
            foveation.blocks[1] if foveation.grid_tile and uncapped(rig, foveation, self.budget) else None
        )
        lod = None
        top = lod_needed(foveation)
        if top is not None:
            arrays, bvh, lod = _levels_of_detail(
                self.scene, arrays, bvh, foveation, rig, self.lod_levels, top
            )
        # On the device once: a frame converts only its own inputs.
        self._scene_inputs = jax.tree.map(jnp.asarray, (arrays, bvh, rig))
        self._tables = jax.tree.map(jnp.asarray, (lod, self._shading))

    # ---- variants sharing the prepared scene ----

    def with_foveation(
        self, foveation: Foveation, *, diagnostics: DiagnosticsLike | None = None
    ) -> FoveatedRenderer:
        """This renderer with another foveation (and diagnostics): the scene's arrays and BVH are
        shared, the rest prepared again (a foveation of the same static options reuses the
        compiled program)."""
        if not isinstance(foveation, Foveation):
            raise TypeError(f"with_foveation: foveation must be a Foveation, got {type(foveation).__name__}")
        other = copy.copy(self)
        other._configure(self.rig, foveation, self.diagnostics if diagnostics is None else diagnostics)
        return other

    def reset_history(self) -> None:
        """Forget the history a temporal method (`Weier2016`, `Patney2016`) carries from frame
        to frame: the next frame starts from none (for the thesis's method, nothing changes)."""
        self._history.value = None

    def with_rig(self, rig: StereoRig) -> FoveatedRenderer:
        """This renderer with the rig moved (its position, rotation, IPD, toe-out: traced values);
        the eye size, field of view and offsets must be this rig's (the budget, tiles and levels
        of detail are planned from them). A temporal method's history is shared with this
        renderer: frames of either continue it."""
        if _rig_shape(rig) != _rig_shape(self.rig):
            raise ValueError(
                f"with_rig: the rig's (eye width, eye height, fov axis, fov, offsets) {_rig_shape(rig)} "
                f"differ from the renderer's {_rig_shape(self.rig)}; make a new FoveatedRenderer"
            )
        other = copy.copy(self)
        arrays, bvh, _ = self._scene_inputs
        other.rig = rig
        other._scene_inputs = (arrays, bvh, jax.tree.map(jnp.asarray, rig))
        return other

    # ---- frames ----

    def _static(self, jitter: bool, diagnostics: tuple[str, ...]) -> dict:
        """The frame program's static arguments (`run_compiled`'s `static`): the method's
        `FrameOptions` for this renderer."""
        method = self.foveation.method
        return {"options": method.frame_options(self, jitter=jitter, diagnostics=diagnostics)}

    def _frame_foveation(self, thresholds) -> Foveation:
        """The program's foveation with the frame's (fovea, periphery) thresholds (traced)."""
        if thresholds is None:
            return self._program_foveation
        fovea, periphery = thresholds
        # Foveation's own checks: fovea <= periphery <= max_periphery_deg, finite angles.
        return dataclasses.replace(self._program_foveation, fovea_deg=fovea, periphery_deg=periphery)

    def render(
        self,
        gaze: GazeLike = CENTRE_GAZE,
        *,
        head_pose: HeadPoseLike = None,
        key: jax.Array | None = None,
        thresholds: tuple[float, float] | None = None,
        diagnostics: DiagnosticsLike | None = None,
        reset: bool = False,
    ) -> FoveatedFrame:
        """One foveated stereo frame.

        Args:
            gaze: per eye (x, y) in normalised display coordinates, (0, 0) the top-left of each
                eye's display. NaN or off-screen gaze is rejected (the tracking layer decides
                fallbacks).
            head_pose: (yaw, pitch, roll) degrees or a `fovjax.devices.HeadPose`.
            key: the frame's PRNG key (sub-pixel jitter and sampling draws); None renders
                pixel-cell centres and a fixed sampling pattern.
            thresholds: this frame's (fovea_deg, periphery_deg) (default the foveation's);
                traced, within `Foveation.max_periphery_deg`.
            diagnostics: this frame's per-pixel outputs (default the renderer's).
            reset: a method that keeps a history of earlier frames (`Weier2016`,
                `Patney2016`) starts this frame from none (a scene change, a tracking loss);
                the renderer keeps each frame's history for the next (`reset_history` clears
                it too).

        Returns:
            The `FoveatedFrame`.

        Raises:
            TypeError: `key` is not a JAX key array.
            ValueError: a bad gaze (naming the eye and the value) or thresholds.
        """
        from ..render import head_pose_angles
        from ..render.internal import frame_stats, run_compiled

        gaze = check_gaze(gaze)
        if key is not None and not isinstance(key, jax.Array):
            raise TypeError(f"FoveatedRenderer.render: key must be a jax.random key or None, got {key!r}")
        diagnostics = self.diagnostics if diagnostics is None else diagnostics_tuple(diagnostics)
        foveation = self._frame_foveation(thresholds)
        jitter = key is not None
        key = key if jitter else jax.random.key(0)
        angles = np.asarray(head_pose_angles(head_pose), np.float32)
        arrays, bvh, rig = self._scene_inputs
        lod, shading = self._tables
        method = foveation.method
        history = self._history.value
        if reset or history is None:  # a temporal method's reset (None: a method without history)
            history = jax.tree.map(jnp.asarray, method.empty_history(self.rig.eye_height, self.rig.eye_width))
        traced = jax.tree.map(jnp.asarray, (angles, gaze, key, foveation))  # this frame's values
        inputs = FrameInputs(arrays, bvh, rig, traced[0], traced[1], traced[2], traced[3], lod, shading)
        (out, reused, history), compile_s, render_s = run_compiled(
            method.entry, method.frame, (inputs, history), self._static(jitter, diagnostics)
        )
        if method.temporal:
            self._history.value = history
        reused = 0 if reused is None else int(np.asarray(reused))
        image = np.asarray(out.image)
        stats = frame_stats(
            out.counts,
            out.bad_pixels,
            compile_s,
            render_s,
            width=image.shape[1],
            height=image.shape[0],
            spp=self.foveation.spp,
            stereo=True,
        )
        fovea, periphery, outside = (int(x) for x in out.primary_by_region)
        fstats = FoveationStats(
            primary_by_region=(fovea, periphery, outside),
            mandatory=int(out.mandatory),
            optional=int(out.optional),
            budget=self.budget,
            padding=int(out.padding),
            dropped=int(out.dropped),
            fovea_deg=float(foveation.fovea_deg),
            periphery_deg=float(foveation.periphery_deg),
            reused=reused,
        )
        if fstats.dropped:
            warnings.warn(
                f"render_foveated: {fstats.dropped:,} samples dropped (the ray budget of {self.budget:,} "
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
            history=self._history.value,
        )

    def render_full(self, *, head_pose: HeadPoseLike = None, key: jax.Array | None = None) -> Frame:
        """The full (unfoveated) stereo frame of the same scene, rig and render config at the
        foveation's samples per pixel: the reference a foveated frame is measured against
        (`fovjax.render.render_stereo`, a `fovjax.render.Frame`)."""
        from ..render import render_stereo

        arrays, bvh = self._full_inputs
        return render_stereo(
            arrays,
            self.rig,
            head_pose=head_pose,
            spp=self.foveation.spp,
            key=key,
            config=self.config,
            bvh=bvh,
        )

    def render_full_batch(
        self,
        *,
        keys: KeysLike = None,
        head_poses: HeadPosesLike = None,
        devices: Sequence[Any] | None = None,  # JAX devices
        partition: str = "shard_map",
    ) -> FrameBatch:
        """The full stereo frames of a batch (`fovjax.render.render_stereo_batch` of this
        renderer's scene, rig, render config and samples per pixel): the references of
        `render_batch`'s frames."""
        from ..render import render_stereo_batch

        return render_stereo_batch(
            self.arrays,
            self.rig,
            keys=keys,
            head_poses=head_poses,
            spp=self.foveation.spp,
            config=self.config,
            bvh=self.bvh,
            devices=devices,
            partition=partition,
        )

    def render_batch(
        self,
        gazes: Sequence[GazeLike] | Real[ArrayLike, "B 2 2"] | Real[ArrayLike, "B 2"] = (CENTRE_GAZE,),
        *,
        keys: KeysLike = None,
        head_poses: HeadPosesLike = None,
        devices: Sequence[Any] | None = None,  # JAX devices
        partition: str = "shard_map",
    ) -> FrameBatch:
        """Foveated stereo frames for a batch in one compiled program, sharded over `devices`
        (default `jax.devices()`): one frame per entry of `gazes` (each ((lx, ly), (rx, ry)) or
        (x, y) for both eyes), `keys` (ints seed `jax.random.key`, or key arrays; None:
        pixel-cell centres) and `head_poses` ((yaw, pitch, roll) degrees; None: level), all of
        one length or of length 1 (broadcast). Each frame equals `render` of the same gaze, key
        and head pose (budget, tiles and levels of detail included). `partition`: "shard_map"
        (each device loops over its own frames) or "auto" (see `fovjax.render.PARTITIONS`).
        Returns a `fovjax.render.FrameBatch` (its per-pixel arrays None where the renderer's
        diagnostics leave them out; the pre-fill means are never returned)."""
        from ..render import frame_mesh
        from ..render import internal as render_internal

        method = self.foveation.method
        if not method.batches:
            batched = [name for name, cls in METHODS.items() if cls.batches]
            raise ValueError(
                f"render_batch: foveation method {method.name!r} renders frames one after another "
                f"(FoveatedRenderer.render); batches are for the methods {batched}"
            )
        n = render_internal.batch_size({"gazes": gazes, "keys": keys, "head_poses": head_poses})

        def gaze_of(g):
            g = np.asarray(g, np.float64)
            return check_gaze(np.broadcast_to(g, (2, 2)) if g.shape == (2,) else g, "gazes")

        gaze = render_internal.per_frame(gazes, n, gaze_of)
        raw_keys, jitter = render_internal.key_data(keys, n)
        poses = render_internal.head_poses_array(head_poses, n)
        diagnostics = tuple(d for d in self.diagnostics if d != "prefill")
        arrays, bvh, rig = self._scene_inputs
        lod, shading = self._tables
        out, padded, compile_s, render_s, sharding = render_internal.run_sharded(
            method.entry,
            _batch_program,
            (arrays, bvh, rig, self._program_foveation, lod, shading),
            (poses, gaze, raw_keys),
            self._static(jitter, diagnostics),
            frame_mesh(devices),
            n,
            partition,
        )
        return FrameBatch(
            images=out.image,
            primary_rays=out.counts.primary,
            shadow_rays=out.counts.shadow,
            reflection_rays=out.counts.reflection,
            bad_samples=out.counts.bad,
            render_seconds=render_s,
            compile_seconds=compile_s,
            devices=sharding.num_devices,
            padded=padded,
            sharding=sharding,
            primary_by_region=out.primary_by_region,
            sample_mask=out.traced,
            regions=out.region,
            eccentricity=out.eccentricity,
        )
