"""The thesis's tables 2-5 re-measured: rays per frame and frame rate, foveated against full.

    python benchmarks/foveation.py                 # 640x512 per eye (a quarter of the pixels)
    python benchmarks/foveation.py --full          # the thesis's 2 x 1280x1024
    python benchmarks/foveation.py --spp 1 4       # a subset of SPP values
    python benchmarks/foveation.py --backend embree
    python benchmarks/foveation.py --profile       # per-stage ms and % of a foveated and a full frame
    python benchmarks/foveation.py --speedup       # the done-when ratios (off-centre gaze, medians)
    python benchmarks/foveation.py --variants --spp 4   # foveated default vs variants, same run
    python benchmarks/foveation.py --variants --spp 1 --which batch   # only variants named so
    python benchmarks/foveation.py --variants --full --spp 1 --which output  # every per-pixel output returned
    python benchmarks/foveation.py --floor 2097152   # fixed cost of a slot budget, 4,096 live rays
    python benchmarks/foveation.py --full --rule thesis-measured   # the sampling Table 2 implies
    python benchmarks/foveation.py --full --rule thesis-measured --count-only  # samples, no render
    python benchmarks/foveation.py --regions       # region shares under each reading (issue 17)
    python benchmarks/foveation.py --preset thesis --size 320 256 --spp 1 4   # tables 2-5, the
                                                   # thesis's configuration, written to a record

`--rule thesis-measured` uses `Foveation.thesis_measured` (that rule, and the planar eccentricity
at the SX111's 16 pixels per degree); `--count-only` prints Tables 2-3 from the samples each
frame traces (primary rays, no shading), foveated against full, without rendering.
`--preset thesis` renders every frame, foveated and full, in the thesis's whole configuration
(`fovjax.foveate.thesis_preset`: its regions, sampling, blur, shading, depth 5) and writes the
tables, the thesis's beside them, to a record.

For every SPP and every thesis (fovea, periphery) pair plus full rendering, on the atrium, in
stereo, gaze at each display's centre, head still: rays per frame (primary + shadow +
reflection rays actually traced), its reduction against full, frames per second (median of
--repeats timed frames after a warm-up, each with a fresh key) and the speed-up, printed in the
layout of the thesis's tables with the thesis's own figures beside ours. Compile time is
reported separately and is not in the frame times. The machine is noisy: read the ratios.
"""

from __future__ import annotations

import argparse
import functools
import resource
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import fovjax
from fovjax.foveate import DIAGNOSTICS, THESIS_PAIRS, Foveation, render_foveated, thesis_preset
from fovjax.render import RenderConfig, StereoRig, render_stereo, scene_arrays
from fovjax.render.internal import scene_scale
from fovjax.trace import build_bvh

SPPS = (1, 4, 9, 16)
# The timed foveated frames return the image and the counts only, as a frame loop asks
# (`render_foveated(diagnostics=())`: no screen-sized mask, regions, eccentricity or pre-fill
# means; `--variants --which output` times the frame with all of them beside it).
FRAME = {"diagnostics": ()}
# Thesis tables 2 and 4 (Sponza, RTX 2060, OptiX, 2560x1024): rays per frame (1e6) and FPS.
THESIS_RPF = {
    (5.0, 10.0): (4.47, 5.47, 7.13, 9.46),
    (7.5, 15.0): (4.49, 6.74, 10.48, 15.71),
    (10.0, 20.0): (4.52, 8.53, 15.20, 24.54),
    (12.5, 25.0): (4.56, 10.76, 21.09, 35.55),
    (15.0, 30.0): (4.60, 13.11, 27.30, 47.17),
    "full": (5.21, 20.85, 46.91, 83.39),
}
THESIS_FPS = {
    (5.0, 10.0): (60.16, 57.84, 53.79, 48.15),
    (7.5, 15.0): (59.98, 54.02, 46.22, 39.40),
    (10.0, 20.0): (59.74, 50.27, 40.29, 31.57),
    (12.5, 25.0): (59.07, 48.39, 34.29, 25.11),
    (15.0, 30.0): (58.64, 47.26, 28.90, 19.84),
    "full": (103.88, 26.12, 17.24, 10.05),
}


def measure(render, repeats):
    frames = [render(jax.random.key(10_000))]  # warm-up (and compile)
    compile_s = frames[0].stats.compile_seconds
    times = []
    for i in range(repeats):
        frame = render(jax.random.key(i))
        times.append(frame.stats.render_seconds)
        frames.append(frame)
    rays = statistics.median(f.stats.rays for f in frames[1:])
    return rays, statistics.median(times), compile_s, frames[-1]


def speedup(ratio):
    return f"{pct((ratio - 1) * 100)} {ratio:4.1f}x"


def pct(x):
    return f"{x:+7.1f}%"


# ---- --profile: per-stage times -----------------------------------------------------------

# An off-centre gaze (each eye looking up and to the left of its display centre).
OFF_CENTRE = ((0.32, 0.38), (0.28, 0.38))


def _timed(fn, *args, repeats):
    """Compile `fn` alone, then the median ms of `repeats` calls (block_until_ready each)."""
    jitted = fn if hasattr(fn, "lower") else jax.jit(fn)
    out = jax.block_until_ready(jitted(*args))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(jitted(*args))
        times.append(time.perf_counter() - t0)
    return out, 1000 * statistics.median(times)


