"""Patney 2016's contrast window against its cost: frame time, errors and contrast per `window_per_sigma`.

    python benchmarks/patney_window.py                        # atrium 2 x 640x512, SPP 1
    python benchmarks/patney_window.py --windows 1 1.5 2 3 --frames 8
    python benchmarks/patney_window.py --scene cornell_box

`Patney2016.window_per_sigma` (the contrast window's σ per blur σ) is fovjax's choice, 2 by
default, and its pre-filter's windows are most of the method's cost over the thesis's frame
(`benchmarks/profile_frame.py --method patney2016`). This charts the choice: per value, the
frame time over the thesis method's (every configuration renders frame k, at the same slowly
moving gaze and key, before any renders frame k + 1, as `benchmarks/methods_frame.py` does) and
two errors of the frame against the full render of the same key, each a mean with its 95%
interval over the measured frames: FLIP (LDR, at the rig's pixels per degree; a metric of what
the fovea sees) and FovVideoVDP's JOD (foveated at the frame's gaze, the worse eye; a metric of
what the periphery sees too, where Patney's pre-filter acts; 10 = no visible difference); and
the contrast the periphery keeps (`contrast_kept`: beyond the periphery radius and the blend,
the local contrast of the luminance summed, over the full render's), the property the
pre-filter exists for: a blur without it keeps too little and the periphery looks like a
tunnel. The ratios are of this run only: its frames alternate with a full render, so they are not those
of `methods_frame.py`. Each Patney renderer first renders
`--warm-up` frames, so its history has built up (its weight 1 − `taa_alpha` per frame) before a
frame is measured. Writes a record (benchmarks/results/patney_window-*.json).
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import math
import statistics
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import fovjax
import fovjax.eval as fe
from fovjax.foveate import Foveation, Patney2016
from fovjax.foveate._methods._patney import local_std, luminance
from fovjax.render import RenderConfig, StereoRig

CONTRAST_SIGMA = 4.0  # px: the coarse rate's block, whose detail the pre-filter blurs and restores


@functools.partial(jax.jit, static_argnames="sigma")
def _local_std(image, sigma):
    return local_std(luminance(image[None]), sigma)[0, ..., 0]


def local_contrast(image: np.ndarray, sigma: float = CONTRAST_SIGMA) -> np.ndarray:
    """Per pixel the standard deviation of the luminance of `image` (H, W, 3) in a Gaussian
    window of `sigma` pixels: the pre-filter's own measure of contrast (`local_std` of its
    `luminance`, the border repeated)."""
    return np.asarray(_local_std(jnp.asarray(image, jnp.float32), sigma), np.float64)


def contrast_kept(image: np.ndarray, reference: np.ndarray, where: np.ndarray) -> float:
    """The local contrast of `image` summed over the pixels `where`, over the reference's:
    1 where the periphery shows the full render's contrast, below 1 where a blur lost some
    (the tunnel vision Patney 2016's pre-filter exists to prevent), above where the image adds
    its own (aliasing, noise)."""
    return float(local_contrast(image)[where].sum() / local_contrast(reference)[where].sum())


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="atrium", help="a built-in scene (fovjax.scenes.BUILTIN)")
    p.add_argument("--size", type=int, nargs=2, default=(640, 512), metavar=("W", "H"))
    p.add_argument("--windows", type=float, nargs="+", default=(1.0, 1.5, 2.0), metavar="SIGMAS")
    p.add_argument("--frames", type=int, default=8, help="frames measured per configuration")
    p.add_argument("--warm-up", type=int, default=24, help="frames rendered before the first measured")
    p.add_argument("--max-depth", type=int, default=5)
    args = p.parse_args(argv)
    if args.frames < 2 or args.warm_up < 0 or min(args.size) < 8:
        p.error(
            "--frames must be at least 2, --warm-up at least 0 and --size at least 8 x 8, "
            f"got {args.frames}, {args.warm_up}, {args.size}"
        )
    if not all(math.isfinite(w) and w > 0 for w in args.windows):
        p.error(f"--windows must be positive, got {args.windows}")
    if args.scene not in fovjax.scenes.BUILTIN:
        p.error(f"--scene {args.scene!r}: one of {sorted(fovjax.scenes.BUILTIN)}")
    use_jod = importlib.util.find_spec("pyfvvdp") is not None
    if not use_jod:
        print("FovVideoVDP (pyfvvdp, the [fvvdp] extra) is not installed: no JOD column")
    w, h = args.size
    scene = fovjax.scenes.BUILTIN[args.scene]()
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=w, eye_height=h)
    display = fe.HmdDisplay.from_camera(rig.eye_cameras()[0])
    base = fovjax.FoveatedRenderer(scene, rig, config=RenderConfig(max_depth=args.max_depth))
    total = args.warm_up + args.frames
    gazes = [((0.45 + 0.002 * k, 0.5), (0.42 + 0.002 * k, 0.5)) for k in range(total + 1)]
    methods = {"thesis": "thesis"} | {f"window {s:g}": Patney2016(window_per_sigma=s) for s in args.windows}
    renderers, compile_s = {}, {}
    for name, method in methods.items():
        r = base.with_foveation(Foveation(method=method, fovea_deg=5.0, periphery_deg=10.0), diagnostics=())
        r.reset_history()
        compile_s[name] = r.render(gazes[0], key=jax.random.key(0)).stats.compile_seconds
        renderers[name] = r
    # The periphery (beyond the periphery radius and the blend), from the eccentricity of a
    # probe renderer that is never timed.
    foveation = Foveation(fovea_deg=5.0, periphery_deg=10.0)
    probe = base.with_foveation(foveation, diagnostics=("eccentricity",))
    outside = foveation.periphery_deg + Patney2016().blend_deg
    ms = {name: [] for name in methods}
    flips = {name: [] for name in methods}
    kept = {name: [] for name in methods}
    jods = {name: [] for name in methods}
    for k in range(1, total + 1):
        key = jax.random.key(k)
        images = {}
        for name, r in renderers.items():
            frame = r.render(gazes[k], key=key)
            if k > args.warm_up:
                ms[name].append(1000 * frame.stats.render_seconds)
                images[name] = np.asarray(frame.image)
        if images:
            reference = np.asarray(base.render_full(key=key).image)
            ecc = np.asarray(probe.render(gazes[k], key=key).eccentricity)
            periphery = np.concatenate([ecc[0], ecc[1]], axis=1) > outside  # side by side, as the images
            for name, image in images.items():
                kept[name].append(contrast_kept(image, reference, periphery))
                flips[name].append(fe.flip(image, reference, ppd=display.ppd).value)
                if use_jod:
                    jods[name].append(fe.fovvdp(image, reference, display, gaze_xy=gazes[k]).value)
    thesis = statistics.median(ms["thesis"])
    rows = []
    print(
        f"{'configuration':14s} {'ms/frame':>9s} {'/ thesis':>9s}  {'FLIP [95%]':26s} {'JOD [95%]':23s} "
        "contrast kept [95%]"
    )
    for name in methods:
        median = statistics.median(ms[name])
        flip = "{:.4f} [{:.4f}, {:.4f}]".format(*fe.mean_interval(flips[name]))
        jod = "{:.3f} [{:.3f}, {:.3f}]".format(*fe.mean_interval(jods[name])) if use_jod else "not measured"
        contrast = "{:.3f} [{:.3f}, {:.3f}]".format(*fe.mean_interval(kept[name]))
        rows.append([name, round(median, 1), round(median / thesis, 2), flip, jod, contrast])
        print(f"{name:14s} {median:9.1f} {median / thesis:9.2f}  {flip:26s} {jod:23s} {contrast}")
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _record import write_record

    write_record(
        "patney_window",
        {
            "tables": [
                {
                    "title": "Patney 2016's contrast window (window_per_sigma) against its cost, "
                    f"{args.scene} 2 × {w}×{h}, SPP 1, depth {args.max_depth}, 5°/10°, "
                    f"{args.frames} frames after {args.warm_up} of warm-up, the configurations in "
                    "turn per frame (median ms; ratio to the thesis method's; mean FLIP and "
                    "FovVideoVDP JOD against the full render of the same key; the periphery's local "
                    f"contrast, σ {CONTRAST_SIGMA:g} px, over the full render's)",
                    "columns": [
                        "configuration",
                        "ms/frame",
                        "/ thesis",
                        "FLIP [95%]",
                        "JOD [95%]",
                        "contrast kept [95%]",
                    ],
                    "rows": rows,
                }
            ],
            "ms": ms,
            "flip": flips,
            "jod": jods,
            "contrast_kept": kept,
            "compile_s": compile_s,
            "ppd": display.ppd,
        },
        note="CPU only (2 shared cores); the configurations render each frame in turn, so read the ratios",
    )


if __name__ == "__main__":
    main()
