"""Frames: sample rays → `radiance` → box filter, compiled once per configuration.

- `render_image` / `render_stereo_image`: pure and jittable, for `jax.grad` (scene arrays, BVH,
  camera or rig, pose and key in; the linear image out).
- `render` / `render_stereo`: the host entry points. They return a `Frame` (the image as NumPy
  and statistics: rays traced by kind, bad pixels, compile and render seconds) and keep one
  compiled program per configuration, keyed by everything static (resolution, spp, jitter or
  not, `RenderConfig`, the array shapes of scene, BVH and camera), so a new head pose, gaze,
  key, light colour or scene of the same shapes reuses it.
"""

from __future__ import annotations

import collections
import dataclasses
import os
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .. import _environment
from ..native.internal import on_platforms
from ..scene import Camera, Scene, pixel_sample_positions, stratified_offsets
from ..scene.internal import key_words, per_sample_threefry
from ..trace import BVH, build_bvh
from ._arrays import SceneArrays, scene_arrays
from ._config import DEFAULT_CONFIG, RenderConfig
from ._envmap import ColorLike, EnvmapLike
from ._integrator import RayCounts, radiance, scene_scale
from ._memory import check_frame_memory
from ._native import camera_rows, integrator_options, integrator_plan, native_camera_frame, whitted_operands
from ._stereo import HeadPoseLike, StereoRig, head_pose_angles


def resolve(
    rgb: Float[Array, "*lead spp H W 3"],
    bad: Bool[Array, "*lead spp H W"] | None = None,
    *,
    bad_color: ColorLike = (1.0, 0.0, 1.0),
) -> tuple[Float[Array, "*lead H W 3"], Bool[Array, "*lead H W"]]:
    """Box-filter the samples of each pixel (axis -4 of `rgb`) into the pixel. A pixel with any
    bad sample is `bad_color` outright (the thesis's exception program paints the pixel).
    Returns (image, bad pixels)."""
    # Sums written out over the (static) sample axis: see `_vec` on short reductions.
    spp = rgb.shape[-4]
    image = rgb[..., 0, :, :, :]
    for s in range(1, spp):
        image = image + rgb[..., s, :, :, :]
    image = image / spp
    if bad is None:
        return image, jnp.zeros(image.shape[:-1], bool)
    bad_pixel = bad[..., 0, :, :]
    for s in range(1, spp):
        bad_pixel = bad_pixel | bad[..., s, :, :]
    return jnp.where(bad_pixel[..., None], jnp.asarray(bad_color, image.dtype), image), bad_pixel


def side_by_side(eyes: Float[Array, "2 H W 3"]) -> Float[Array, "H 2*W 3"]:
    """The left eye's image in the left half, the right eye's in the right half."""
    return jnp.concatenate([eyes[0], eyes[1]], axis=1)


def _as_arrays(scene) -> SceneArrays:
    return scene if isinstance(scene, SceneArrays) else scene_arrays(scene)


def sample_radiance(scene: SceneArrays, bvh: BVH, origins, directions, *, config: RenderConfig):
    """`radiance` of per-sample primary rays (..., S, H, W, 3), S = n² samples per pixel, traced
    as one image of the sub-samples n times the size: sample (sx, sy) of pixel (x, y) at
    (n·y + sy, n·x + sx). A packet's tile then holds neighbouring pixels' samples, as a
    frame of one sample per pixel at that size does, rather than pixels n apart in one sample's
    image (2 x 640x512 at SPP 4 on the atrium: a tenth to a sixth faster). The results come back
    in the sample layout: the same samples, summed per pixel in the same order."""
    *lead, spp, h, w, _ = jnp.broadcast_shapes(jnp.shape(origins), jnp.shape(directions))
    n = int(round(spp**0.5))
    if n == 1 or not isinstance(config.packet, tuple):
        return radiance(scene, bvh, origins, directions, config=config)
    lead = tuple(lead)
    k = len(lead)

    def as_image(x):  # (*lead, n·n, H, W, C) -> (*lead, H·n, W·n, C)
        c = x.shape[-1]
        x = jnp.broadcast_to(x, (*lead, spp, h, w, c)).reshape(*lead, n, n, h, w, c)
        x = x.transpose(*range(k), k + 2, k, k + 3, k + 1, k + 4)
        return x.reshape(*lead, h * n, w * n, c)

    def as_samples(x):  # the inverse
        c = x.shape[-1]
        x = x.reshape(*lead, h, n, w, n, c).transpose(*range(k), k + 1, k + 3, k, k + 2, k + 4)
        return x.reshape(*lead, spp, h, w, c)

    result = radiance(scene, bvh, as_image(origins), as_image(directions), config=config)
    return result._replace(rgb=as_samples(result.rgb), bad=as_samples(result.bad[..., None])[..., 0])