def _radiance_stages(arrays, bvh, o, d, active, config, rows, repeats):
    """The integrator's stages on the given rays, each compiled and timed on its own: primary
    traversal, shading (surfaces, shadow-ray setup, lights, reflection spawn), shadow rays, and
    each reflection bounce. Appends (stage, ms) to `rows`; returns the traced contribution."""
    from fovjax.render._integrator import (
        _append,
        _bands,
        _finish_shading,
        _queue_of,
        _reflection_level,
        _surface_and_shadow_rays,
        _trace_primary,
        _trace_shadows,
        _usable_packet,
    )
    from fovjax.render._vec import normalize

    batch = active.shape
    packet = _usable_packet(config.packet, len(batch))
    kw = {"backend": config.backend}
    offset = lambda a: config.ray_offset * scene_scale(a)  # noqa: E731
    d = jax.jit(normalize)(d)
    hit, t = _timed(
        lambda a, b, o, d, act: _trace_primary(a, b, o, d, act, packet=packet, **kw),
        arrays,
        bvh,
        o,
        d,
        active,
        repeats=repeats,
    )
    rows.append(("primary traversal", t))
    (surface, rays), t_setup = _timed(
        lambda a, hit, d, act: _surface_and_shadow_rays(a, hit, d, act, offset(a)),
        arrays,
        hit,
        d,
        active,
        repeats=repeats,
    )
    blocked, t = _timed(lambda b, r: _trace_shadows(b, r, packet, config.backend), bvh, rays, repeats=repeats)
    (contribution, state), t_finish = _timed(
        lambda a, s, d, act, r, bl: _finish_shading(
            a,
            s,
            d,
            act,
            jnp.ones(batch + (3,), jnp.float32),
            r,
            bl,
            offset=offset(a),
            spawn=config.max_depth > 0,
        ),
        arrays,
        surface,
        d,
        active,
        rays,
        blocked,
        repeats=repeats,
    )
    rows.append(("shading (surfaces, lights, spawn)", t_setup + t_finish))
    rows.append(("shadow rays (depth 0)", t))
    if config.max_depth == 0:
        return contribution
    n = int(np.prod(batch))
    band, count = _bands(batch, config)
    size = int(np.prod(band))
    capacity = (count + 1) * size

    def queue_of(contribution, state):
        """The first reflection level's rays, compacted into a queue (the frame does this band
        by band)."""
        o2, d2, w2, alive2 = (x.reshape((n,) + x.shape[len(batch) :]) for x in state)
        empty = _queue_of(capacity)
        pad = lambda x: jnp.pad(x, ((0, capacity - n),) + ((0, 0),) * (x.ndim - 1))  # noqa: E731
        queue, n_q = _append(
            empty, 0, (pad(o2), pad(d2), pad(w2), jnp.arange(capacity, dtype=jnp.int32)), pad(alive2)
        )
        return pad(contribution.reshape(n, 3)), queue, n_q

    (total, queue, n_q), t0 = _timed(queue_of, contribution, state, repeats=repeats)
    other = jax.tree.map(jnp.zeros_like, queue)
    bounce = jax.jit(
        lambda a, b, tot, src, n_src, dst, k: _reflection_level(
            a, b, tot, src, n_src, dst, k, offset=offset(a), config=config, size=size
        )
    )
    for depth in range(1, config.max_depth + 1):
        rays = int(n_q)
        (total, other, n_q, _), t = _timed(
            bounce, arrays, bvh, total, queue, n_q, other, jnp.int32(depth), repeats=repeats
        )
        queue, other = other, queue
        rows.append((f"reflection bounce {depth}", t + (t0 if depth == 1 else 0)))
        rows.append((f"  (bounce {depth} rays)", rays))
    return total[:n].reshape(batch + (3,))


def _chunked_stages(arrays, bvh, rays_at, n_live, n_slots, config, rows, repeats):
    """The chunked integrator's stages (`radiance_in_chunks`), each compiled and timed on its
    own over the live chunks: primary traversal, shadow rays of the primary hits, the rest of
    the primary level (shading, reflection spawn and queueing), each reflection bounce."""
    from fovjax.render._integrator import (
        _batch,
        _chunks,
        _level_sizes,
        _packet_of,
        _primary_level,
        _queue_level,
        _surface_and_shadow_rays,
        _trace_primary,
        _trace_shadows,
    )
    from fovjax.render._vec import normalize
    from fovjax.render.internal import chunk_loop
    from fovjax.trace import Hit

    chunks = _chunks(n_slots, config)
    size = chunks.size
    packet = _packet_of(config)
    offset = lambda a: config.ray_offset * scene_scale(a)  # noqa: E731
    lanes = jnp.arange(size, dtype=jnp.int32)

    def hits(a, b, n):
        def body(buf, first):
            o, d = rays_at(first, size)
            hit = _trace_primary(
                a, b, o, normalize(d), first + lanes < n, packet=packet, backend=config.backend
            )
            return tuple(
                jax.lax.dynamic_update_slice_in_dim(x, y, first, 0) for x, y in zip(buf, hit, strict=True)
            )

        init = (
            jnp.zeros(chunks.padded),
            jnp.zeros(chunks.padded, jnp.int32),
            jnp.zeros(chunks.padded),
            jnp.zeros(chunks.padded),
        )
        return chunk_loop(chunks.count, size, n, body, init)

    hit, t = _timed(hits, arrays, bvh, n_live, repeats=repeats)
    rows.append(("primary traversal", t))

    def shadow_stage(a, b, hit, n, trace):
        def body(count, first):
            o, d = rays_at(first, size)
            h = Hit(*(jax.lax.dynamic_slice_in_dim(x, first, size) for x in hit))
            _, rays = _surface_and_shadow_rays(a, h, normalize(d), first + lanes < n, offset(a))
            if trace:
                blocked = _trace_shadows(b, rays, packet, config.backend)
                return count + jnp.sum(blocked)
            return count + jnp.sum(rays.tmax)

        return chunk_loop(chunks.count, size, n, body, jnp.float32(0))

    _, t_setup = _timed(
        lambda a, b, h, n: shadow_stage(a, b, h, n, False), arrays, bvh, hit, n_live, repeats=repeats
    )
    _, t_with = _timed(
        lambda a, b, h, n: shadow_stage(a, b, h, n, True), arrays, bvh, hit, n_live, repeats=repeats
    )
    # The program takes the slots through every level a depth batch at a time; the stages
    # below time the first batch (every live slot when they fit in one, as at 5°/10°).
    batch = _batch(chunks, config)
    if int(n_live) > batch.padded:
        print(f"    (profile: the first depth batch of {batch.padded:,} slots of {int(n_live):,})")
    (total, queue, n_q, _, _), t_level = _timed(
        lambda a, b, n: _primary_level(
            a, b, rays_at, n, chunks, offset=offset(a), config=config, count=batch.count
        ),
        arrays,
        bvh,
        n_live,
        repeats=repeats,
    )
    rows.append(("shading (surfaces, lights, spawn)", max(t_level - t - (t_with - t_setup), 0.0)))
    rows.append(("shadow rays (depth 0)", max(t_with - t_setup, 0.0)))
    first, _ = _level_sizes(chunks, config)
    bounces = [
        jax.jit(
            lambda a, b, tot, q, n, k, size=size: _queue_level(
                a, b, tot, q, n, k, chunks, offset=offset(a), config=config, size=size
            )
        )
        for size in (first, None)  # the first level's chunks, the later levels'
    ]
    for depth in range(1, config.max_depth + 1):
        n_rays = int(n_q)
        (total, queue, n_q, _), t = _timed(
            bounces[depth > 1], arrays, bvh, total, queue, n_q, jnp.int32(depth), repeats=repeats
        )
        rows.append((f"reflection bounce {depth}", t))
        rows.append((f"  (bounce {depth} rays)", n_rays))
    return total


