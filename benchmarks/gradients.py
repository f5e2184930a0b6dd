"""Gradients of a frame beside Mitsuba 3's automatic differentiation of the same frame.

    python benchmarks/gradients.py                      # atrium, 2 x 320x256 and 2 x 640x512
    python benchmarks/gradients.py --sizes 160x128 --repeats 3

The loss: the mean squared difference between the stereo frame (Whitted, depth 5, SPP 1,
cell-centre samples) and a target frame rendered with one material's Kd raised by 0.1; its
gradient with respect to every material's Kd and every light's colour. Timed, in one process,
the two renderers taking turns call by call (medians of --repeats after a warm-up that
compiles):
- **fovjax forward**: `jax.jit` of the loss (`render_stereo_image`, the default configuration:
  on a CPU the native integrator);
- **fovjax forward + backward**: `jax.jit(jax.value_and_grad(loss))`: the native forward stores
  each ray's path and the gradient is the reverse pass of its replay
  (`fovjax/render/_replay.py`);
- **fovjax, JAX integrator**: the same with `RenderConfig(integrator="jax")`, where the gradient
  re-runs the forward in the JAX integrator (the way fovjax differentiated before the replay);
- **Mitsuba forward** and **forward + backward**: `benchmarks/mitsuba_frame.py`'s Dr.Jit
  wavefront (`llvm_ad_rgb`) with Kd and the light colours as differentiable arrays; its
  backward (`dr.backward`) walks the graph its forward recorded (hits and shadow answers
  kept: no ray is traced again), the fast way to write it.

Printed: milliseconds, the ratios fovjax / Mitsuba and gradient / forward, and how the
gradients agree: fovjax against Mitsuba, and fovjax against central finite differences of its
own forward on three Kd components (the image is linear in Kd, so the differences are exact up
to rounding). A record is written (`FOVJAX_BENCH_RECORD=0`: none).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import mitsuba_frame as mf  # noqa: E402
from _record import write_record  # noqa: E402

STEP = 0.1  # the target's Kd change
OFF_TARGET = 0.02  # every Kd this far from the scene's: the loss non-zero at every pixel
FD_STEP = 1e-2  # the finite differences' step in Kd (linear: any step is exact up to rounding)
SAME_PATH = 1e-3  # a pixel's largest channel difference between the renderers on the same paths
ADAM_RATE = 0.02


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: a size is WIDTHxHEIGHT, e.g. 320x256") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: width and height must be positive")
    return w, h


def _median_ms(xs) -> float:
    return 1e3 * statistics.median(xs)


class DifferentiableWhitted(mf.MitsubaWhitted):
    """`mitsuba_frame.MitsubaWhitted` with Kd and the light colours as arrays Dr.Jit can
    differentiate."""

    def __init__(self, mi, dr, arrays, config, offset):
        super().__init__(mi, dr, arrays, config, offset)
        self.light_colors = [mi.Vector3f(*color) for _, color, _ in self.lights]
        self.lights = [
            (position, color, is_point)
            for (position, _, is_point), color in zip(self.lights, self.light_colors, strict=True)
        ]

    def parameters(self):
        return [self.kd, *self.light_colors]

    def set_kd(self, kd):
        self.kd = self.mi.Float(np.asarray(kd, np.float32).ravel())

    def loss(self, prepared, target, weights=None):
        """The mean squared difference to `target`, or, with `weights` (0 or 1 per pixel), its
        mean over the pixels weighted 1."""
        dr = self.dr
        image, _ = self.frame(prepared)
        diff = image - target
        squared = dr.square(diff.x) + dr.square(diff.y) + dr.square(diff.z)
        if weights is None:
            return dr.mean(squared) / 3
        return dr.sum(weights * squared) / (3 * dr.sum(weights))


class _Mitsuba:
    """Mitsuba's loss on the benchmark's rays: `forward`, `forward_backward` (optionally over
    pixels weighted 0 or 1), its image, and `adam` steps with Mitsuba's own optimiser."""

    def __init__(self, arrays, rig, config, target_image):
        from fovjax.render import stereo_sample_rays
        from fovjax.render.internal import scene_scale

        self.mi, self.dr = mf.load_mitsuba()
        mi = self.mi
        offset = config.ray_offset * float(scene_scale(arrays))
        self.integrator = DifferentiableWhitted(mi, self.dr, arrays, config, offset)
        self.kd0 = self.integrator.kd
        rays = stereo_sample_rays(rig, None, 1, None)
        self.prepared = self.integrator.prepare(np.asarray(rays.origins), np.asarray(rays.directions))
        # The target in the layout of Mitsuba's image (side by side, row by row).
        self.target = self._vector(target_image)

    def _vector(self, image):
        mi = self.mi
        return mi.Vector3f(*(mi.Float(np.ascontiguousarray(c)) for c in np.asarray(image).reshape(-1, 3).T))

    def image(self) -> np.ndarray:
        """The frame as fovjax lays it out: (H, 2W, 3)."""
        image, _ = self.integrator.frame(self.prepared)
        return np.stack([np.asarray(c) for c in (image.x, image.y, image.z)], axis=-1)

    def forward(self):
        dr = self.dr
        loss = self.integrator.loss(self.prepared, self.target)
        dr.eval(loss)
        dr.sync_thread()
        return loss

    def forward_backward(self, weights=None):
        dr = self.dr
        w = None if weights is None else self.mi.Float(np.ascontiguousarray(weights, np.float32).ravel())
        params = self.integrator.parameters()
        for p in params:
            dr.enable_grad(p)
        loss = self.integrator.loss(self.prepared, self.target, w)
        dr.backward(loss)
        grads = [dr.grad(p) for p in params]
        dr.eval(grads)
        dr.sync_thread()
        for p in params:
            dr.disable_grad(p)
        return loss, grads

    def adam(self, steps: int, rate: float) -> tuple[float, np.ndarray]:
        """`steps` steps of `mi.ad.Adam` on Kd from the scene's Kd: (last loss, Kd)."""
        dr = self.dr
        optimiser = self.mi.ad.Adam(lr=rate)
        optimiser["kd"] = self.mi.Float(self.kd0)
        loss = None
        for _ in range(steps):
            self.integrator.kd = optimiser["kd"]
            loss = self.integrator.loss(self.prepared, self.target)
            dr.backward(loss)
            optimiser.step()
            dr.eval(optimiser["kd"])
        dr.sync_thread()
        kd = np.asarray(optimiser["kd"], np.float64)
        self.integrator.kd = self.kd0
        return float(np.asarray(loss).ravel()[0]), kd


