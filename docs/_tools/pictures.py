"""Render the documentation's pictures (docs/images/): one foveated stereo frame of the atrium and
its stages — regions and traced samples, the traced samples before the fill, the full render.

    python docs/_tools/pictures.py          # a few minutes on a 2-core CPU
"""

from pathlib import Path

import jax
import numpy as np

import fovjax
from fovjax.foveate import Foveation
from fovjax.render import RenderConfig, StereoRig

OUT = Path(__file__).resolve().parents[1] / "images"
W, H = 320, 256
GAZE = ((0.42, 0.5), (0.58, 0.5))


def main() -> None:
    OUT.mkdir(exist_ok=True)
    scene = fovjax.scenes.atrium()
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=W, eye_height=H)
    config = RenderConfig(max_depth=2)
    fov = Foveation(fovea_deg=10, periphery_deg=20)
    key = jax.random.key(0)
    frame = fovjax.render_stereo(scene, rig, gaze=GAZE, foveation=fov, config=config, key=key)
    fovjax.save_image(OUT / "foveated.png", frame.image)
    fovjax.save_image(OUT / "regions.png", frame.debug_view)
    prefill = np.asarray(frame.outputs.prefill)
    if prefill.ndim == 4:  # (2, H, W, 3): side by side
        prefill = np.concatenate(list(prefill), axis=1)
    fovjax.save_image(OUT / "prefill.png", np.nan_to_num(prefill))
    both = np.concatenate([np.asarray(frame.image), np.asarray(frame.debug_view)], axis=0)
    fovjax.save_image(OUT / "foveated_regions.png", both)
    full = fovjax.render_stereo(scene, rig, config=config, key=key)
    fovjax.save_image(OUT / "full.png", full.image)
    print(frame.stats, frame.foveation, full.stats, sep="\n")


if __name__ == "__main__":
    main()
