"""Built-in procedural scenes and their default cameras.

- `cornell_box()`: the classic box from its published dimensions (metres by default).
- `atrium(triangles=262_000)`: an indoor courtyard like Sponza in layout and scale.
- `spheres()`: a minimal scene for fast tests.
- `default_camera(scene)`: a `CameraPose` (position, look_at, up, vertical FOV) for each.

Files (OBJ+MTL, glTF/GLB, PLY) load with `fovjax.load_scene`.
"""

from ._atrium import atrium as atrium
from ._camera import CameraPose as CameraPose
from ._camera import default_camera as default_camera
from ._cornell import cornell_box as cornell_box
from ._spheres import spheres as spheres

BUILTIN = {"atrium": atrium, "cornell_box": cornell_box, "spheres": spheres}