def render_image(
    scene: SceneArrays | Scene,
    bvh: BVH,
    camera: Camera,
    *,
    spp: int = 1,
    key: jax.Array | None = None,
    config: RenderConfig = DEFAULT_CONFIG,
) -> Float[Array, "H W 3"]:
    """One camera's linear-RGB image: `camera.sample_rays(spp, key)` → `radiance` → `resolve`
    (`camera_frame`). Pure; jit it, or take `jax.grad` of a loss of it."""
    return camera_frame(_as_arrays(scene), bvh, (camera,), key, spp=spp, config=config)[0]


def render_stereo_image(
    scene: SceneArrays | Scene,
    bvh: BVH,
    rig: StereoRig,
    head_pose: HeadPoseLike = None,
    *,
    spp: int = 1,
    key: jax.Array | None = None,
    config: RenderConfig = DEFAULT_CONFIG,
) -> Float[Array, "H W2 3"]:
    """The side-by-side stereo image (linear RGB) for a head pose. Pure; jittable.

    The width W2 is twice the rig's eye width (no argument carries the eye width as an array
    axis, so the annotation cannot say `2*W`: jaxtyping rejects an axis it has not bound)."""
    cameras = rig.eye_cameras(head_pose)
    return camera_frame(_as_arrays(scene), bvh, cameras, key, spp=spp, config=config)[0]


# ---- host side: compiled programs, frames --------------------------------------------------

# Every compiled program of the package (frames, foveated frames, eval's batches) by (entry,
# static arguments, extra key, argument structure and shapes); and how many times each entry
# has been traced (a retrace means a recompile).
_COMPILED: dict = {}
TRACE_COUNTS: collections.Counter = collections.Counter()
# Called as hook(entry, jitted program, args) before a new program compiles (tests use it to
# lower every frame program for another platform too).
LOWERING_HOOKS: list = []


# XLA:CPU emits fused loops two ways: its newer fusion emitters (XLA's default) and its loop
# emitters. Full frames compile with loop emitters, which ran them faster and compiled them
# faster (`benchmarks/compile_options.py`); the thesis's foveated frame keeps the fusion
# emitters, which run its screen passes (the JAX selection's threefry draws) faster. The two
# round some sums differently: images differ in the last bits. The option is XLA:CPU's: a
# program compiled for another platform gets none (XLA's GPU compiler refuses an option it does
# not know). FOVJAX_XLA_EMITTERS=loop or =fusion makes every frame program compile with those
# (to measure them), read when a program compiles.
LOOP_EMITTERS = {"xla_cpu_use_fusion_emitters": False}
FUSION_EMITTER_ENTRIES = ("foveated", "batch:foveated")


def frame_compiler_options(entry: str, platform: str = "cpu") -> dict[str, Any]:
    """The XLA compiler options the frame program of `entry` ("stereo", "foveated", "batch:full",
    ...) compiles with for `platform` ("cpu", "gpu", ...): on a CPU `LOOP_EMITTERS`, except for
    the thesis's foveated frame (`FUSION_EMITTER_ENTRIES`: XLA's default); FOVJAX_XLA_EMITTERS=
    loop or fusion for every program; none on other platforms."""
    choice = _environment.choice("FOVJAX_XLA_EMITTERS")
    if choice == "auto":
        choice = "fusion" if entry in FUSION_EMITTER_ENTRIES else "loop"
    return dict(LOOP_EMITTERS) if choice == "loop" and platform == "cpu" else {}


