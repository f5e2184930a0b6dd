"""The renderer: Whitted ray tracing (Blinn–Phong, shadow rays, mirror reflections, env map),
the stereo HMD rig with head pose, and frames compiled once per configuration.

The frame is three steps, each usable on its own (the foveation layer reuses them):

- `stereo_sample_rays(rig, head_pose, spp, key)` → `SampleRays(origins, directions)` of shape
  (2, spp, H, W, 3) and `pixel_xy` (spp, H, W, 2) (or `Camera.sample_rays` for one camera);
- `radiance(scene_arrays, bvh, origins, directions, active, config=)` →
  `Radiance(rgb (..., 3), bad (...), counts: RayCounts)`, tracing only the `active` rays;
- `resolve(rgb, bad)` → the box-filtered pixels (and which are bad); `side_by_side` for stereo;
- `radiance_in_chunks(scene_arrays, bvh, rays_at, n_live, n_slots=)`: rays made and traced chunk
  by chunk, a cost that follows the live rays (the foveated frame); with `classes=`
  (`ShadingClasses`, shadow modes `SHADOWS_ALL`/`SHADOWS_BRIGHTEST`/`SHADOWS_NONE`) a
  reflection depth and shadow-ray mode per class of rays (the foveated frame's per-region fidelity),
  and a texture level of detail per class (`texture_level`, `texture_cone`: box-filtered mip
  pyramids from `with_texture_mips`, trilinear lookups `mip_lookup`, ray-cone levels).

`render` / `render_stereo` put them together and return a `Frame`; `render_image` /
`render_stereo_image` are the pure, differentiable versions; `differentiable(render_fn, scene,
names)` makes any of them a function of the scene values a user names (`Parameters`: material
colours, lights, vertices, the camera's position, the head pose) for `jax.grad` and `jax.jvp`;
`render_stereo_batch` a batch of stereo frames in one program sharded over devices
(`FrameBatch`). Every host entry point compiles through one path
(`fovjax.render.internal.run_compiled`): `clear_compile_cache` and `compile_cache_info` cover
them all. `enable_compile_cache()` keeps compiled programs on disk across processes
(JAX's persistent compilation cache; the command line turns it on).

For the packages that build frames of their own on this one, `fovjax.render.internal` holds what
they share and users do not need: the compile path (`run_compiled`), the stats builder
(`frame_stats`), the pure full stereo frame (`stereo_program`), `key_args`, `bvh_for`, the chunked
integrator (`radiance_in_chunks`, `ShadingClasses`, `ImageTile`), texture mips and the batch
machinery. `DEFAULT_CONFIG` is `RenderConfig()`.

Departures from the thesis's shading (chosen, and kept: the images are compared against
Mitsuba elsewhere):

- the specular term is not multiplied by n·l: per visible light Kd·(n·l) + Ks·(n·h)^Ns (Blinn–
  Phong as usually written), where the thesis's shadow payload (§4.4.3) scales both terms by
  n·l; under a light at grazing incidence a highlight is brighter here than in the thesis
  (`RenderConfig(specular_payload=True)` reads the thesis literally; `specular="phong"` is
  eq. 1's (r·v)^Ns; `min_contribution` is §2.5.2's cut-off; `fovjax.foveate.thesis_preset`
  sets the thesis's whole configuration);
- rays that miss every surface see a constant background, `RenderConfig.background`
  (default `THESIS_BACKGROUND` (0.34, 0.55, 0.85), the thesis's OptiX "bg color"), unless an
  environment map is given (`scene_arrays(..., envmap=)`, `fovjax render --envmap`); the
  thesis's miss program (§4.4.4) samples an environment map.

`fovjax.render` is both this subpackage and, when called, `render`: `fovjax.render(scene,
camera, spp=4)` renders a frame while `fovjax.render.radiance` etc. stay reachable.
"""

import sys
import types

