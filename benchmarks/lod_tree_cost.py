"""What a coarser level of detail costs a ray: each LOD level's BVH cost, against the same
scene tessellated to the same triangle count (well-shaped triangles), no timing. (Written when
coarse levels traced slower than level 0 — fans of slivers; welding and Delaunay flips in
`fovjax.scene._lod` fixed that: docs/concepts/scenes.md, "Level of detail".)

    python benchmarks/lod_tree_cost.py                  # atrium 262k, its cached LOD levels
    python benchmarks/lod_tree_cost.py --rays 500       # fewer host-traced rays (faster)

Per level: triangles, geometric error (scene units), triangle shape (longest edge² over the
area of an equilateral triangle with that edge: 1.0 for equilateral, large for slivers; and the
99th-percentile longest edge), the SAH cost of its binary tree (`fovjax.trace`'s builder, the
cost model of that builder: one unit per node visited and per triangle tested, as expected
steps of a ray through the root box, split into inner nodes and leaf triangles), and the mean
steps per closest-hit ray (nodes visited + triangles tested, nearest child first) of rays cast
from the default camera over its field of view, traced on the host through that binary tree —
a deterministic count, not a time. The last rows: `atrium(triangles=N)` at each level's
count, i.e. what a level with well-shaped triangles would cost. The traversal in
`fovjax.trace` walks a 4-wide collapse of the same tree, so its steps are fewer but scale alike.
"""

from __future__ import annotations

import argparse

import numpy as np
from _record import write_record

import fovjax
from fovjax.scene import lod_levels
from fovjax.scene._atrium import min_triangles as atrium_min_triangles
from fovjax.trace import BuildParams
from fovjax.trace._build import build_tree  # the builder itself: the tree the renderer uses


def _area(lo, hi):
    d = np.maximum(hi - lo, 0.0)
    return 2.0 * (d[..., 0] * d[..., 1] + d[..., 1] * d[..., 2] + d[..., 2] * d[..., 0])


def _leaf_sizes(tree, codes):
    start = -1 - codes
    last = np.flatnonzero(tree.leaf_last)
    return last[np.searchsorted(last, start)] - start + 1


def sah_cost(tree) -> tuple[float, float]:
    """(inner, leaf) SAH cost relative to the root box: sum of node areas, and of leaf area x
    triangle count, over the root's area."""
    cl, ch = tree.child_lo.astype(np.float64), tree.child_hi.astype(np.float64)
    root = _area(cl[0].min(axis=0), ch[0].max(axis=0))
    inner = _area(cl.min(axis=1), ch.max(axis=1)).sum() / root
    leaf = 0.0
    for side, codes in ((0, tree.left), (1, tree.right)):
        m = codes < 0
        leaf += (_area(cl[m, side], ch[m, side]) * _leaf_sizes(tree, codes[m])).sum() / root
    return float(inner), float(leaf)


def _slab(o, inv, lo, hi, tmax):
    t0, t1 = (lo - o) * inv, (hi - o) * inv
    near = np.minimum(t0, t1).max()
    far = np.maximum(t0, t1).min()
    return near if (near <= far and far >= 0 and near < tmax) else None