def _fovjax_adam(loss, kd0, light0, scene_in, rate: float):
    """One compiled Adam step on Kd (the update `mi.ad.Adam` makes), and the loop of `steps`:
    (last loss, Kd)."""
    import jax
    import jax.numpy as jnp

    b1, b2, eps = 0.9, 0.999, 1e-8

    @jax.jit
    def step(kd, m, v, t, scene_in):
        value, grad = jax.value_and_grad(loss)(kd, light0, scene_in)
        t = t + 1
        m = b1 * m + (1 - b1) * grad
        v = b2 * v + (1 - b2) * grad * grad
        scale = rate * jnp.sqrt(1 - b2**t) / (1 - b1**t)
        return kd - scale * m / (jnp.sqrt(v) + eps), m, v, t, value

    def run(steps: int):
        kd, m, v, t = kd0, jnp.zeros_like(kd0), jnp.zeros_like(kd0), jnp.zeros((), jnp.float32)
        value = None
        for _ in range(steps):
            kd, m, v, t, value = step(kd, m, v, t, scene_in)
        return float(value), np.asarray(kd, np.float64)

    return run


def run_size(scene, bvh, width, height, args):
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from fovjax.render import RenderConfig, StereoRig, render_stereo_image, scene_arrays

    rig = StereoRig.from_pose(mf_default_camera(scene), eye_width=width, eye_height=height)
    arrays = scene_arrays(scene)
    config = RenderConfig(max_depth=args.max_depth)
    kd0 = jnp.asarray(arrays.kd)
    light0 = jnp.asarray(arrays.light_color)
    # The target: the most-seen material's Kd raised by STEP (through fovjax's forward).
    counts = np.bincount(np.asarray(arrays.face_material), minlength=len(np.asarray(kd0)))
    changed = int(np.argmax(counts))
    target = jax.jit(
        lambda kd: render_stereo_image(eqx.tree_at(lambda s: s.kd, arrays, kd), bvh, rig, config=config)
    )(kd0.at[changed].add(STEP))
    target = jax.block_until_ready(target)

    # The scene's arrays go in as operands (closed over, XLA would fold them as constants).
    scene_in = jax.tree.map(jnp.asarray, arrays)

    def make_loss(cfg):
        def loss(kd, light_color, scene_in, weights=None):
            a = eqx.tree_at(lambda s: (s.kd, s.light_color), scene_in, (kd, light_color))
            squared = (render_stereo_image(a, bvh, rig, config=cfg) - target) ** 2
            if weights is None:
                return jnp.mean(squared)
            return jnp.sum(weights[..., None] * squared) / (3 * jnp.sum(weights))

        return loss

    def bound(fn):
        jitted = jax.jit(fn)
        return lambda kd, light: jitted(kd, light, scene_in)

    loss = make_loss(config)
    fj_forward = bound(loss)
    fj_grad = bound(jax.value_and_grad(loss, argnums=(0, 1)))
    jax_loss = make_loss(RenderConfig(max_depth=args.max_depth, integrator="jax"))
    fj_jax_grad = bound(jax.value_and_grad(jax_loss, argnums=(0, 1)))
    peer = _Mitsuba(arrays, rig, config, target)
    mi_forward, mi_grad = peer.forward, peer.forward_backward

    kd_off = kd0 + OFF_TARGET
    runs = {
        "fovjax_forward": lambda: jax.block_until_ready(fj_forward(kd0, light0)),
        "fovjax_forward_backward": lambda: jax.block_until_ready(fj_grad(kd0, light0)),
        # At the scene's Kd the loss is zero wherever the changed material is not seen, and the
        # native adjoint skips a ray whose cotangent is zero: the same gradient where every
        # pixel's loss is non-zero (every Kd off the target, as along an optimisation).
        "fovjax_forward_backward_everywhere": lambda: jax.block_until_ready(fj_grad(kd_off, light0)),
        "mitsuba_forward": mi_forward,
        "mitsuba_forward_backward": mi_grad,
    }
    if not args.no_jax_integrator:
        runs["fovjax_jax_integrator_forward_backward"] = lambda: jax.block_until_ready(
            fj_jax_grad(kd0, light0)
        )
    out = {"width": width, "height": height, "changed_material": changed}
    for name, fn in runs.items():  # warm-ups: compiles, Dr.Jit's kernels
        t0 = time.perf_counter()
        fn()
        out[f"{name}_first_s"] = time.perf_counter() - t0
    timed = {name: [] for name in runs}
    for _ in range(args.repeats):
        for name, fn in runs.items():
            t0 = time.perf_counter()
            fn()
            timed[name].append(time.perf_counter() - t0)
    for name, xs in timed.items():
        out[f"{name}_ms"] = _median_ms(xs)

    # The gradients and how they agree.
    value, (g_kd, g_light) = fj_grad(kd0, light0)
    mi_value, (mi_kd, *mi_lights) = mi_grad()
    g_kd, g_light = np.asarray(g_kd, np.float64), np.asarray(g_light, np.float64)
    mi_kd = np.asarray(mi_kd, np.float64).reshape(g_kd.shape)
    mi_light = np.stack([np.asarray(c, np.float64).reshape(3) for c in mi_lights])

    def relative(a, b):
        return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-30))

    out["loss_fovjax"] = float(value)
    out["loss_mitsuba"] = float(np.asarray(mi_value).ravel()[0])
    out["kd_gradient_vs_mitsuba"] = relative(g_kd, mi_kd)
    out["light_gradient_vs_mitsuba"] = relative(g_light, mi_light)
    # Away from visibility changes: the loss over the pixels whose colour the two renderers
    # agree on. Where the two traversals disagree on which surface a ray (or its reflection or
    # shadow ray) meets, a pixel's colour differs by the difference of two surfaces' radiance;
    # the same path differs only by float rounding (~1e-6), far below SAME_PATH.
    fj_image = np.asarray(jax.jit(lambda s: render_stereo_image(s, bvh, rig, config=config))(scene_in))
    mi_image = peer.image().reshape(fj_image.shape)
    same = np.max(np.abs(fj_image - mi_image), axis=-1) <= SAME_PATH
    weights = jnp.asarray(same, jnp.float32)
    _, (g_kd_same, g_light_same) = jax.jit(jax.value_and_grad(loss, argnums=(0, 1)))(
        kd0, light0, scene_in, weights
    )
    _, (mi_kd_same, *mi_lights_same) = peer.forward_backward(np.asarray(same, np.float32))
    mi_kd_same = np.asarray(mi_kd_same, np.float64).reshape(g_kd.shape)
    mi_light_same = np.stack([np.asarray(c, np.float64).reshape(3) for c in mi_lights_same])
    out["pixels_where_paths_differ"] = int(np.sum(~same))
    g_kd_same, g_light_same = (np.asarray(g, np.float64) for g in (g_kd_same, g_light_same))
    out["kd_gradient_vs_mitsuba_same_paths"] = relative(g_kd_same, mi_kd_same)
    out["light_gradient_vs_mitsuba_same_paths"] = relative(g_light_same, mi_light_same)
    # Central finite differences of fovjax's forward on the three largest Kd components.
    flat = np.argsort(-np.abs(g_kd).ravel())[:3]
    fd, an = [], []
    for index in flat:
        m, c = np.unravel_index(index, g_kd.shape)
        up = float(fj_forward(kd0.at[m, c].add(FD_STEP), light0))
        down = float(fj_forward(kd0.at[m, c].add(-FD_STEP), light0))
        fd.append((up - down) / (2 * FD_STEP))
        an.append(g_kd[m, c])
    out["kd_gradient_vs_finite_differences"] = relative(np.asarray(an), np.asarray(fd))
    out["ratio_forward_backward"] = out["fovjax_forward_backward_ms"] / out["mitsuba_forward_backward_ms"]
    if args.adam_steps:
        # Recovering the changed material: Adam on every Kd, from the scene's, `adam_steps`
        # steps each (after a warm-up of two steps: compiles, Dr.Jit's kernels).
        fj_adam = _fovjax_adam(loss, kd0, light0, scene_in, ADAM_RATE)
        truth = np.asarray(kd0, np.float64)
        truth[changed] += STEP
        for name, run in (("fovjax", fj_adam), ("mitsuba", lambda n: peer.adam(n, ADAM_RATE))):
            t0 = time.perf_counter()
            run(2)
            out[f"{name}_adam_warm_up_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            last, kd = run(args.adam_steps)
            out[f"{name}_adam_s"] = time.perf_counter() - t0
            out[f"{name}_adam_loss"] = last
            out[f"{name}_adam_kd_error"] = float(np.max(np.abs(kd.reshape(truth.shape) - truth)))
        out["adam_steps"] = args.adam_steps
        out["ratio_adam"] = out["fovjax_adam_s"] / out["mitsuba_adam_s"]
    out["ratio_forward"] = out["fovjax_forward_ms"] / out["mitsuba_forward_ms"]
    out["fovjax_gradient_over_forward"] = out["fovjax_forward_backward_ms"] / out["fovjax_forward_ms"]
    out["fovjax_gradient_everywhere_over_forward"] = (
        out["fovjax_forward_backward_everywhere_ms"] / out["fovjax_forward_ms"]
    )
    out["mitsuba_gradient_over_forward"] = out["mitsuba_forward_backward_ms"] / out["mitsuba_forward_ms"]
    return out


def _rounded(ms):
    return None if ms is None else round(ms, 1)


def mf_default_camera(scene):
    import fovjax

    return fovjax.scenes.default_camera(scene)


def report(r) -> None:
    print(f"2 x {r['width']}x{r['height']} (target: material {r['changed_material']}'s Kd + {STEP})")
    rows = [
        ("fovjax forward", "fovjax_forward_ms"),
        ("fovjax forward + backward", "fovjax_forward_backward_ms"),
        ("fovjax forward + backward, every pixel off target", "fovjax_forward_backward_everywhere_ms"),
        ("fovjax, JAX integrator, forward + backward", "fovjax_jax_integrator_forward_backward_ms"),
        ("Mitsuba forward", "mitsuba_forward_ms"),
        ("Mitsuba forward + backward", "mitsuba_forward_backward_ms"),
    ]
    for label, key in rows:
        if key in r:
            print(f"  {label:44s} {r[key]:9.1f} ms")
    ratios = (r["ratio_forward"], r["ratio_forward_backward"])
    print("  fovjax / Mitsuba: forward {:.2f}, forward + backward {:.2f}".format(*ratios))
    everywhere = r.get("fovjax_gradient_everywhere_over_forward")
    print(
        f"  gradient / forward: fovjax {r['fovjax_gradient_over_forward']:.2f}"
        + ("" if everywhere is None else f" ({everywhere:.2f} every pixel off target)")
        + f", Mitsuba {r['mitsuba_gradient_over_forward']:.2f}"
    )
    print(
        "  gradients, max relative difference: "
        f"Kd vs Mitsuba {r['kd_gradient_vs_mitsuba']:.2e}, "
        f"light colour vs Mitsuba {r['light_gradient_vs_mitsuba']:.2e}, "
        f"Kd vs finite differences {r['kd_gradient_vs_finite_differences']:.2e}"
    )
    print(
        f"  away from visibility changes ({r['pixels_where_paths_differ']} pixels left out): "
        f"Kd vs Mitsuba {r['kd_gradient_vs_mitsuba_same_paths']:.2e}, "
        f"light colour vs Mitsuba {r['light_gradient_vs_mitsuba_same_paths']:.2e}"
    )
    if "adam_steps" in r:
        print(
            f"  {r['adam_steps']} Adam steps on Kd: fovjax {r['fovjax_adam_s']:.2f} s "
            f"(loss {r['fovjax_adam_loss']:.2e}, Kd error {r['fovjax_adam_kd_error']:.3f}), "
            f"Mitsuba {r['mitsuba_adam_s']:.2f} s (loss {r['mitsuba_adam_loss']:.2e}, "
            f"Kd error {r['mitsuba_adam_kd_error']:.3f}); fovjax / Mitsuba {r['ratio_adam']:.2f}"
        )


COLUMNS = [
    "size (per eye)",
    "fovjax fwd ms",
    "fovjax fwd+bwd ms",
    "fovjax JAX integrator fwd+bwd ms",
    "Mitsuba fwd ms",
    "Mitsuba fwd+bwd ms",
    "fwd+bwd fovjax / Mitsuba",
    "gradient / forward: fovjax",
    "gradient / forward: Mitsuba",
    "Kd gradient vs Mitsuba",
    "Kd gradient vs finite differences",
    "Kd gradient vs Mitsuba, away from visibility changes",
    "Adam steps s: fovjax",
    "Adam steps s: Mitsuba",
]


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="atrium", help="a built-in scene (fovjax.scenes.BUILTIN)")
    ap.add_argument("--sizes", type=_size, nargs="+", default=[(320, 256), (640, 512)], metavar="WxH")
    ap.add_argument("--max-depth", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--adam-steps", type=int, default=50, help="Adam steps timed per size (0: none)")
    ap.add_argument(
        "--no-jax-integrator",
        action="store_true",
        help="leave out the JAX integrator's gradient (the slow one)",
    )
    args = ap.parse_args(argv)
    if args.repeats < 1:
        ap.error(f"--repeats {args.repeats}: at least 1")
    if args.adam_steps < 0:
        ap.error(f"--adam-steps {args.adam_steps}: at least 0")
    if args.max_depth < 0:
        ap.error(f"--max-depth {args.max_depth}: at least 0")
    import fovjax

    if args.scene not in fovjax.scenes.BUILTIN:
        ap.error(f"--scene {args.scene!r}: one of {sorted(fovjax.scenes.BUILTIN)}")
    try:
        mf.load_mitsuba()
    except mf.Unavailable as exc:
        print(f"gradients: Mitsuba 3 cannot run here: {exc}", file=sys.stderr)
        raise SystemExit(1) from None
    scene = fovjax.scenes.BUILTIN[args.scene]()
    bvh = fovjax.trace.build_bvh(scene)
    rows = []
    for width, height in args.sizes:
        r = run_size(scene, bvh, width, height, args)
        report(r)
        rows.append(r)
    table = {
        "title": (
            f"Gradients of an image loss (Kd, lights), {args.scene}, depth {args.max_depth}, SPP 1; "
            f"{args.adam_steps} Adam steps on Kd"
        ),
        "columns": COLUMNS,
        "rows": [
            [
                f"{r['width']}x{r['height']}",
                round(r["fovjax_forward_ms"], 1),
                round(r["fovjax_forward_backward_ms"], 1),
                _rounded(r.get("fovjax_jax_integrator_forward_backward_ms")),
                round(r["mitsuba_forward_ms"], 1),
                round(r["mitsuba_forward_backward_ms"], 1),
                round(r["ratio_forward_backward"], 2),
                round(r["fovjax_gradient_over_forward"], 2),
                round(r["mitsuba_gradient_over_forward"], 2),
                f"{r['kd_gradient_vs_mitsuba']:.1e}",
                f"{r['kd_gradient_vs_finite_differences']:.1e}",
                f"{r['kd_gradient_vs_mitsuba_same_paths']:.1e}",
                None if "adam_steps" not in r else round(r["fovjax_adam_s"], 2),
                None if "adam_steps" not in r else round(r["mitsuba_adam_s"], 2),
            ]
            for r in rows
        ],
    }
    figures = {"rows": rows, "tables": [table]}
    write_record("gradients", figures)
    return figures


if __name__ == "__main__":
    main()
