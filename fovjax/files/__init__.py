"""Files: images in and out, and writes that never leave a half-written file.

- `save_image(path, image)`, `load_image(path)`: PNG/JPEG (tone-mapped, sRGB) and EXR/HDR
  (linear) by suffix (`HDR_SUFFIXES`); `tonemap`, `linear_to_srgb`, `srgb_to_linear`.
- `atomic_path(path)`: a context manager that yields a temporary path beside `path` and renames
  it into place only when the block succeeds.
- `deferred_interrupt()`, `interrupt_flag()`: Ctrl-C (and SIGTERM, `INTERRUPT_SIGNALS`) held
  back (or only recorded) while a file is being written, so an interrupted program never leaves
  a torn output.

This package imports nothing else from fovjax.
"""

from ._atomic import INTERRUPT_SIGNALS as INTERRUPT_SIGNALS
from ._atomic import atomic_path as atomic_path
from ._atomic import deferred_interrupt as deferred_interrupt
from ._atomic import interrupt_flag as interrupt_flag
from ._image import HDR_SUFFIXES as HDR_SUFFIXES
from ._image import TONEMAPS as TONEMAPS
from ._image import linear_to_srgb as linear_to_srgb
from ._image import load_image as load_image
from ._image import save_image as save_image
from ._image import srgb_to_linear as srgb_to_linear
from ._image import tonemap as tonemap

__all__ = [
    "INTERRUPT_SIGNALS",
    "atomic_path",
    "deferred_interrupt",
    "interrupt_flag",
    "HDR_SUFFIXES",
    "TONEMAPS",
    "linear_to_srgb",
    "load_image",
    "save_image",
    "srgb_to_linear",
    "tonemap",
]