def profile_foveated(arrays, bvh, rig, angles, gaze, key, foveation, config, repeats):
    from fovjax.foveate._api import _budget_for
    from fovjax.foveate._frame import (
        accumulate,
        eccentricities,
        fill_and_blur_eyes,
        select_samples,
        slot_rays,
        traced_count,
        traced_mask,
    )
    from fovjax.foveate._positions import positions_at
    from fovjax.render._integrator import _chunks

    h, w, spp = rig.eye_height, rig.eye_width, foveation.spp
    budget = _budget_for(rig, angles, foveation)
    chunks = _chunks(budget, config)
    rows = []
    ecc, t = _timed(
        lambda r, p, g, f: eccentricities(r.eye_cameras(p), g, f),
        rig,
        angles,
        gaze,
        foveation,
        repeats=repeats,
    )
    rows.append(("region / eccentricity", t))

    def sample(e, k, f):
        sel = select_samples(e, k, foveation=f, budget=budget)
        if chunks.padded > sel.order.shape[0]:
            sel = sel._replace(order=jnp.pad(sel.order, (0, chunks.padded - sel.order.shape[0])))
        return sel

    sel, t = _timed(sample, ecc, key, foveation, repeats=repeats)
    rows.append(("sampling + compaction (+ ray generation)", t))
    cameras = rig.eye_cameras(angles)
    # As the frame: the slots' sub-pixel positions computed for the traced samples only (in
    # the primary traversal's chunks).
    positions = functools.partial(positions_at, key, spp=spp, h=h, w=w)

    def rays_at(first, size):
        slots = jax.lax.dynamic_slice_in_dim(sel.order, first, size)
        return slot_rays(cameras, positions, slots, spp=spp, h=h, w=w)

    total = _chunked_stages(arrays, bvh, rays_at, sel.n_traced, budget, config, rows, repeats)

    def finish(tot, s, f):
        mask = traced_mask(s, budget)
        n = traced_count(mask, spp)
        prefill, _, _ = accumulate(tot, s, n, spp=spp, h=h, w=w, size=chunks.size, bad_color=config.bad_color)
        return fill_and_blur_eyes(prefill, n, s, f)

    _, t = _timed(finish, total, sel, foveation, repeats=repeats)
    rows.append(("accumulate + fill / blur", t))
    return rows


def profile_full(arrays, bvh, rig, angles, key, spp, config, repeats):
    from fovjax.render import resolve, side_by_side, stereo_sample_rays

    rows = []
    rays, t = _timed(lambda r, p, k: stereo_sample_rays(r, p, spp, k), rig, angles, key, repeats=repeats)
    rows.append(("sampling + compaction (+ ray generation)", t))
    active = jnp.ones(rays.directions.shape[:-1], bool)
    rgb = _radiance_stages(arrays, bvh, rays.origins, rays.directions, active, config, rows, repeats)
    _, t = _timed(lambda c: side_by_side(resolve(c)[0]), rgb, repeats=repeats)
    rows.append(("accumulate + fill / blur", t))
    return rows


def _whole(render, repeats):
    """Median of the compiled program's own time and of the host overhead around it (argument
    conversion, transfers, statistics), over `repeats` frames after a warm-up."""
    frame = render(jax.random.key(10_000))
    print(f"    (compile {frame.stats.compile_seconds:.1f} s)", flush=True)
    programs, hosts = [], []
    for i in range(repeats):
        t0 = time.perf_counter()
        frame = render(jax.random.key(i))
        wall = time.perf_counter() - t0
        programs.append(frame.stats.render_seconds)
        hosts.append(wall - frame.stats.render_seconds)
    return 1000 * statistics.median(programs), 1000 * statistics.median(hosts), frame


