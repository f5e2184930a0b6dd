"""Inverse rendering: recover the Cornell box's red wall colour and light colour from an image.

A target image is rendered with the published colours. Starting from a wrong wall colour (grey)
and a wrong light colour (blue-ish), optimistix's BFGS minimises the mean squared difference
between the rendered and the target image, with gradients from `jax.grad` through the Whitted
renderer (shading and the differentiable re-intersection; see `fovjax.render`). The red wall's
pixels fix the product wall colour x light colour, the white walls fix the light colour, so both
are recoverable.

    python examples/cornell_inverse.py                # 64 x 64, about a minute
    python examples/cornell_inverse.py --size 128 -o out/cornell_inverse

Writes target.png, before.png, after.png (sRGB) and loss.png (the loss per BFGS step, log
scale) to the output folder, and prints the recovered colours against the true ones.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

import fovjax
from fovjax.render import RenderConfig, render_image, scene_arrays
from fovjax.trace import build_bvh

TRUE_LIGHT = (1.0, 1.0, 1.0)
START_WALL = (0.3, 0.3, 0.3)
START_LIGHT = (0.6, 0.9, 1.4)
# The box has no mirrors: primary rays and shadow rays are all there is to trace.
CONFIG = RenderConfig(max_depth=0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=64, help="image width and height in pixels")
    parser.add_argument("--steps", type=int, default=60, help="most BFGS steps")
    parser.add_argument("-o", "--output", default="out/cornell_inverse", help="output folder")
    args = parser.parse_args(argv)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)

    scene = fovjax.scenes.cornell_box(light_color=TRUE_LIGHT)
    red = scene.materials.names.index("red")
    bvh = build_bvh(scene)
    camera = fovjax.Camera.from_pose(fovjax.scenes.default_camera(scene), width=args.size, height=args.size)
    truth = scene_arrays(scene, background=(0.0, 0.0, 0.0))
    true_wall = np.asarray(truth.kd[red])

    def with_params(params):
        kd = jnp.asarray(truth.kd).at[red].set(params["wall"])
        return eqx.tree_at(lambda a: (a.kd, a.light_color), truth, (kd, params["light"][None]))

    def image(params):
        return render_image(with_params(params), bvh, camera, config=CONFIG)

    target = jax.jit(image)({"wall": jnp.asarray(true_wall), "light": jnp.asarray(TRUE_LIGHT, jnp.float32)})

    def loss(params, _args):
        return jnp.mean((image(params) - target) ** 2), None

    y = {"wall": jnp.asarray(START_WALL, jnp.float32), "light": jnp.asarray(START_LIGHT, jnp.float32)}
    before = jax.jit(image)(y)

    solver = optx.BFGS(rtol=1e-8, atol=1e-10)
    options, tags = {}, frozenset()
    f_struct, aux_struct = jax.eval_shape(lambda: loss(y, None))
    state = solver.init(loss, y, None, options, f_struct, aux_struct, tags)
    step = eqx.filter_jit(lambda y, state: solver.step(loss, y, None, options, state, tags))
    done = eqx.filter_jit(lambda y, state: solver.terminate(loss, y, None, options, state, tags))
    loss_at = jax.jit(lambda y: loss(y, None)[0])

    history = [float(loss_at(y))]
    start = time.perf_counter()
    for i in range(args.steps):
        y, state, _ = step(y, state)
        history.append(float(loss_at(y)))
        print(f"step {i + 1:3d}  loss {history[-1]:.3e}  wall {np.round(np.asarray(y['wall']), 4)}  "
              f"light {np.round(np.asarray(y['light']), 4)}")  # fmt: skip
        if bool(done(y, state)[0]):
            break
    seconds = time.perf_counter() - start
    after = jax.jit(image)(y)

    fovjax.save_image(out / "target.png", np.asarray(target))
    fovjax.save_image(out / "before.png", np.asarray(before))
    fovjax.save_image(out / "after.png", np.asarray(after))
    _plot_loss(history, out / "loss.png")

    wall, light = np.asarray(y["wall"]), np.asarray(y["light"])
    print(f"{len(history) - 1} BFGS steps in {seconds:.1f} s (including compilation of the first step)")
    print(f"loss {history[0]:.3e} -> {history[-1]:.3e}")
    print(f"red wall  true {np.round(true_wall, 4)}  start {START_WALL}  recovered {np.round(wall, 4)}")
    print(f"light     true {TRUE_LIGHT}  start {START_LIGHT}  recovered {np.round(light, 4)}")
    print(f"wrote {out.resolve()}/{{target,before,after,loss}}.png")
    return 0


def _plot_loss(history, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.2), dpi=120)
    ax.semilogy(range(len(history)), history, marker="o", markersize=3)
    ax.set_xlabel("BFGS step")
    ax.set_ylabel("mean squared error (linear RGB)")
    ax.set_title("Cornell box: wall and light colour from an image")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
