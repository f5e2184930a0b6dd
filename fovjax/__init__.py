"""fovjax: a differentiable JAX reference renderer and model-fitting toolkit for foveated ray
tracing on eye-tracked stereo head-mounted displays."""

# First, before JAX starts: malloc's kept memory, and Ctrl-C while the program starts
# (fovjax/_startup.py).
from . import _startup  # noqa: F401
from . import foveate as foveate
from . import render as render
from . import scene as scene
from . import scenes as scenes
from . import trace as trace
from ._dispatch import render_stereo as render_stereo
from .files import linear_to_srgb as linear_to_srgb
from .files import load_image as load_image
from .files import save_image as save_image
from .files import tonemap as tonemap
from .foveate import Fidelity as Fidelity
from .foveate import FoveatedFrame as FoveatedFrame
from .foveate import FoveatedRenderer as FoveatedRenderer
from .foveate import Foveation as Foveation
from .foveate import render_foveated as render_foveated
from .render import Frame as Frame
from .render import RenderConfig as RenderConfig
from .render import StereoRig as StereoRig
from .render import enable_compile_cache as enable_compile_cache
from .scene import DIRECTIONAL_LIGHT as DIRECTIONAL_LIGHT
from .scene import POINT_LIGHT as POINT_LIGHT
from .scene import SPOT_LIGHT as SPOT_LIGHT
from .scene import Camera as Camera
from .scene import Lights as Lights
from .scene import LODLevels as LODLevels
from .scene import Materials as Materials
from .scene import Scene as Scene
from .scene import decimate as decimate
from .scene import load_scene as load_scene
from .scene import lod_levels as lod_levels
from .scene import look_at_rotation as look_at_rotation
from .scene import make_lights as make_lights
from .scene import make_materials as make_materials
from .scene import make_scene as make_scene
from .scene import pixel_sample_positions as pixel_sample_positions
from .scene import select_lod as select_lod
from .scene import stratified_offsets as stratified_offsets
from .scene import vfov_from_hfov as vfov_from_hfov
from .session import SessionConfig as SessionConfig
from .session import SessionOutput as SessionOutput
from .session import full_eccentricity as full_eccentricity
from .session import run_session as run_session


def _version() -> str:
    """The installed distribution's version: one place, `pyproject.toml`."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("fovjax")
    except PackageNotFoundError:  # a source tree on sys.path without an install
        return "0+unknown"


__version__ = _version()


# The main eval entry points, imported from `fovjax.eval` on first use: `import fovjax` stays
# free of the metrics' dependencies.
_FROM_EVAL = ("compare_thresholds", "plan_fidelity", "video_study")


def __getattr__(name: str):
    """`fovjax.compare_thresholds`, `fovjax.plan_fidelity`, `fovjax.video_study` (from
    `fovjax.eval`, imported on first use). `plan_fidelity` lives in eval, not foveate, because it
    judges plans by image metrics and the core packages never import eval
    (docs/concepts/architecture.md)."""
    if name in _FROM_EVAL:
        from . import eval as eval_package

        return getattr(eval_package, name)
    raise AttributeError(f"module 'fovjax' has no attribute {name!r}")


__all__ = [
    "render_stereo",
    "linear_to_srgb",
    "load_image",
    "save_image",
    "tonemap",
    "Fidelity",
    "FoveatedFrame",
    "FoveatedRenderer",
    "Foveation",
    "render_foveated",
    "Frame",
    "RenderConfig",
    "StereoRig",
    "enable_compile_cache",
    "DIRECTIONAL_LIGHT",
    "POINT_LIGHT",
    "SPOT_LIGHT",
    "Camera",
    "Lights",
    "LODLevels",
    "Materials",
    "Scene",
    "decimate",
    "load_scene",
    "lod_levels",
    "look_at_rotation",
    "make_lights",
    "make_materials",
    "make_scene",
    "pixel_sample_positions",
    "select_lod",
    "stratified_offsets",
    "vfov_from_hfov",
    "SessionConfig",
    "SessionOutput",
    "full_eccentricity",
    "run_session",
]