def profile(scene, bvh, rig, config, spp, pair, repeats):
    """Per-stage table of a foveated and a full frame (gaze off-centre, head still)."""
    arrays = scene_arrays(scene, background=config.background)
    angles = np.zeros(3, np.float32)
    gaze = np.asarray(OFF_CENTRE, np.float32)
    key = jax.random.key(1)
    foveation = Foveation.thesis(pair, spp=spp)
    fov_rows = profile_foveated(arrays, bvh, rig, angles, gaze, key, foveation, config, repeats)
    full_rows = profile_full(arrays, bvh, rig, angles, key, spp, config, repeats)
    fov_prog, fov_host, fov_frame = _whole(
        lambda k: render_foveated(
            scene, rig, gaze=OFF_CENTRE, foveation=foveation, key=k, config=config, bvh=bvh, **FRAME
        ),
        repeats,
    )
    full_prog, full_host, full_frame = _whole(
        lambda k: render_stereo(scene, rig, spp=spp, key=k, config=config, bvh=bvh), repeats
    )
    fov_rows.append(("host: arguments, transfers, stats", fov_host))
    full_rows.append(("host: arguments, transfers, stats", full_host))
    fd, ud = dict(fov_rows), dict(full_rows)
    counts = {n: (fd.get(n), ud.get(n)) for n, _ in fov_rows + full_rows if "rays)" in n}
    fov = {n: t for n, t in fov_rows if n not in counts}
    full = {n: t for n, t in full_rows if n not in counts}
    names = list(dict.fromkeys([n for n, _ in fov_rows] + [n for n, _ in full_rows]))
    total_fov, total_full = sum(fov.values()), sum(full.values())
    print(
        f"\nPer-stage profile, 2 x {rig.eye_width}x{rig.eye_height}, SPP {spp}, "
        f"foveated {pair[0]}°/{pair[1]}° "
        f"vs full, gaze {OFF_CENTRE}; each stage compiled on its own and timed on the same inputs "
        f"(median of {repeats}); the real frame is one fused program (its time below)."
    )
    print(f"{'stage':48s}{'foveated ms':>12s}{'%':>7s}{'full ms':>12s}{'%':>7s}")

    def cell(table, total, name):
        return (
            f"{table[name]:12.1f}{100 * table[name] / total:7.1f}" if name in table else f"{'-':>12s}{'':>7s}"
        )

    for name in names:
        if name in counts:
            a, b = ("-" if x is None else f"{x:,}" for x in counts[name])
            print(f"{name:48s}{a:>12s}{'':7s}{b:>12s}")
        else:
            print(f"{name:48s}{cell(fov, total_fov, name)}{cell(full, total_full, name)}")
    print(f"{'sum of stages':48s}{total_fov:12.1f}{100.0:7.1f}{total_full:12.1f}{100.0:7.1f}")
    print(f"{'the fused program (render_seconds)':48s}{fov_prog:12.1f}{'':7s}{full_prog:12.1f}")
    fr, rr = fov_frame.stats.rays, full_frame.stats.rays
    print(
        f"rays traced: foveated {fr:,} ({fov_frame.stats.primary_rays:,} primary), full {rr:,} "
        f"({full_frame.stats.primary_rays:,} primary): {fr / rr:.1%} of the rays in "
        f"{fov_prog / full_prog:.1%} "
        f"of the time; cost per ray foveated / full = {(fov_prog / fr) / (full_prog / rr):.2f}x"
    )
    return {
        "profile": {"foveated_ms": fov_rows, "full_ms": full_rows},
        "fused_program_ms": {"foveated": fov_prog, "full": full_prog},
        "rays": {"foveated": fr, "full": rr},
        "backend": config.backend,
        "eye": [rig.eye_width, rig.eye_height],
        "spp": spp,
        "pair": pair,
    }


def foveation_tables(out: dict) -> list[dict]:
    """A --speedup or --profile result as the Performance page's table."""
    w, h = out["eye"]
    fovea, periphery = out["pair"]
    where = f"2 × {w}×{h}, foveated {fovea:g}°/{periphery:g}° at an off-centre gaze, backend {out['backend']}"
    if "speedup" in out:
        rows = [
            [
                r["spp"],
                round(r["foveated_ms"], 1),
                round(r["full_ms"], 1),
                r["foveated_rays"],
                r["full_rays"],
                round(r["speedup"], 2),
                round(r["cost_per_ray_foveated_over_full"], 2),
            ]
            for r in out["speedup"]
        ]
        columns = [
            "SPP",
            "foveated ms",
            "full ms",
            "foveated rays",
            "full rays",
            "speed-up",
            "cost per traced ray, foveated / full",
        ]
        return [
            {"title": f"Foveated against full frames, {where} (medians)", "columns": columns, "rows": rows}
        ]
    fov, full = dict(out["profile"]["foveated_ms"]), dict(out["profile"]["full_ms"])
    names = list(dict.fromkeys([*fov, *full]))
    rows = [[n.strip(), *("" if t.get(n) is None else round(t[n], 1) for t in (fov, full))] for n in names]
    fused = out["fused_program_ms"]
    rows.append(["the fused program (the frame)", round(fused["foveated"], 1), round(fused["full"], 1)])
    title = f"Per-stage profile, {where}, SPP {out['spp']}: ms (the rows in parentheses count rays)"
    return [{"title": title, "columns": ["stage", "foveated", "full"], "rows": rows}]


def _program_memory() -> str:
    """Temporaries and outputs (MiB) of each compiled frame program so far, by entry point
    (`compiled.memory_analysis()`; on a CPU the temporaries are allocated, and their pages
    faulted in, on every call)."""
    from fovjax.render._frame import _COMPILED

    parts = []
    for key, compiled in _COMPILED.items():
        m = compiled.memory_analysis()
        if m is not None:
            temp, out = m.temp_size_in_bytes / 2**20, m.output_size_in_bytes / 2**20
            parts.append(f"{key[0]}: temp {temp:.1f} MiB, out {out:.1f} MiB")
    return "; ".join(parts)