def _hit(o, d, tri):
    """Möller-Trumbore over a few triangles: nearest t > 0 or inf."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - tri[:, 0]
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ d) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    good = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-6)
    return float(t[good].min()) if good.any() else np.inf


def steps_per_ray(tree, tri, origins, dirs) -> float:
    """Mean nodes visited + triangles tested per closest-hit ray, nearest child first."""
    tri = tri.astype(np.float64)
    order = tree.tri_order
    last = np.flatnonzero(tree.leaf_last)
    total = 0
    for o, d in zip(origins, dirs, strict=True):
        inv = 1.0 / np.where(np.abs(d) > 1e-12, d, 1e-12)
        tmax, steps, stack = np.inf, 0, [0]
        while stack:
            node = stack.pop()
            steps += 1
            kids = []
            for side, codes in ((0, tree.left), (1, tree.right)):
                t = _slab(o, inv, tree.child_lo[node, side], tree.child_hi[node, side], tmax)
                if t is not None:
                    kids.append((t, int(codes[node])))
            for t, code in sorted(kids, reverse=True):  # nearest popped first
                if code >= 0:
                    stack.append(code)
                    continue
                if t >= tmax:
                    continue
                start = -1 - code
                end = last[np.searchsorted(last, start)] + 1
                steps += end - start
                tmax = min(tmax, _hit(o, d, tri[order[start:end]]))
        total += steps
    return total / len(origins)


def _rays(scene, n: int, seed: int = 0):
    pose = fovjax.scenes.default_camera(scene)
    eye = np.asarray(pose.position, np.float64)
    fwd = np.asarray(pose.look_at, np.float64) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(pose.up, np.float64))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    half = np.tan(np.radians(pose.vfov_deg) / 2)
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(-half, half, (2, n))
    d = fwd + x[:, None] * right + y[:, None] * up
    return np.repeat(eye[None], n, axis=0), d / np.linalg.norm(d, axis=1, keepdims=True)


def row(name: str, scene, error, origins, dirs) -> list:
    tri = np.asarray(scene.vertices, np.float32)[np.asarray(scene.faces)]
    t64 = tri.astype(np.float64)
    edge = np.linalg.norm(np.roll(t64, -1, axis=1) - t64, axis=2).max(axis=1)
    area = 0.5 * np.linalg.norm(np.cross(t64[:, 1] - t64[:, 0], t64[:, 2] - t64[:, 0]), axis=1)
    shape = edge**2 / np.maximum(area * 4 / np.sqrt(3), 1e-20)
    tree = build_tree(tri.min(axis=1), tri.max(axis=1), BuildParams())
    inner, leaf = sah_cost(tree)
    steps = steps_per_ray(tree, tri, origins, dirs)
    err = "" if error is None else f"{error:.4f}"
    print(
        f"{name:<22} {len(tri):>8,} {err:>8} {np.median(shape):>6.1f} {np.percentile(shape, 90):>6.1f} "
        f"{np.percentile(edge, 99):>7.2f} {inner:>7.1f} {leaf:>6.1f} {inner + leaf:>7.1f} {steps:>7.1f}",
        flush=True,
    )
    return [
        name,
        len(tri),
        None if error is None else round(float(error), 5),
        f"{np.median(shape):.1f} / {np.percentile(shape, 90):.1f}",
        f"{np.percentile(edge, 99):.2f} m",
        f"{inner:.1f} + {leaf:.1f} = {inner + leaf:.1f}",
        round(float(steps), 2),
    ]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triangles", type=int, default=262_000)
    ap.add_argument("--rays", type=int, default=2000)
    args = ap.parse_args(argv)
    scene = fovjax.scenes.atrium(triangles=args.triangles)
    levels = lod_levels(scene)
    origins, dirs = _rays(scene, args.rays)
    print(f"atrium {args.triangles:,}, LOD ratios {levels.ratios}, {args.rays} camera rays (host-traced)")
    print(
        f"{'scene':<22} {'tris':>8} {'error':>8} {'shape':>6} {'p90':>6} {'p99 edge':>7} "
        f"{'SAH in':>7} {'leaf':>6} {'SAH':>7} {'steps':>7}"
    )
    rows = []
    for i, (level, error) in enumerate(zip(levels.scenes, levels.errors, strict=True)):
        rows.append(row(f"level {i} ({levels.ratios[i]:g})", level, error, origins, dirs))
    for n in levels.triangles[1:]:
        if n < atrium_min_triangles():
            continue
        rows.append(row(f"atrium(triangles={n})", fovjax.scenes.atrium(triangles=n), None, origins, dirs))
    cols = ["tree", "triangles", "error (m)", "shape median / p90", "p99 longest edge", "SAH inner + leaf"]
    table = {
        "title": f"Each level's tree: shape, SAH cost, steps per ray ({args.rays} camera rays, host-traced)",
        "columns": [*cols, "steps per ray"],
        "rows": rows,
    }
    write_record("lod_tree_cost", {"tables": [table]})


if __name__ == "__main__":
    main()
