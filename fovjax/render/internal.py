"""What the packages built on the renderer share with it and users do not need: the compile
path, the frame statistics builder, the pure stereo frame program and the batch machinery.
Sibling packages (`fovjax.foveate`, `fovjax.eval`, the session and the viewer) import these from
here; nothing here is part of the stable public API (tests/test_architecture.py keeps users'
layers, the command line and the top level, from importing it)."""

from ._batch import batch_size as batch_size
from ._batch import head_poses_array as head_poses_array
from ._batch import key_data as key_data
from ._batch import per_frame as per_frame
from ._batch import run_sharded as run_sharded
from ._frame import LOOP_EMITTERS as LOOP_EMITTERS
from ._frame import LOWERING_HOOKS as LOWERING_HOOKS
from ._frame import _key_args as key_args
from ._frame import _stereo_program as stereo_program
from ._frame import bvh_for as bvh_for
from ._frame import frame_compiler_options as frame_compiler_options
from ._frame import frame_stats as frame_stats
from ._frame import run_compiled as run_compiled
from ._integrator import SHADOWS_ALL as SHADOWS_ALL
from ._integrator import SHADOWS_BRIGHTEST as SHADOWS_BRIGHTEST
from ._integrator import SHADOWS_NONE as SHADOWS_NONE
from ._integrator import ChunkedRadiance as ChunkedRadiance
from ._integrator import ImageTile as ImageTile
from ._integrator import ShadingClasses as ShadingClasses
from ._integrator import Surface as Surface
from ._integrator import _chunk_rays as chunk_rays
from ._integrator import bilinear_wrap as bilinear_wrap
from ._integrator import chunk_loop as chunk_loop
from ._integrator import native_integrator as native_integrator
from ._integrator import radiance_in_chunks as radiance_in_chunks
from ._integrator import scene_scale as scene_scale
from ._integrator import shading_of as shading_of
from ._integrator import surface_at as surface_at
from ._mips import mip_lookup as mip_lookup
from ._mips import mip_shapes as mip_shapes
from ._mips import pixel_spread_angle as pixel_spread_angle
from ._mips import texture_mips as texture_mips
from ._mips import with_texture_mips as with_texture_mips
from ._native import MAX_NATIVE_DEPTH as MAX_NATIVE_DEPTH
from ._native import SHADING_FIELDS as SHADING_FIELDS
from ._native import camera_rows as camera_rows
from ._native import integrator_options as integrator_options
from ._native import integrator_plan as integrator_plan
from ._native import native_shading_adjoint as native_shading_adjoint
from ._native import shading_attributes as shading_attributes
from ._native import warp_integrator_plan as warp_integrator_plan
from ._native import whitted_operands as whitted_operands
from ._replay import StoredPaths as StoredPaths
from ._replay import replay_radiance as replay_radiance
from ._replay import shading_tangent as shading_tangent
from ._replay import split_tangents as split_tangents
from ._warp_whitted import warp_integrate as warp_integrate

__all__ = [
    "LOOP_EMITTERS",
    "LOWERING_HOOKS",
    "frame_compiler_options",
    "bvh_for",
    "frame_stats",
    "run_compiled",
    "ChunkedRadiance",
    "ImageTile",
    "SHADOWS_ALL",
    "SHADOWS_BRIGHTEST",
    "SHADOWS_NONE",
    "ShadingClasses",
    "Surface",
    "bilinear_wrap",
    "chunk_loop",
    "chunk_rays",
    "native_integrator",
    "integrator_plan",
    "warp_integrator_plan",
    "warp_integrate",
    "MAX_NATIVE_DEPTH",
    "whitted_operands",
    "StoredPaths",
    "replay_radiance",
    "shading_tangent",
    "split_tangents",
    "SHADING_FIELDS",
    "native_shading_adjoint",
    "shading_of",
    "shading_attributes",
    "integrator_options",
    "camera_rows",
    "radiance_in_chunks",
    "scene_scale",
    "surface_at",
    "mip_lookup",
    "mip_shapes",
    "pixel_spread_angle",
    "texture_mips",
    "with_texture_mips",
    "batch_size",
    "head_poses_array",
    "key_data",
    "per_frame",
    "run_sharded",
    "key_args",
    "stereo_program",
]