def speedup_table(scene, bvh, rig, config, spps, pair, repeats):
    """The done-when ratios of issue 12: foveated (off-centre gaze) against the full frame, the
    medians of `repeats` frames each after a warm-up, both in this run; and recompiles when the
    thresholds change within the maximum."""
    f_of = lambda spp: Foveation.thesis(pair, spp=spp)  # noqa: E731
    print(
        f"\nSpeed-up, 2 x {rig.eye_width}x{rig.eye_height}, foveated {pair[0]}°/{pair[1]}° "
        f"at gaze {OFF_CENTRE} "
        f"vs full, median of {repeats} frames (fresh key each)"
    )
    rows = []
    for spp in spps:
        fov_render = lambda k, spp=spp: render_foveated(  # noqa: E731
            scene, rig, gaze=OFF_CENTRE, foveation=f_of(spp), key=k, config=config, bvh=bvh, **FRAME
        )
        full_render = lambda k, spp=spp: render_stereo(  # noqa: E731
            scene, rig, spp=spp, key=k, config=config, bvh=bvh
        )
        # Warm-up (compile), then foveated and full frames alternately, so that the load of
        # this shared machine falls on both alike.
        warm = fov_render(jax.random.key(10_000)), full_render(jax.random.key(10_000))
        print(
            f"    SPP {spp}: compile foveated {warm[0].stats.compile_seconds:.1f} s, "
            f"full {warm[1].stats.compile_seconds:.1f} s",
            flush=True,
        )
        print(f"    SPP {spp}: program memory {_program_memory()}", flush=True)
        fov_ts, full_ts, fov_faults, full_faults = [], [], [], []
        for i in range(repeats):
            f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            fov = fov_render(jax.random.key(i))
            f1 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            full = full_render(jax.random.key(i))
            full_faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f1)
            fov_faults.append(f1 - f0)
            fov_ts.append(fov.stats.render_seconds)
            full_ts.append(full.stats.render_seconds)
        fov_t, full_t = 1000 * statistics.median(fov_ts), 1000 * statistics.median(full_ts)
        first = render_foveated(
            scene,
            rig,
            gaze=OFF_CENTRE,
            foveation=Foveation.thesis((7.5, 15.0), spp=spp),
            key=jax.random.key(99),
            config=config,
            bvh=bvh,
            **FRAME,
        )
        per_ray = (fov_t / fov.stats.rays) / (full_t / full.stats.rays)
        print(
            f"  SPP {spp}: foveated {fov_t:8.1f} ms ({fov.stats.rays:,} rays)  full {full_t:8.1f} ms "
            f"({full.stats.rays:,} rays)  speed-up {full_t / fov_t:5.2f}x  cost per traced ray "
            f"foveated/full {per_ray:4.2f}x  ({fov.stats.rays / full.stats.rays:.1%} of the rays); "
            f"7.5°/15° next: compile {first.stats.compile_seconds:.1f} s\n"
            f"    frames ms: foveated {[round(1000 * t) for t in fov_ts]}, "
            f"full {[round(1000 * t) for t in full_ts]}; minor page faults per frame (fresh "
            f"memory, each a kernel entry on a CPU): foveated {statistics.median(fov_faults):,.0f}, "
            f"full {statistics.median(full_faults):,.0f}"
        )
        sys.stdout.flush()
        rows.append(
            {
                "spp": spp,
                "foveated_ms": fov_t,
                "full_ms": full_t,
                "foveated_rays": fov.stats.rays,
                "full_rays": full.stats.rays,
                "speedup": full_t / fov_t,
                "cost_per_ray_foveated_over_full": per_ray,
                "compile_s": {
                    "foveated": warm[0].stats.compile_seconds,
                    "full": warm[1].stats.compile_seconds,
                },
                "frames_ms": {"foveated": [1000 * t for t in fov_ts], "full": [1000 * t for t in full_ts]},
            }
        )
    return {"speedup": rows, "backend": config.backend, "eye": [rig.eye_width, rig.eye_height], "pair": pair}


def variants_table(scene, bvh, rig, config, spps, pair, repeats, which=()):
    """Foveated frames of the default configuration against variants of it, in the same run:
    compile each, then one frame of each in turn (so the machine's load falls on all alike),
    medians of the frame time and of this process's CPU time (less sensitive to other jobs on
    a shared machine), and each variant's ratio to the default; and the minor page faults
    per frame (fresh memory the program touches: on a CPU each costs kernel time)."""
    import dataclasses
    import resource

    # name: (RenderConfig changes, Foveation changes, render_foveated arguments)
    variants = {
        "default": ({}, {}, FRAME),
        "every bounce in 4096-ray chunks": ({"first_bounce_chunk_size": None}, {}, FRAME),
        "every bounce in 16384-ray chunks": (
            {"first_bounce_chunk_size": None, "queue_chunk_size": 16384},
            {},
            FRAME,
        ),
        "fovea tile + pixel grid (packets)": ({}, {"fovea_tile_deg": pair[0], "grid_tile": True}, FRAME),
        "one depth batch of every slot (before)": ({"depth_batch_size": None}, {}, FRAME),
        "every per-pixel output (before)": ({}, {}, {"diagnostics": DIAGNOSTICS}),
    }
    if which:  # the default and the variants whose names contain any of `which`
        variants = {n: v for n, v in variants.items() if n == "default" or any(w in n for w in which)}
    print(
        f"\nVariants, 2 x {rig.eye_width}x{rig.eye_height}, foveated {pair[0]}°/{pair[1]}° at gaze "
        f"{OFF_CENTRE}, median of {repeats} frames each (fresh key each)"
    )
    for spp in spps:

        def render(name, k, spp=spp):
            c, f, r = variants[name]
            foveation = Foveation.thesis(pair, spp=spp, **f)
            cfg = dataclasses.replace(config, **c)
            return render_foveated(
                scene, rig, gaze=OFF_CENTRE, foveation=foveation, key=k, config=cfg, bvh=bvh, **r
            )

        for name in variants:
            warm = render(name, jax.random.key(10_000))
            print(f"    SPP {spp} {name}: compile {warm.stats.compile_seconds:.1f} s", flush=True)
        wall = {n: [] for n in variants}
        cpu = {n: [] for n in variants}
        faults = {n: [] for n in variants}
        rays = {}
        for i in range(repeats):
            for name in variants:
                c0, f0 = time.process_time(), resource.getrusage(resource.RUSAGE_SELF).ru_minflt
                frame = render(name, jax.random.key(i))
                cpu[name].append(time.process_time() - c0)
                faults[name].append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
                wall[name].append(frame.stats.render_seconds)
                rays[name] = frame.stats.rays
        base_w, base_c = statistics.median(wall["default"]), statistics.median(cpu["default"])
        for name in variants:
            w_ms, c_ms = statistics.median(wall[name]), statistics.median(cpu[name])
            print(
                f"  SPP {spp} {name:36s} {1000 * w_ms:8.1f} ms ({w_ms / base_w:5.2f}x default), "
                f"CPU {1000 * c_ms:8.1f} ms ({c_ms / base_c:5.2f}x), {rays[name]:,} rays, "
                f"{statistics.median(faults[name]):,.0f} page faults; "
                f"frames ms {[round(1000 * t) for t in wall[name]]}"
            )
        sys.stdout.flush()


