"""Batches of stereo frames in one compiled program, sharded over `jax.devices()`: the eval
sweeps' entry points. The machinery is the renderer's (`fovjax.render.FrameBatch`,
`fovjax.render.render_stereo_batch`), the foveated batch `fovjax.foveate.FoveatedRenderer`'s
`render_batch`, so a batch is prepared exactly as a single frame is (budget, tiles, texture
mips, levels of detail): see `fovjax/render/_batch.py` for how frames are laid out over devices
and what batching costs."""

from __future__ import annotations

from collections.abc import Sequence

from ..render import PARTITIONS as PARTITIONS
from ..render import FrameBatch as FrameBatch
from ..render import frame_mesh as frame_mesh
from ..render import render_stereo_batch as render_stereo_batch


def render_foveated_batch(
    scene,
    rig=None,
    *,
    gazes: Sequence = (((0.5, 0.5), (0.5, 0.5)),),
    keys: Sequence | None = None,
    head_poses: Sequence | None = None,
    foveation=None,
    config=None,
    bvh=None,
    devices: Sequence | None = None,
    partition: str = "shard_map",
) -> FrameBatch:
    """Foveated stereo frames for a batch (`FoveatedRenderer.render_batch` of a renderer made from
    `scene`, `rig`, `foveation`, `config` and `bvh`; a frame loop that renders more than one
    batch makes the renderer once itself): one frame per entry of `gazes`, `keys` and
    `head_poses`, sharded over `devices`. Each frame equals `render_foveated` of the same gaze,
    key and head pose. The batch returns the sample mask, regions and eccentricity per frame."""
    from ..foveate import FoveatedRenderer

    renderer = FoveatedRenderer(
        scene, rig, foveation, config, bvh=bvh, diagnostics=("traced", "region", "eccentricity")
    )
    return renderer.render_batch(
        gazes, keys=keys, head_poses=head_poses, devices=devices, partition=partition
    )
