"""Batches of stereo frames in one compiled program, sharded over `jax.devices()` (the machinery
of `render_stereo_batch` here and of `fovjax.foveate.FoveatedRenderer.render_batch`).

A batch (gaze points × keys × head poses, one frame each) becomes one jitted program: the pure
frame function (the full render's `fovjax.render.stereo_program`, `jax.vmap`ped over
the frames; or `fovjax.foveate.foveated_stereo`, `lax.map`ped: one frame after another,
so each frame's chunk `lax.cond`s still skip what it does not trace), and the frame axis is
laid out over a one-axis mesh `Mesh(devices, ("frames",))` with `NamedSharding(mesh,
P("frames"))`; the scene, BVH, rig and foveation are replicated. `jax.shard_map` gives each
device its slice of frames; there is no scheduler of ours. (Left to jit's own
partitioner, `partition="auto"`, the vmapped loops' conditions become all-reduces over the
devices: each traversal step waits for every device, and all run until the batch's slowest
frame.) The batch is padded to a multiple
of the device count by repeating its last frame (the copies are traced, then dropped).

Under `jax.distributed` (several processes, possibly on several hosts) `jax.devices()` lists
every process's devices, every process runs the same call with the same batch, each computes its
own frames, and the results are gathered back to every process.

Costs of batching full frames with `vmap`, the price of one program for many frames:
- a `lax.while_loop` (BVH traversal) runs until the slowest frame of the device's slice is done,
  the finished frames idling along (with `partition="auto"`, of the whole batch);
- a `lax.cond` whose predicate differs per frame (the integrator skips reflection chunks with no
  live rays) becomes a `select`: every chunk of every frame is shaded;
- memory grows with the frames per device (every frame's buffers live at once).
Compiled through `fovjax.render.run_compiled` (the package's one compile path and cache). So a
sharded batch pays off when devices are really parallel (several GPUs, hosts, or CPU
devices with cores to spare); on one small CPU it can be slower than frames one by one
(`benchmarks/shard.py` measures it).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any, TypeAlias

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P
from jaxtyping import ArrayLike, Real

from ..scene import Scene
from ..trace import BVH
from ._arrays import SceneArrays, scene_arrays
from ._config import DEFAULT_CONFIG, RenderConfig
from ._envmap import EnvmapLike
from ._frame import run_compiled
from ._stereo import HeadPoseLike, StereoRig

FRAME_AXIS = "frames"
# A batch's keys: one per frame, each a seed of `jax.random.key` or a key array (or an array of
# keys), or None for pixel-cell centres; its head poses: one per frame ((B, 3) degrees or a
# sequence of head poses), or None for level.
KeysLike: TypeAlias = Sequence[int | np.integer | jax.Array] | jax.Array | None
HeadPosesLike: TypeAlias = Sequence[HeadPoseLike] | Real[ArrayLike, "B 3"] | None
# "shard_map": each device runs the vmapped frames of its own slice (its loops end with its own
# slowest frame); "auto": jit's partitioner splits the one vmapped program, and every batched
# loop condition becomes an all-reduce over the devices (each iteration synchronises them and
# all run until the slowest frame of the whole batch).
PARTITIONS = ("shard_map", "auto")


@dataclasses.dataclass(frozen=True)
class FrameBatch:
    """Frames rendered in one sharded program. Arrays have the frame axis first (the padding
    dropped): `images` (B, H, 2W, 3) linear RGB side by side, and ray counts per frame
    (`primary_rays`, `shadow_rays`, `reflection_rays`, `bad_samples`, each (B,)). Foveated
    batches also have `primary_by_region` (B, 3), `sample_mask` (B, 2, spp, H, W), `regions`
    (B, 2, H, W) and `eccentricity` (B, 2, H, W); full batches have `bad_pixels` (B,).
    `render_seconds` is the wall time of the whole batch (padding included), `compile_seconds` 0
    when the compiled program was reused; `devices` the number of devices the frames were
    spread over, `padded` the padded batch size, `sharding` the output images' sharding."""

    images: np.ndarray
    primary_rays: np.ndarray
    shadow_rays: np.ndarray
    reflection_rays: np.ndarray
    bad_samples: np.ndarray
    render_seconds: float
    compile_seconds: float
    devices: int
    padded: int
    sharding: object
    primary_by_region: np.ndarray | None = None
    sample_mask: np.ndarray | None = None
    regions: np.ndarray | None = None
    eccentricity: np.ndarray | None = None
    bad_pixels: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.images)

    @property
    def rays(self) -> np.ndarray:
        """Rays traced per frame (primary + shadow + reflection)."""
        return self.primary_rays + self.shadow_rays + self.reflection_rays

    @property
    def ms_per_frame(self) -> float:
        """Batch wall time over the frames asked for (the padding's cost is included)."""
        return 1000.0 * self.render_seconds / len(self)