def _program_platform(args) -> str:
    """The platform a program of `args` compiles for: that of the first placed array among them
    (jit runs where its committed arguments are), else JAX's default backend."""
    for leaf in jax.tree.leaves(args):
        if isinstance(leaf, jax.Array):
            try:
                return next(iter(leaf.devices())).platform
            except (RuntimeError, StopIteration):  # deleted or not yet placed: the default
                break
    return jax.default_backend()


def compile_cache_info() -> dict[str, int]:
    """Compiled programs held per entry point ("mono", "stereo", "foveated", "batch:...")."""
    counts = collections.Counter(key[0] for key in _COMPILED)
    return dict(counts)


def clear_compile_cache() -> None:
    """Forget every compiled program (all entry points) and the trace counts."""
    _COMPILED.clear()
    TRACE_COUNTS.clear()


def _signature(args) -> tuple:
    leaves, treedef = jax.tree.flatten(args)
    return treedef, tuple((np.shape(x), _dtype(x), getattr(x, "weak_type", False)) for x in leaves)


def _dtype(x):
    dtype = getattr(x, "dtype", None)
    return np.asarray(x).dtype if dtype is None else dtype


def run_compiled(entry: str, program, args: tuple, static: dict | None = None, *, jit=None, key=()):
    """Run `program(*args, **static)`, compiling it first if this configuration is new: the one
    compile path of every host entry point. The cache key is the entry, the static arguments,
    `key` (anything else the program depends on, e.g. devices) and the structure, shapes and
    dtypes of `args`, so new values of the same shapes (gaze, pose, key, thresholds) reuse it.
    `jit`: how to jit the program with its static arguments bound (default `jax.jit`; eval's
    batches pass their shardings). Returns (outputs, compile seconds (0 when reused), run
    seconds)."""
    static = dict(static or {})
    cache_key = (entry, tuple(sorted(static.items(), key=lambda kv: kv[0])), key, _signature(args))
    compiled = _COMPILED.get(cache_key)
    compile_seconds = 0.0
    if compiled is None:

        def counted(*a):
            TRACE_COUNTS[entry] += 1
            return program(*a, **static)

        # First: a bad setting is said before any work.
        options = frame_compiler_options(entry, _program_platform(args))
        jitted = (jit or jax.jit)(counted)
        for hook in LOWERING_HOOKS:  # e.g. the test that exports every frame program for CUDA
            hook(entry, jitted, args)
        start = time.perf_counter()
        compiled = jitted.lower(*args).compile(compiler_options=options or None)
        compile_seconds = time.perf_counter() - start
        _COMPILED[cache_key] = compiled
    start = time.perf_counter()
    outputs = jax.block_until_ready(compiled(*args))
    return outputs, compile_seconds, time.perf_counter() - start


def camera_frame_why_not(config: RenderConfig, key, width: int, height: int, spp: int) -> str:
    """Why `camera_frame` cannot run in the native camera frame handler (`render/_frame.cc`), or
    "" where it can: the native integrator on (`integrator_plan`), sub-pixel draws it reproduces
    (none, or JAX's threefry2x32 per sample: `per_sample_threefry`), at most 256 samples per pixel
    and 32-bit counters."""
    plan = integrator_plan(config)
    if not plan.cpu:
        return f"the native integrator is off ({plan.reason})"
    if spp > 256:
        return f"spp {spp} is above the handler's 256 (16 x 16 sub-samples)"
    if 2 * spp * width * height >= 2**32:
        return f"2 x {spp} x {height} x {width} draws do not fit the handler's 32-bit counters"
    if key is not None and not per_sample_threefry(key):
        return "the frame key's sub-pixel draws are not the default threefry2x32 the handler reproduces"
    return ""


