"""`fovjax.render_stereo`: the package's stereo entry point, above both the renderer and the
foveation layer (the renderer knows nothing of foveation)."""

from __future__ import annotations

import jax

from .foveate import DIAGNOSTICS, DiagnosticsLike, FoveatedFrame, Foveation, GazeLike, render_foveated
from .render import Frame, HeadPoseLike, RenderConfig, SceneArrays, StereoRig
from .render import render_stereo as _render_full
from .scene import Scene
from .trace import BVH


def render_stereo(
    scene: Scene | SceneArrays,
    rig: StereoRig | None = None,
    *,
    gaze: GazeLike | None = None,
    foveation: Foveation | None = None,
    head_pose: HeadPoseLike = None,
    spp: int | None = None,
    key: jax.Array | None = None,
    config: RenderConfig | None = None,
    bvh: BVH | None = None,
    diagnostics: DiagnosticsLike = DIAGNOSTICS,
) -> Frame | FoveatedFrame:
    """Render one stereo frame of the thesis's HMD: both eyes side by side, full or foveated.

    Without `foveation` and `gaze` this is the full render (`fovjax.render.render_stereo`); with
    either, only the samples the foveation selects are traced (`fovjax.foveate.render_foveated`).

    Args:
        scene: a `fovjax.Scene` (or the `SceneArrays` of one, with `bvh`).
        rig: the `fovjax.render.StereoRig`; default the thesis HMD at the scene's default
            viewpoint.
        gaze: per eye (x, y) in normalised display coordinates, ((lx, ly), (rx, ry)); default the
            display centres. Given alone, foveates with `Foveation(spp=spp)`.
        foveation: a `fovjax.foveate.Foveation`; its `spp` is the frame's.
        head_pose: (yaw, pitch, roll) degrees or a `fovjax.devices.HeadPose`; default straight.
        spp: samples per pixel, a perfect square (default 1; must agree with `foveation.spp`).
        key: the frame's `jax.random` key (jitter and sampling draws); None for cell centres and a
            fixed sampling pattern.
        config: the `fovjax.render.RenderConfig` (default `RenderConfig()`).
        bvh: a prebuilt BVH (default: built, or loaded from the disk cache).
        diagnostics: foveated frames only: which per-pixel outputs to return (names of
            `fovjax.foveate.DIAGNOSTICS`); each set is its own compiled program.

    An environment map for the rays that miss: `fovjax.render.render_stereo(envmap=)` or
    `fovjax.FoveatedRenderer(envmap=)`, or a `SceneArrays` made with one
    (`scene_arrays(scene, envmap=)`) as `scene`, with `bvh`.

    Returns:
        A `fovjax.render.Frame`, or a `fovjax.foveate.FoveatedFrame` when foveated (image,
        stats, per-region counts, sample mask, regions, eccentricity, debug view).

    Raises:
        TypeError: `scene` is not a `fovjax.Scene` or `SceneArrays` (a scene's name, say).
        ValueError: `spp` disagrees with `foveation.spp`, or a bad gaze, SPP or threshold;
            `fovjax.render.FrameTooLargeError` for a frame larger than the machine's free memory
            (`fovjax.render.frame_memory`; `FOVJAX_SIZE_CHECK=0` skips the check).

    Example:
        ```python
        scene = fovjax.scenes.cornell_box()
        rig = fovjax.StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=64, eye_height=48)
        full = fovjax.render_stereo(scene, rig, key=jax.random.key(0))
        fov = fovjax.render_stereo(scene, rig, gaze=((0.4, 0.5), (0.6, 0.5)),
                                   foveation=Foveation(fovea_deg=5, periphery_deg=10))
        ```
    """
    if not isinstance(scene, Scene | SceneArrays):
        raise TypeError(
            f"render_stereo: scene {scene!r} is not a fovjax.Scene (nor its SceneArrays); make one "
            "first, e.g. fovjax.scenes.cornell_box() or fovjax.load_scene(path)"
        )
    config = RenderConfig() if config is None else config
    if foveation is None and gaze is None:
        return _render_full(
            scene,
            rig,
            head_pose=head_pose,
            spp=1 if spp is None else spp,
            key=key,
            config=config,
            bvh=bvh,
        )
    if foveation is None:
        foveation = Foveation(spp=spp or 1)
    elif spp is not None and spp != foveation.spp:
        raise ValueError(f"render_stereo: spp={spp} disagrees with foveation.spp={foveation.spp}")
    return render_foveated(
        scene,
        rig,
        gaze=((0.5, 0.5), (0.5, 0.5)) if gaze is None else gaze,
        foveation=foveation,
        head_pose=head_pose,
        key=key,
        config=config,
        bvh=bvh,
        diagnostics=diagnostics,
    )