def frame_mesh(devices: Sequence | None = None) -> Mesh:
    """The one-axis mesh ("frames",) over `devices` (default: `jax.devices()`, every process's)."""
    devices = list(jax.devices() if devices is None else devices)
    if not devices:
        raise ValueError("frame_mesh: no devices given")
    return Mesh(np.array(devices, dtype=object), (FRAME_AXIS,))


def batch_size(name_values: dict) -> int:
    """The common length of the per-frame inputs; a length-1 input is broadcast."""
    lengths = {name: len(v) for name, v in name_values.items() if v is not None}
    n = max(lengths.values(), default=1)
    for name, m in lengths.items():
        if m not in (1, n):
            raise ValueError(
                f"render batch: {name} has {m} entries but the batch has {n} frames "
                "(give one entry per frame, or one for all)"
            )
    if n < 1:
        raise ValueError("render batch: the batch is empty")
    return n


def per_frame(values, n: int, convert) -> np.ndarray:
    rows = [convert(v) for v in values]
    return np.stack(rows if len(rows) == n else rows * n)


def key_data(keys, n: int) -> tuple[np.ndarray, bool]:
    """(n, ...) raw key data and whether to jitter; None = pixel-cell centres (as
    `render_foveated(key=None)`). Integers are seeds of `jax.random.key`."""
    if keys is None:
        return np.broadcast_to(np.asarray(jax.random.key_data(jax.random.key(0))), (n, 2)).copy(), False

    def one(k):
        if isinstance(k, int | np.integer):
            k = jax.random.key(int(k))
        return np.asarray(jax.random.key_data(k))

    return per_frame(keys, n, one), True


def pad_frames(x: np.ndarray, padded: int) -> np.ndarray:
    return np.concatenate([x, np.repeat(x[-1:], padded - len(x), axis=0)]) if padded > len(x) else x


def global_arrays(tree, sharding: NamedSharding):
    """Host values as global arrays with `sharding`. Built from each process's own copy of the
    whole value (every process passes the same batch), so it works under `jax.distributed`."""

    def put(x):
        x = np.asarray(x)
        return jax.make_array_from_callback(x.shape, sharding, lambda index: x[index])

    return jax.tree.map(put, tree)


def to_host(tree):
    if jax.process_count() == 1:
        return jax.tree.map(np.asarray, tree)
    from jax.experimental import multihost_utils

    return multihost_utils.process_allgather(tree, tiled=True)