def _frame_of_rays(scene, bvh, cameras, key, *, spp, config):
    """`camera_frame` in JAX: the rays (`Camera.sample_rays`, or for two cameras
    `stereo_sample_rays`' stack), `sample_radiance`, `resolve` and `side_by_side`."""
    if len(cameras) == 1:
        o, d, _ = cameras[0].sample_rays(spp, key)
    else:
        xy = pixel_sample_positions(cameras[0].width, cameras[0].height, spp, key)
        d = jnp.stack([camera.ray_directions(xy) for camera in cameras])
        positions = jnp.stack([jnp.asarray(camera.position, jnp.float32) for camera in cameras])
        o = jnp.broadcast_to(positions[:, None, None, None, :], d.shape)
    result = sample_radiance(scene, bvh, o, d, config=config)
    eyes, bad_pixels = resolve(result.rgb, result.bad, bad_color=config.bad_color)
    image = eyes if len(cameras) == 1 else side_by_side(eyes)
    return image, result.counts, jnp.sum(bad_pixels, dtype=jnp.int32)


def camera_frame(scene: SceneArrays, bvh: BVH, cameras: tuple[Camera, ...], key, *, spp: int, config):
    """The full frame of one camera or of a stereo pair's two (their images side by side): `spp`
    sub-samples per pixel (jittered from `key`, cell centres without one), their radiance, each
    pixel's mean. Returns (image, `RayCounts`, bad pixels). On a CPU with the native integrator
    (`camera_frame_why_not`), one call of the camera frame handler makes the rays, traces them
    and filters the image; elsewhere `_frame_of_rays` (its oracle), whose integrator takes the
    native side where it can. Derivatives are always `_frame_of_rays`' (the replay of the paths
    its native forward stores), and so is the primal a JVP returns (`value_and_grad`'s value):
    the handler's image to float rounding (its rays round differently from XLA's). Pure;
    jittable."""
    width, height = cameras[0].width, cameras[0].height
    if any((c.width, c.height) != (width, height) for c in cameras) or len(cameras) not in (1, 2):
        raise ValueError("camera_frame: one or two cameras of one resolution")
    if camera_frame_why_not(config, key, width, height, spp):
        return _frame_of_rays(scene, bvh, cameras, key, spp=spp, config=config)
    typed = key is not None and jnp.issubdtype(key.dtype, jax.dtypes.prng_key)

    def as_key(key_data):
        if key is None:
            return None
        return jax.random.wrap_key_data(key_data, impl="threefry2x32") if typed else key_data

    def reference(scene, cameras, key_data):
        return _frame_of_rays(scene, bvh, cameras, as_key(key_data), spp=spp, config=config)

    def native(scene, cameras, key_data):
        with jax.ensure_compile_time_eval():
            grid = np.asarray(stratified_offsets(spp), np.float32)
        offset = jnp.asarray(config.ray_offset * scene_scale(scene), jnp.float32).reshape(1)
        image, counts = native_camera_frame(
            (*whitted_operands(scene, bvh), jax.lax.stop_gradient(offset)),
            key_data,
            grid,
            camera_rows(cameras),
            jnp.asarray(config.bad_color, jnp.float32),
            spp=spp,
            height=height,
            width=width,
            jitter=key is not None,
            **integrator_options(config, bvh),
        )
        if len(cameras) == 1:
            image = image.reshape(height, width, 3)
        ray_counts = RayCounts(primary=counts[0], shadow=counts[1], reflection=counts[2], bad=counts[3])
        return image, ray_counts, counts[4]

    key_data = jnp.zeros(2, jnp.uint32) if key is None else key_words(key)
    # Derivatives (and the primal a JVP returns) are the reference's: one native forward that
    # stores its paths, then their replay. Taking the handler's image as that primal instead
    # would cost a second forward in every `value_and_grad`.
    stage = on_platforms(reference, cpu=native, cpu_only=integrator_plan(config).cpu_only)
    return stage(scene, tuple(cameras), key_data)


def _mono_program(scene, bvh, camera, key, *, spp, jitter, config):
    return camera_frame(scene, bvh, (camera,), key if jitter else None, spp=spp, config=config)


def _stereo_program(scene, bvh, rig, head_pose, key, *, spp, jitter, config):
    cameras = rig.eye_cameras(head_pose)
    return camera_frame(scene, bvh, cameras, key if jitter else None, spp=spp, config=config)


_PROGRAMS = {"mono": _mono_program, "stereo": _stereo_program}


