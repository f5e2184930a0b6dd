"""Scenes: the `Scene` pytree, cameras, loading from files, and the built-in procedural scenes.

- `Scene`, `Materials`, `Lights`, `Textures` and their constructors `make_scene`, `make_materials`,
  `make_lights` (`POINT_LIGHT`, `DIRECTIONAL_LIGHT`, `SPOT_LIGHT` name the light kinds); `geometry_hash` and
  `validate_geometry` check and identify a triangle mesh (the BVH cache keys on the hash).
- `Camera` (a pinhole camera with its primary rays), `look_at_rotation`, `vfov_from_hfov`,
  `stratified_offsets` and `pixel_sample_positions` (the per-pixel sample positions every
  renderer shares).
- `load_scene(path)`: OBJ+MTL, glTF/GLB and PLY files (`SUPPORTED_FORMATS`); one file, or a
  scene of many (a folder, a glob pattern or a list; `scene_files` lists them) with `skip=` and
  `scale=`, as the thesis loads Sponza's 382 parts.
- `cornell_box()`: the classic box from its published dimensions (metres by default).
- `atrium(triangles=262_000)`: an indoor courtyard like Sponza in layout and scale.
- `spheres()`: a minimal scene for fast tests.
- Level of detail (`_lod.py`, the `[lod]` extra): `decimate(scene, ratio)` by per-material
  quadric decimation, `lod_levels(scene, ratios)` the cached chain with each level's measured
  `geometric_error`, `select_lod(errors, eccentricity, distance, acuity, pixels_per_degree)` the
  coarsest level the eye cannot tell apart.
- `default_camera(scene)`: a `CameraPose` (position, look_at, up, vertical FOV) for each;
  `BUILTIN` maps the built-in scenes' names to their constructors.

This package imports nothing else from fovjax: every other part builds on it.
"""

from ._atrium import atrium as atrium
from ._camera import Camera as Camera
from ._camera import look_at_rotation as look_at_rotation
from ._camera import pixel_sample_positions as pixel_sample_positions
from ._camera import stratified_offsets as stratified_offsets
from ._camera import vfov_from_hfov as vfov_from_hfov
from ._cornell import cornell_box as cornell_box
from ._files import scene_files as scene_files
from ._loaders import SUPPORTED_FORMATS as SUPPORTED_FORMATS
from ._loaders import load_scene as load_scene
from ._lod import DEFAULT_RATIOS as DEFAULT_RATIOS
from ._lod import LODLevels as LODLevels
from ._lod import decimate as decimate
from ._lod import geometric_error as geometric_error
from ._lod import lod_levels as lod_levels
from ._lod import select_lod as select_lod
from ._lod import surface_distance as surface_distance
from ._poses import CameraPose as CameraPose
from ._poses import default_camera as default_camera
from ._scene import DIRECTIONAL_LIGHT as DIRECTIONAL_LIGHT
from ._scene import POINT_LIGHT as POINT_LIGHT
from ._scene import SPOT_LIGHT as SPOT_LIGHT
from ._scene import Lights as Lights
from ._scene import Materials as Materials
from ._scene import Scene as Scene
from ._scene import Textures as Textures
from ._scene import geometry_hash as geometry_hash
from ._scene import make_lights as make_lights
from ._scene import make_materials as make_materials
from ._scene import make_scene as make_scene
from ._scene import validate_geometry as validate_geometry
from ._spheres import spheres as spheres

BUILTIN = {"atrium": atrium, "cornell_box": cornell_box, "spheres": spheres}

__all__ = [
    "atrium",
    "Camera",
    "look_at_rotation",
    "pixel_sample_positions",
    "stratified_offsets",
    "vfov_from_hfov",
    "cornell_box",
    "SUPPORTED_FORMATS",
    "load_scene",
    "scene_files",
    "DEFAULT_RATIOS",
    "LODLevels",
    "decimate",
    "geometric_error",
    "lod_levels",
    "select_lod",
    "surface_distance",
    "CameraPose",
    "default_camera",
    "DIRECTIONAL_LIGHT",
    "POINT_LIGHT",
    "SPOT_LIGHT",
    "Lights",
    "Materials",
    "Scene",
    "Textures",
    "geometry_hash",
    "make_lights",
    "make_materials",
    "make_scene",
    "validate_geometry",
    "spheres",
    "BUILTIN",
]
