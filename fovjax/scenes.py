"""Built-in procedural scenes and their default cameras: `fovjax.scenes.atrium()` and friends.

Kept so that `fovjax.scenes` reads as it always has; the code lives in `fovjax.scene`.
"""

from .scene import BUILTIN as BUILTIN
from .scene import CameraPose as CameraPose
from .scene import atrium as atrium
from .scene import cornell_box as cornell_box
from .scene import default_camera as default_camera
from .scene import spheres as spheres