def run_sharded(
    entry: str, program, replicated: tuple, batched: tuple, static: dict, mesh: Mesh, n: int, partition: str
):
    """Pad the batched inputs to a multiple of the mesh size, run the (cached) compiled program,
    drop the padding. Returns (host outputs, padded size, compile s, render s, output sharding)."""
    devices = mesh.devices.size
    padded = -(-n // devices) * devices
    batched = tuple(pad_frames(x, padded) for x in batched)
    sharded = NamedSharding(mesh, P(FRAME_AXIS))
    whole = NamedSharding(mesh, P())
    # Canonical dtypes (float64 host values become float32, as jnp.asarray makes them).
    replicated = jax.tree.map(lambda x: np.asarray(jnp.asarray(x)), replicated)
    if partition not in PARTITIONS:
        raise ValueError(f"render batch: partition must be one of {PARTITIONS}, got {partition!r}")
    args = (*global_arrays(replicated, whole), *global_arrays(batched, sharded))
    shardings = (*(whole,) * len(replicated), *(sharded,) * len(batched))

    def jit(program):
        if partition == "shard_map":
            specs = (*(P(),) * len(replicated), *(P(FRAME_AXIS),) * len(batched))
            # No collectives inside, every output is per frame: the varying-axis type check
            # (which the renderer's loop carries, begun from replicated constants, would fail)
            # has nothing to protect.
            program = jax.shard_map(
                program, mesh=mesh, in_specs=specs, out_specs=P(FRAME_AXIS), check_vma=False
            )
        return jax.jit(program, in_shardings=shardings, out_shardings=sharded)

    # The one compile path of every entry point (`fovjax.render.run_compiled`); the static
    # settings are bound to the program (jit takes no keyword arguments with in_shardings).
    out, compile_s, render_s = run_compiled(
        f"batch:{entry}",
        program,
        args,
        static,
        jit=jit,
        key=(partition, tuple(d.id for d in mesh.devices.flat)),
    )
    out_sharding = jax.tree.leaves(out)[0].sharding
    host = jax.tree.map(lambda x: x[:n], to_host(out))
    return host, padded, compile_s, render_s, out_sharding


def head_poses_array(head_poses, n: int) -> np.ndarray:
    from ._stereo import head_pose_angles

    if head_poses is None:
        return np.zeros((n, 3), np.float32)
    return per_frame(head_poses, n, lambda p: np.asarray(head_pose_angles(p), np.float32))


def _full_program(scene, bvh, rig, head_poses, raw_keys, **static):
    from ._frame import _stereo_program

    def frame(head_pose, key):
        return _stereo_program(scene, bvh, rig, head_pose, jax.random.wrap_key_data(key), **static)

    return jax.vmap(frame)(head_poses, raw_keys)


def render_stereo_batch(
    scene: Scene | SceneArrays,
    rig: StereoRig | None = None,
    *,
    keys: KeysLike = None,
    head_poses: HeadPosesLike = None,
    spp: int = 1,
    config: RenderConfig | None = None,
    envmap: EnvmapLike = None,
    bvh: BVH | None = None,
    devices: Sequence[Any] | None = None,  # JAX devices
    partition: str = "shard_map",
) -> FrameBatch:
    """Full stereo frames for a batch of `keys` and/or `head_poses` (as
    `render_foveated_batch`), `vmap`ped and sharded over `devices`. Each frame equals
    `fovjax.render.render_stereo` of the same key and head pose."""
    from ._frame import _key_args, bvh_for

    config = config or DEFAULT_CONFIG
    _key_args(None, spp)  # validates spp
    n = batch_size({"keys": keys, "head_poses": head_poses})
    keys_raw, jitter = key_data(keys, n)
    poses = head_poses_array(head_poses, n)
    if rig is None:
        from ..scene import default_camera

        if not isinstance(scene, Scene):
            raise ValueError("render_stereo_batch: pass a rig when the scene is not a fovjax.Scene")
        rig = StereoRig.from_pose(default_camera(scene))
    bvh = bvh_for(scene, bvh)
    arrays = (
        scene
        if isinstance(scene, SceneArrays)
        else scene_arrays(scene, envmap=envmap, background=config.background)
    )
    static = {"spp": int(spp), "jitter": jitter, "config": config}
    (image, counts, bad_pixels), padded, compile_s, render_s, sharding = run_sharded(
        "full",
        _full_program,
        (arrays, bvh, rig),
        (poses, keys_raw),
        static,
        frame_mesh(devices),
        n,
        partition,
    )
    return FrameBatch(
        images=image,
        primary_rays=counts.primary,
        shadow_rays=counts.shadow,
        reflection_rays=counts.reflection,
        bad_samples=counts.bad,
        render_seconds=render_s,
        compile_seconds=compile_s,
        devices=sharding.num_devices,
        padded=padded,
        sharding=sharding,
        bad_pixels=bad_pixels,
    )