def floor_table(scene, bvh, config, n_slots, repeats):
    """The fixed cost of a static slot budget: `radiance_in_chunks` on 4,096 live camera rays
    (depth `config.max_depth`) among `n_slots` slots, with the default depth batches and with
    one batch of every slot (the queue sized to every slot), in the same run, alternately:
    medians of this process's CPU time and of the minor page faults per call, also with no
    live ray at all."""
    import dataclasses
    import resource

    from fovjax.render.internal import radiance_in_chunks

    arrays = scene_arrays(scene, background=config.background)
    cam = fovjax.Camera.from_pose(fovjax.scenes.default_camera(scene), width=64, height=64)
    o, d, _ = cam.sample_rays(1, None)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    live = o.shape[0]
    po = jnp.zeros((n_slots, 3)).at[:live].set(o)
    pd = jnp.ones((n_slots, 3)).at[:live].set(d)
    variants = {
        f"depth batches of {config.depth_batch_size:,}": config,
        "one batch of every slot": dataclasses.replace(config, depth_batch_size=None),
    }
    programs = {}
    for name, cfg in variants.items():

        def program(a, b, po, pd, n, cfg=cfg):
            def rays_at(first, size):
                return tuple(jax.lax.dynamic_slice_in_dim(x, first, size) for x in (po, pd))

            return radiance_in_chunks(a, b, rays_at, n, n_slots=n_slots, config=cfg)

        t0 = time.perf_counter()
        programs[name] = jax.jit(program).lower(arrays, bvh, po, pd, jnp.int32(live)).compile()
        print(f"    {name}: compile {time.perf_counter() - t0:.1f} s", flush=True)
    depth = config.max_depth
    print(f"\nFixed cost of {n_slots:,} slots: radiance_in_chunks, depth {depth}, median of {repeats}")
    for n in (live, 0):
        cpu = {k: [] for k in variants}
        faults = {k: [] for k in variants}
        for _ in range(repeats):
            for name, c in programs.items():
                c0, f0 = time.process_time(), resource.getrusage(resource.RUSAGE_SELF).ru_minflt
                jax.block_until_ready(c(arrays, bvh, po, pd, jnp.int32(n)))
                cpu[name].append(1000 * (time.process_time() - c0))
                faults[name].append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
        for name in variants:
            print(
                f"  {n:5d} live rays, {name:32s} CPU {statistics.median(cpu[name]):8.1f} ms, "
                f"{statistics.median(faults[name]):9,.0f} page faults"
            )
    sys.stdout.flush()


def foveation_for(pair, spp, rule, eye_height, preset=None):
    if preset == "thesis":
        return thesis_preset(pair, spp=spp, eye_height=eye_height).foveation
    if rule == "thesis-measured":
        return Foveation.thesis_measured(pair, spp=spp, eye_height=eye_height)
    return Foveation.thesis(pair, spp=spp, rule=rule)


def count_samples(rig, gaze, foveation):
    """Samples a foveated frame traces (both eyes), from the sample classes alone."""
    from fovjax.foveate._frame import eccentricities, select_samples

    ecc = eccentricities(rig.eye_cameras(), jnp.asarray(gaze, jnp.float32), foveation)
    full = 2 * foveation.spp * rig.eye_width * rig.eye_height
    sel = select_samples(ecc, jax.random.key(0), foveation=foveation, budget=full)
    return int(sel.n_traced)