def _run(entry: str, args: tuple, static: dict):
    """`run_compiled` of a frame program on host arguments."""
    return run_compiled(entry, _PROGRAMS[entry], jax.tree.map(jnp.asarray, args), static)


@dataclasses.dataclass(frozen=True)
class FrameStats:
    """What a frame cost. Ray counts are rays actually traced; `bad_pixels` are pixels painted
    the bad colour; `compile_seconds` is 0 when a compiled program was reused; `render_seconds`
    is the compiled program's wall time (rays, shading, filtering; not the host transfers)."""

    primary_rays: int
    shadow_rays: int
    reflection_rays: int
    bad_samples: int
    bad_pixels: int
    compile_seconds: float
    render_seconds: float
    width: int
    height: int
    spp: int
    stereo: bool

    @property
    def rays(self) -> int:
        return self.primary_rays + self.shadow_rays + self.reflection_rays

    def summary(self) -> str:
        kind = "stereo" if self.stereo else "mono"
        rate = self.rays / self.render_seconds / 1e6 if self.render_seconds > 0 else float("nan")
        return (
            f"{kind} {self.width}x{self.height} spp {self.spp}: {self.primary_rays:,} primary + "
            f"{self.shadow_rays:,} shadow + {self.reflection_rays:,} reflection rays in "
            f"{self.render_seconds:.2f} s ({rate:.2f} Mrays/s), compile {self.compile_seconds:.1f} s, "
            f"{self.bad_pixels} bad pixels"
        )


@dataclasses.dataclass(frozen=True)
class Frame:
    """A rendered frame: `image` (H, W, 3) linear-RGB float32 NumPy (side by side for stereo:
    W = 2 x eye width, left eye on the left) and its `stats`."""

    image: np.ndarray
    stats: FrameStats

    def eyes(self) -> tuple[np.ndarray, np.ndarray]:
        """(left, right) halves of a stereo frame."""
        if not self.stats.stereo:
            raise ValueError("Frame.eyes: this is a mono frame")
        half = self.image.shape[1] // 2
        return self.image[:, :half], self.image[:, half:]

    def save(self, path: str | os.PathLike, **kwargs: Any) -> Path:
        """Save the image (see `fovjax.save_image`: PNG tone-mapped sRGB, EXR/HDR linear;
        `kwargs` are its options)."""
        from ..files import save_image

        return save_image(path, self.image, **kwargs)


_BVH_MEMO: collections.OrderedDict = collections.OrderedDict()


def bvh_for(scene: Scene | SceneArrays, bvh: BVH | None) -> BVH:
    """`bvh` checked against the scene, or the scene's BVH (built once, memoised by content)."""
    if not isinstance(scene, Scene | SceneArrays):
        raise TypeError(
            f"render: scene {scene!r} is not a fovjax.Scene (nor its SceneArrays); make one first, "
            "e.g. fovjax.scenes.cornell_box() or fovjax.load_scene(path)"
        )
    if bvh is None:
        if not isinstance(scene, Scene) or not scene.content_hash:
            raise ValueError("render: pass bvh= when the scene is not a fovjax.Scene with a content hash")
        bvh = _BVH_MEMO.get(scene.content_hash)
        if bvh is None:
            bvh = build_bvh(scene)
            _BVH_MEMO[scene.content_hash] = bvh
            while len(_BVH_MEMO) > 4:
                _BVH_MEMO.popitem(last=False)
    faces = np.shape(scene.faces)
    if bvh.num_triangles != faces[0]:
        raise ValueError(
            f"render: the BVH has {bvh.num_triangles} triangles but the scene has {faces[0]}; "
            "build it from this scene (fovjax.trace.build_bvh(scene))"
        )
    return bvh


def _key_args(key, spp: int):
    if spp < 1 or int(round(spp**0.5)) ** 2 != spp:
        raise ValueError(f"spp must be a positive square (1, 4, 9, 16, ...), got {spp}")
    jitter = key is not None
    return (key if jitter else jax.random.key(0)), jitter


