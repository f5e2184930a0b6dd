"""What the packages built on the renderer share with it and users do not need: the compile
path, the frame statistics builder, the pure stereo frame program and the batch machinery.
Sibling packages (`fovjax.foveate`, `fovjax.eval`, the session and the viewer) import these from
here; nothing here is part of the stable public API (tests/test_architecture.py keeps users'
layers, the command line and the top level, from importing it)."""

from ._batch import batch_size as batch_size
from ._batch import frame_mesh as frame_mesh
from ._batch import head_poses_array as head_poses_array
from ._batch import key_data as key_data
from ._batch import per_frame as per_frame
from ._batch import run_sharded as run_sharded