def region_shares(w=1280, h=1024):
    """Issue 17's clue: the share of an eye's pixels within ω1 = 10-30° of the display centre
    under each candidate reading of the thesis's regions, beside Table 2's b / b_full."""
    y, x = np.mgrid[0:h, 0:w] + 0.5
    r = np.hypot(x - w / 2, y - h / 2)  # pixels from the gaze point
    deg = np.degrees
    readings = {
        "the thesis's b / b_full": None,
        "exact angle, 90° horizontal (fovjax default)": deg(np.arctan(r / (w / 2))),
        "planar eq. 4-5, D 24 mm, pitch from the 90° width": deg(2 * np.arctan(r * 48 / w / 48)),
        "exact angle, SX111 64° vertical per eye": deg(np.arctan(r / (h / 2 / np.tan(np.radians(32))))),
        "planar, 2560 px spanning the 90°": deg(2 * np.arctan(r * 48 / (2 * w) / 48)),
        "threshold as a diameter (angle / 2, 90°)": deg(np.arctan(r / (w / 2))) / 2,
        "planar, pitch D tan(64°/1024) (thesis_pixel_pitch_mm)": deg(
            2 * np.arctan(r * 24 * np.tan(np.radians(64 / h)) / 48)
        ),
        "constant 16 px per degree (1024 / 64)": r / (h / 64),
    }
    b = {p: (THESIS_RPF[p][1] - THESIS_RPF[p][0]) / 3 for p in THESIS_PAIRS}  # slope from SPP 1, 4
    b_full = (THESIS_RPF["full"][1] - THESIS_RPF["full"][0]) / 3
    print(f"\nShare of a {w}x{h} eye's pixels within ω1 of the gaze (display centre), %")
    print(f"{'reading':56s}" + "".join(f"{p[1]:7.0f}°" for p in THESIS_PAIRS))
    for name, ecc in readings.items():
        cells = [
            100 * b[p] / b_full if ecc is None else 100 * float(np.mean(ecc <= p[1])) for p in THESIS_PAIRS
        ]
        print(f"{name:56s}" + "".join(f"{c:8.1f}" for c in cells))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="2 x 1280x1024 (default: 2 x 640x512)")
    ap.add_argument("--spp", type=int, nargs="+", default=list(SPPS))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--backend", choices=fovjax.trace.BACKENDS, default="auto")
    ap.add_argument("--max-depth", type=int, default=5)
    ap.add_argument("--profile", action="store_true", help="per-stage table (first --spp, --pair)")
    ap.add_argument("--pair", type=float, nargs=2, default=(5.0, 10.0), help="fovea, periphery (--profile)")
    ap.add_argument("--size", type=int, nargs=2, default=None, help="eye width, height (overrides --full)")
    ap.add_argument("--speedup", action="store_true", help="foveated vs full at an off-centre gaze (--spp)")
    ap.add_argument("--variants", action="store_true", help="foveated default vs its variants (--spp)")
    ap.add_argument("--floor", type=int, default=None, metavar="SLOTS", help="fixed cost of a slot budget")
    ap.add_argument("--which", nargs="+", default=(), help="--variants: only those whose names contain these")
    ap.add_argument("--rule", choices=("either", "strict", "thesis-measured"), default="either")
    ap.add_argument("--count-only", action="store_true", help="tables 2-3 from traced samples, no render")
    ap.add_argument("--regions", action="store_true", help="region shares under each reading (issue 17)")
    ap.add_argument(
        "--preset",
        choices=("thesis",),
        default=None,
        help="the thesis's whole configuration (thesis_preset; replaces --rule and --max-depth); "
        "tables 2-5 written to a record",
    )
    ap.add_argument("--note", default=None, help="the record's note (--preset): the run's conditions")
    args = ap.parse_args(argv)
    if args.regions:
        return region_shares()
    w, h = (1280, 1024) if args.full else (640, 512)
    if args.size:
        w, h = args.size
    scene = fovjax.scenes.atrium()
    bvh = build_bvh(scene)
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=w, eye_height=h)
    config = RenderConfig(max_depth=args.max_depth, backend=args.backend)
    if args.preset:  # the thesis's shading, depth and background on the chosen ray backend
        config = thesis_preset(config=RenderConfig(backend=args.backend)).config
        args.rule = thesis_preset().foveation.rule
    if args.floor:
        return floor_table(scene, bvh, config, args.floor, args.repeats)
    if args.profile:
        print(
            f"atrium {scene.num_triangles:,} triangles, jax {jax.__version__} on {jax.devices()[0].platform}"
        )
        return profile(scene, bvh, rig, config, args.spp[0], tuple(args.pair), args.repeats)
    if args.speedup:
        print(
            f"atrium {scene.num_triangles:,} triangles, jax {jax.__version__} on {jax.devices()[0].platform}"
        )
        return speedup_table(scene, bvh, rig, config, args.spp, tuple(args.pair), args.repeats)
    if args.variants:
        print(
            f"atrium {scene.num_triangles:,} triangles, jax {jax.__version__} on {jax.devices()[0].platform}"
        )
        return variants_table(scene, bvh, rig, config, args.spp, tuple(args.pair), args.repeats, args.which)
    gaze = ((0.5, 0.5), (0.5, 0.5))
    print(
        f"atrium {scene.num_triangles:,} triangles, stereo 2 x {w}x{h}, gaze at the display centres, "
        f"backend {args.backend}, max depth {config.max_depth}, "
        f"jax {jax.__version__} on {jax.devices()[0].platform}"
    )
    print(f"sampling rule {args.rule}" + (" (samples traced, no render)" if args.count_only else ""))
    if args.preset:
        print(f"preset {args.preset}: {config}")
    results = {}
    for spp in args.spp:
        if args.count_only:
            results["full", spp] = (2 * spp * w * h, float("nan"))
            for pair in THESIS_PAIRS:
                n = count_samples(rig, gaze, foveation_for(pair, spp, args.rule, h, args.preset))
                results[pair, spp] = (n, float("nan"))
            continue
        rays, t, c, _ = measure(
            lambda k, spp=spp: render_stereo(scene, rig, spp=spp, key=k, config=config, bvh=bvh), args.repeats
        )
        results["full", spp] = (rays, t)
        print(
            f"  full          spp {spp:2d}: {rays / 1e6:7.3f} M rays  {1 / t:7.3f} fps  (compile {c:.1f} s)"
        )
        sys.stdout.flush()
        for pair in THESIS_PAIRS:
            f = foveation_for(pair, spp, args.rule, h, args.preset)
            rays, t, c, frame = measure(
                lambda k, f=f: render_foveated(
                    scene, rig, gaze=gaze, foveation=f, key=k, config=config, bvh=bvh, **FRAME
                ),
                args.repeats,
            )
            results[pair, spp] = (rays, t)
            fs = frame.foveation
            print(
                f"  {pair[0]:4.1f}/{pair[1]:4.1f}     spp {spp:2d}: "
                f"{rays / 1e6:7.3f} M rays  {1 / t:7.3f} fps  "
                f"(compile {c:.1f} s; primary by region {fs.primary_by_region}, budget {fs.budget:,}, "
                f"padding {fs.padding:,}, dropped {fs.dropped})"
            )
            sys.stdout.flush()

    rows = [*THESIS_PAIRS, "full"]

    def name(p):
        return "Full        " if p == "full" else f"{p[0]:4.1f}° {p[1]:4.1f}° "

    def table(title, cell, thesis=None):
        print(f"\n{title}")
        print("Foveal/Periph " + "".join(f"{'SPP ' + str(s):>24s}" for s in args.spp))
        print("              " + "".join(f"{'ours':>12s}{'thesis':>12s}" for _ in args.spp))
        for p in rows:
            cells = []
            for s in args.spp:
                ours = cell(p, s)
                theirs = thesis(p, s) if thesis else ""
                cells.append(f"{ours:>12s}{theirs:>12s}")
            print(name(p) + "  " + "".join(cells))

    idx = {s: SPPS.index(s) for s in args.spp}
    table(
        "Table 2: samples traced per frame (x 10^6; the thesis's: all rays, about 2 per sample)"
        if args.count_only
        else "Table 2: rays per frame (x 10^6)",
        lambda p, s: f"{results[p, s][0] / 1e6:.3f}",
        lambda p, s: f"{THESIS_RPF[p][idx[s]]:.2f}",
    )
    table(
        "Table 3: reduction of rays per frame (foveated / full - 1)",
        lambda p, s: pct((results[p, s][0] / results["full", s][0] - 1) * 100),
        lambda p, s: pct((THESIS_RPF[p][idx[s]] / THESIS_RPF["full"][idx[s]] - 1) * 100),
    )
    if args.count_only:
        return results
    table(
        "Table 4: frames per second (median)",
        lambda p, s: f"{1 / results[p, s][1]:.3f}",
        lambda p, s: f"{THESIS_FPS[p][idx[s]]:.2f}",
    )
    table(
        "Table 5: speed-up in FPS (foveated / full - 1); x = ratio",
        lambda p, s: speedup(results["full", s][1] / results[p, s][1]),
        lambda p, s: pct((THESIS_FPS[p][idx[s]] / THESIS_FPS["full"][idx[s]] - 1) * 100),
    )
    if args.preset:
        tables = preset_tables(results, args.spp, (w, h), config)
        return {"preset": args.preset, "eye": [w, h], "tables": tables, "note": args.note}
    return results


