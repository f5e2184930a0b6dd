"""fovjax: a differentiable JAX reference renderer and model-fitting toolkit for foveated ray
tracing on eye-tracked stereo head-mounted displays."""

# First: Ctrl-C while the program starts (fovjax/_startup.py).
from . import _startup  # noqa: F401
from . import foveate as foveate
from . import render as render
from . import scenes as scenes
from . import trace as trace
from ._camera import (
    Camera as Camera,
)
from ._camera import (
    look_at_rotation as look_at_rotation,
)
from ._camera import (
    pixel_sample_positions as pixel_sample_positions,
)
from ._camera import (
    stratified_offsets as stratified_offsets,
)
from ._camera import (
    vfov_from_hfov as vfov_from_hfov,
)
from ._dispatch import render_stereo as render_stereo
from ._image import linear_to_srgb as linear_to_srgb
from ._image import load_image as load_image
from ._image import save_image as save_image
from ._image import tonemap as tonemap
from ._loaders import load_scene as load_scene
from ._scene import (
    DIRECTIONAL_LIGHT as DIRECTIONAL_LIGHT,
)
from ._scene import (
    POINT_LIGHT as POINT_LIGHT,
)
from ._scene import (
    Lights as Lights,
)
from ._scene import (
    Materials as Materials,
)
from ._scene import (
    Scene as Scene,
)
from ._scene import (
    make_lights as make_lights,
)
from ._scene import (
    make_materials as make_materials,
)
from ._scene import (
    make_scene as make_scene,
)
from ._session import full_eccentricity as full_eccentricity
from ._session import run_session as run_session
from .render import Frame as Frame
from .render import RenderConfig as RenderConfig
from .render import StereoRig as StereoRig

__version__ = "0.1.0"