def frame_stats(
    counts, bad_pixels, compile_s: float, render_s: float, *, width, height, spp, stereo
) -> FrameStats:
    """The `FrameStats` of a frame program's outputs (ray counts and bad pixels as arrays or
    ints): the one stats builder of every entry point."""
    primary, shadow, reflection, bad = (int(c) for c in counts)  # a RayCounts
    return FrameStats(
        primary_rays=primary,
        shadow_rays=shadow,
        reflection_rays=reflection,
        bad_samples=bad,
        bad_pixels=int(bad_pixels),
        compile_seconds=compile_s,
        render_seconds=render_s,
        width=int(width),
        height=int(height),
        spp=int(spp),
        stereo=bool(stereo),
    )


def _frame(outputs, compile_s, render_s, *, spp, stereo) -> Frame:
    image, counts, bad_pixels = outputs
    image = np.asarray(image)
    stats = frame_stats(
        counts,
        bad_pixels,
        compile_s,
        render_s,
        width=image.shape[1],
        height=image.shape[0],
        spp=spp,
        stereo=stereo,
    )
    return Frame(image=image, stats=stats)


def render(
    scene: Scene | SceneArrays,
    camera: Camera,
    *,
    spp: int = 1,
    key: jax.Array | None = None,
    config: RenderConfig = DEFAULT_CONFIG,
    envmap: EnvmapLike = None,
    bvh: BVH | None = None,
) -> Frame:
    """Render one camera's view of `scene` with the Whitted integrator.

    `spp` samples per pixel (a square: 1, 4, 9, 16, ...) on a stratified sub-pixel grid,
    jittered per pixel from the PRNG `key` (cell centres when None), box-filtered. `envmap`: a
    lat-long image path or array seen by missing rays (else `config.background`). `bvh`:
    reused if given, else built (and cached) from the scene.
    """
    check_frame_memory(camera.width, camera.height, int(spp), eyes=1, config=config, where="render")
    bvh = bvh_for(scene, bvh)
    arrays = (
        scene
        if isinstance(scene, SceneArrays)
        else scene_arrays(scene, envmap=envmap, background=config.background)
    )
    key, jitter = _key_args(key, spp)
    outputs, compile_s, render_s = _run(
        "mono", (arrays, bvh, camera, key), {"spp": int(spp), "jitter": jitter, "config": config}
    )
    return _frame(outputs, compile_s, render_s, spp=int(spp), stereo=False)


def render_stereo(
    scene: Scene | SceneArrays,
    rig: StereoRig | None = None,
    *,
    head_pose: HeadPoseLike = None,
    spp: int = 1,
    key: jax.Array | None = None,
    config: RenderConfig = DEFAULT_CONFIG,
    envmap: EnvmapLike = None,
    bvh: BVH | None = None,
) -> Frame:
    """The full stereo frame, every pixel traced (no foveation). Both eyes of `rig` (default: the
    thesis HMD at the scene's default viewpoint) side by side for a head pose ((yaw, pitch, roll)
    degrees or a `fovjax.devices.HeadPose`); other arguments as `render`. Foveated frames:
    `fovjax.render_stereo(..., foveation=, gaze=)`, the package's entry point above this one and
    `fovjax.foveate`, which calls this one when neither is given."""
    if rig is None:
        from ..scene import default_camera

        if not isinstance(scene, Scene):
            raise ValueError("render_stereo: pass a rig when the scene is not a fovjax.Scene")
        rig = StereoRig.from_pose(default_camera(scene))
    check_frame_memory(rig.eye_width, rig.eye_height, int(spp), config=config, where="render_stereo")
    bvh = bvh_for(scene, bvh)
    arrays = (
        scene
        if isinstance(scene, SceneArrays)
        else scene_arrays(scene, envmap=envmap, background=config.background)
    )
    key, jitter = _key_args(key, spp)
    angles = np.asarray(head_pose_angles(head_pose), np.float32)
    outputs, compile_s, render_s = _run(
        "stereo", (arrays, bvh, rig, angles, key), {"spp": int(spp), "jitter": jitter, "config": config}
    )
    return _frame(outputs, compile_s, render_s, spp=int(spp), stereo=True)
