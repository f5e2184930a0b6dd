"""fovjax: a differentiable JAX reference renderer and model-fitting toolkit for foveated ray
tracing on eye-tracked stereo head-mounted displays."""

from . import scenes as scenes
from ._loaders import load_scene as load_scene
from ._scene import (
    DIRECTIONAL_LIGHT as DIRECTIONAL_LIGHT,
    POINT_LIGHT as POINT_LIGHT,
    Lights as Lights,
    Materials as Materials,
    Scene as Scene,
    make_lights as make_lights,
    make_materials as make_materials,
    make_scene as make_scene,
)

__version__ = "0.1.0"