def preset_tables(results, spps, eye, config) -> list[dict]:
    """Tables 2-5 of a --preset run as the record's tables: ours beside the thesis's, per SPP."""
    w, h = eye
    rows = [*THESIS_PAIRS, "full"]
    label = {p: "full" if p == "full" else f"{p[0]:g}° / {p[1]:g}°" for p in rows}
    idx = {s: SPPS.index(s) for s in spps}
    columns = ["ω0 / ω1"] + [c for s in spps for c in (f"SPP {s}", "thesis")]
    scale = (2 * 1280 * 1024) / (2 * w * h)
    where = f"atrium, 2 × {w}×{h}, gaze at the centres, the thesis's configuration ({config.backend} rays)"

    def table(title, ours, theirs, skip_full=False):
        body = [
            [label[p]] + [c for s in spps for c in (ours(p, s), theirs(p, s))]
            for p in rows
            if not (skip_full and p == "full")
        ]
        return {"title": title, "columns": columns, "rows": body}

    def ratio(p, s, i):
        return results[p, s][i] / results["full", s][i]

    return [
        table(
            f"Table 2: rays per frame (×10⁶), {where}; ours scaled by the pixels to 2 × 1280×1024 "
            f"(×{scale:g}) beside the thesis's",
            lambda p, s: round(results[p, s][0] * scale / 1e6, 2),
            lambda p, s: THESIS_RPF[p][idx[s]],
        ),
        table(
            f"Table 3: reduction of rays per frame (foveated / full − 1), {where}",
            lambda p, s: f"{(ratio(p, s, 0) - 1) * 100:+.1f}%",
            lambda p, s: f"{(THESIS_RPF[p][idx[s]] / THESIS_RPF['full'][idx[s]] - 1) * 100:+.1f}%",
            skip_full=True,
        ),
        table(
            f"Table 4: frames per second (median), {where}: this CPU's, the thesis's an RTX 2060's",
            lambda p, s: round(1 / results[p, s][1], 2),
            lambda p, s: THESIS_FPS[p][idx[s]],
        ),
        table(
            f"Table 5: speed-up in frames per second (foveated / full − 1), {where}",
            lambda p, s: f"{(1 / ratio(p, s, 1) - 1) * 100:+.1f}%",
            lambda p, s: f"{(THESIS_FPS[p][idx[s]] / THESIS_FPS['full'][idx[s]] - 1) * 100:+.1f}%",
            skip_full=True,
        ),
    ]


if __name__ == "__main__":
    np.set_printoptions(linewidth=200)
    out = main()
    if isinstance(out, dict) and ("speedup" in out or "profile" in out):
        from _record import write_record

        write_record("foveation", {**out, "tables": foveation_tables(out)})
    elif isinstance(out, dict) and "preset" in out:
        from _record import write_record

        note = out.pop("note")
        write_record("foveation", out, note=note)
