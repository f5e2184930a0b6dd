"""`fovjax.render_stereo`: the package's stereo entry point, above both the renderer and the
foveation layer (the renderer knows nothing of foveation)."""

from __future__ import annotations

from .foveate import DIAGNOSTICS, Foveation, render_foveated
from .render import RenderConfig
from .render import render_stereo as _render_full


def render_stereo(
    scene,
    rig=None,
    *,
    gaze=None,
    foveation=None,
    head_pose=None,
    spp: int | None = None,
    key=None,
    config: RenderConfig | None = None,
    envmap=None,
    bvh=None,
    diagnostics=DIAGNOSTICS,
):
    """Render both eyes of `rig` (default: the thesis HMD at the scene's default viewpoint)
    side by side for a head pose ((yaw, pitch, roll) degrees or a `fovjax.devices.HeadPose`);
    other arguments as `fovjax.render.render`. Returns a `fovjax.render.Frame`.

    Foveated: with `foveation=` (a `fovjax.foveate.Foveation`; its `spp` is the frame's) and/or
    `gaze=((lx, ly), (rx, ry))` (normalised display coordinates; default the centres), the frame
    traces only the samples the foveation selects and returns a `fovjax.foveate.FoveatedFrame`
    (image, stats, per-region counts, sample mask, debug view; `diagnostics` chooses its
    per-pixel outputs); see `fovjax.foveate.render_foveated`."""
    config = RenderConfig() if config is None else config
    if foveation is None and gaze is None:
        return _render_full(
            scene,
            rig,
            head_pose=head_pose,
            spp=1 if spp is None else spp,
            key=key,
            config=config,
            envmap=envmap,
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
        envmap=envmap,
        bvh=bvh,
        diagnostics=diagnostics,
    )