from . import internal as internal
from ._arrays import SceneArrays as SceneArrays
from ._arrays import scene_arrays as scene_arrays
from ._batch import PARTITIONS as PARTITIONS
from ._batch import FrameBatch as FrameBatch
from ._batch import HeadPosesLike as HeadPosesLike
from ._batch import KeysLike as KeysLike
from ._batch import frame_mesh as frame_mesh
from ._batch import render_stereo_batch as render_stereo_batch
from ._compile_cache import compile_cache_dir as compile_cache_dir
from ._compile_cache import compile_cache_entries as compile_cache_entries
from ._compile_cache import compile_cache_problem as compile_cache_problem
from ._compile_cache import enable_compile_cache as enable_compile_cache
from ._config import DEFAULT_CONFIG as DEFAULT_CONFIG
from ._config import MAGENTA as MAGENTA
from ._config import THESIS_BACKGROUND as THESIS_BACKGROUND
from ._config import RenderConfig as RenderConfig
from ._envmap import EnvmapLike as EnvmapLike
from ._envmap import constant_envmap as constant_envmap
from ._envmap import envmap_lookup as envmap_lookup
from ._envmap import latlong_uv as latlong_uv
from ._envmap import load_envmap as load_envmap
from ._frame import TRACE_COUNTS as TRACE_COUNTS
from ._frame import Frame as Frame
from ._frame import FrameStats as FrameStats
from ._frame import clear_compile_cache as clear_compile_cache
from ._frame import compile_cache_info as compile_cache_info
from ._frame import render as render
from ._frame import render_image as render_image
from ._frame import render_stereo as render_stereo
from ._frame import render_stereo_image as render_stereo_image
from ._frame import resolve as resolve
from ._frame import side_by_side as side_by_side
from ._integrator import Radiance as Radiance
from ._integrator import RayCounts as RayCounts
from ._integrator import describe_integrator as describe_integrator
from ._integrator import radiance as radiance
from ._memory import SIZE_CHECK_VARIABLE as SIZE_CHECK_VARIABLE
from ._memory import FrameTooLargeError as FrameTooLargeError
from ._memory import check_frame_memory as check_frame_memory
from ._memory import frame_memory as frame_memory
from ._memory import memory_limit as memory_limit
from ._parameters import PARAMETER_NAMES as PARAMETER_NAMES
from ._parameters import Differentiable as Differentiable
from ._parameters import Parameters as Parameters
from ._parameters import differentiable as differentiable
from ._stereo import HeadPoseLike as HeadPoseLike
from ._stereo import SampleRays as SampleRays
from ._stereo import StereoRig as StereoRig
from ._stereo import head_pose_angles as head_pose_angles
from ._stereo import head_rotation as head_rotation
from ._stereo import stereo_sample_rays as stereo_sample_rays

# Names that moved to `fovjax.render.internal` (what only the packages built on the renderer
# use): still reachable here, with a DeprecationWarning.
_MOVED_TO_INTERNAL = frozenset(internal.__all__)


def __getattr__(name: str):
    if name in _MOVED_TO_INTERNAL:
        import warnings

        warnings.warn(
            f"fovjax.render.{name} moved to fovjax.render.internal (plumbing the packages built on "
            "the renderer share; not part of the stable API)",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(internal, name)
    raise AttributeError(f"module 'fovjax.render' has no attribute {name!r}")


class _CallableModule(types.ModuleType):
    """Lets `fovjax.render(...)` call `render` without hiding this subpackage's other names."""

    def __call__(self, *args, **kwargs):
        return render(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule

__all__ = [
    "SceneArrays",
    "scene_arrays",
    "PARTITIONS",
    "FrameBatch",
    "HeadPosesLike",
    "KeysLike",
    "frame_mesh",
    "render_stereo_batch",
    "compile_cache_dir",
    "compile_cache_entries",
    "compile_cache_problem",
    "enable_compile_cache",
    "DEFAULT_CONFIG",
    "MAGENTA",
    "THESIS_BACKGROUND",
    "RenderConfig",
    "EnvmapLike",
    "constant_envmap",
    "envmap_lookup",
    "latlong_uv",
    "load_envmap",
    "TRACE_COUNTS",
    "Frame",
    "FrameStats",
    "clear_compile_cache",
    "compile_cache_info",
    "render",
    "render_image",
    "render_stereo",
    "render_stereo_image",
    "resolve",
    "side_by_side",
    "Radiance",
    "RayCounts",
    "radiance",
    "describe_integrator",
    "SIZE_CHECK_VARIABLE",
    "FrameTooLargeError",
    "check_frame_memory",
    "frame_memory",
    "memory_limit",
    "PARAMETER_NAMES",
    "Differentiable",
    "Parameters",
    "differentiable",
    "HeadPoseLike",
    "SampleRays",
    "StereoRig",
    "head_pose_angles",
    "head_rotation",
    "stereo_sample_rays",
]
