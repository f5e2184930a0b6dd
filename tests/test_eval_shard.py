"""Frames sharded over devices: two forced CPU devices give the frames of one device and of
frames rendered one by one; the sharded sweep equals the unsharded one; `fovjax compare
--distributed` over two processes on localhost writes what one process writes.

Runs in a subprocess because the device count (XLA_FLAGS) is fixed when JAX starts. The
subprocess compiles with XLA's backend optimisation level 0: five programs compile in about
half the time, and what is tested (the same compiled arithmetic per frame however the frames
are laid out over devices) does not depend on the level; at the default level the sharded and
one-device batches were also bit for bit equal when this was written.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import textwrap

OPT_LEVEL_0 = "--xla_backend_optimization_level=0"
SCRIPT = textwrap.dedent(
    """
    import jax
    import numpy as np
    from jax.sharding import PartitionSpec as P

    import fovjax
    from fovjax.eval import ThresholdSweep, compare_thresholds, render_foveated_batch, render_stereo_batch
    from fovjax.foveate import Foveation, render_foveated
    from fovjax.render import RenderConfig, StereoRig, render_stereo

    assert jax.device_count() == 2, jax.devices()
    scene = fovjax.scenes.cornell_box(mirror_block=True)  # reflections under vmap too
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=32, eye_height=24)
    config = RenderConfig(max_depth=1)
    fov = Foveation(fovea_deg=5.0, periphery_deg=10.0, spp=1)
    gazes = [(0.5, 0.5), ((0.3, 0.4), (0.35, 0.4)), (0.7, 0.65)]
    keys = [0, 1, 2]

    two = render_foveated_batch(scene, rig, gazes=gazes, keys=keys, foveation=fov, config=config)
    assert len(two) == 3 and two.padded == 4 and two.devices == 2, (len(two), two.padded, two.devices)
    # The frame axis is split over both devices: frames 0-1 on one, 2-3 (one padding) on the other.
    assert two.sharding.spec == P("frames"), two.sharding
    slices = sorted(idx[0].indices(4)[:2] for idx in two.sharding.devices_indices_map((4,)).values())
    assert slices == [(0, 2), (2, 4)], slices
    assert len(two.sharding.device_set) == 2

    one = render_foveated_batch(
        scene, rig, gazes=gazes, keys=keys, foveation=fov, config=config, devices=jax.devices()[:1]
    )
    assert one.devices == 1 and one.padded == 3
    # Same per-frame arithmetic on each device, in two programs (a batch of 2 per device and
    # of 3): XLA compiles the rays' arithmetic around the integrator per program, and at the
    # suite's optimisation level 0 the two can round apart by an ulp (tests/_frames.py).
    np.testing.assert_allclose(two.images, one.images, rtol=1e-5, atol=1e-6)
    for name in ("primary_rays", "shadow_rays", "reflection_rays", "primary_by_region", "sample_mask"):
        assert np.array_equal(getattr(two, name), getattr(one, name)), name

    for i, (g, k) in enumerate(zip(gazes, keys)):
        g = np.broadcast_to(np.asarray(g, np.float32), (2, 2))
        frame = render_foveated(scene, rig, gaze=g, foveation=fov, key=jax.random.key(k), config=config)
        assert frame.foveation.budget > 0
        assert frame.stats.primary_rays == two.primary_rays[i]
        assert frame.stats.shadow_rays == two.shadow_rays[i]
        assert frame.stats.reflection_rays == two.reflection_rays[i]
        assert np.array_equal(frame.sample_mask, two.sample_mask[i])
        assert np.array_equal(frame.regions, two.regions[i])
        # Under vmap XLA compiles the same float32 arithmetic as other loops (vector widths,
        # fused multiply-adds, the vectorised pow of the specular term): a few ulps, no more.
        np.testing.assert_allclose(two.images[i], frame.image, rtol=1e-5, atol=1e-6)

    full = render_stereo_batch(scene, rig, keys=[0, 1], config=config)
    assert full.devices == 2 and full.padded == 2
    assert (full.reflection_rays > 0).all() and (two.reflection_rays > 0).all()
    for i, k in enumerate([0, 1]):
        frame = render_stereo(scene, rig, key=jax.random.key(k), config=config)
        assert frame.stats.rays == full.rays[i] and frame.stats.bad_pixels == full.bad_pixels[i]
        np.testing.assert_allclose(full.images[i], frame.image, rtol=1e-5, atol=1e-6)

    # The sweep, sharded and not: same rays and metrics (reuses the programs compiled above).
    renderer = fovjax.FoveatedRenderer(scene, rig, config=config)
    sweep = ThresholdSweep(thresholds=[(5, 10)], spp=[1], gazes=[(0.5, 0.5), (0.3, 0.4)], keys=[0, 1])
    options = dict(criterion=("psnr", 10.0), perceptual=False, progress=False)
    sharded = compare_thresholds(renderer, sweep=sweep, shard=True, **options)
    plain = compare_thresholds(renderer, sweep=sweep, shard=False, **options)
    (a,), (b,) = sharded.records, plain.records
    assert a["timing"].startswith("batch over 2 devices") and b["timing"] == "median of frames"
    assert a["rays_per_frame"] == b["rays_per_frame"] and a["n"] == b["n"] == 4
    assert sharded.full[1]["rays_per_frame"] == plain.full[1]["rays_per_frame"]
    for m in ("psnr", "ssim", "flip"):
        for col in (m, m + "_lo", m + "_hi"):
            if col in b:
                assert abs(a[col] - b[col]) <= 1e-4 * max(1.0, abs(b[col])), (col, a[col], b[col])
    assert (sharded.choice is None) == (plain.choice is None)
    print("OK")
    """
)


def test_sharded_frames_equal_one_device_and_frames_one_by_one():
    env = {
        **os.environ,
        "XLA_FLAGS": " ".join(
            [os.environ.get("XLA_FLAGS", ""), "--xla_force_host_platform_device_count=2", OPT_LEVEL_0]
        ).strip(),
        "JAX_PLATFORMS": "cpu",
    }
    result = subprocess.run(
        [sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-6000:]
    assert result.stdout.strip().endswith("OK")


def test_compare_over_two_processes_with_jax_distributed(tmp_path):
    """`fovjax compare --distributed` on two processes of one CPU device each (the multi-host
    path, on one machine) writes what one process writes without sharding."""
    with socket.socket() as s:
        s.bind(("localhost", 0))
        port = s.getsockname()[1]
    common = ["compare", "--scene", "cornell_box", "--thresholds", "5,10", "--spp", "1"]
    common += ["--width", "32", "--height", "24", "--gazes", "0.5,0.5", "0.3,0.4", "--keys", "0", "1"]
    common += ["--criterion", "psnr", "--threshold", "0", "--max-depth", "0", "--no-perceptual"]
    cli = [sys.executable, "-m", "fovjax.cli"]
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    procs = [
        subprocess.Popen(
            [*cli, *common, "-o", str(tmp_path / f"out{i}"), "--distributed", f"localhost:{port},2,{i}"],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(2)
    ]
    outputs = [p.communicate(timeout=900) for p in procs]
    for p, (out, err) in zip(procs, outputs, strict=True):
        assert p.returncode == 0, out[-2000:] + err[-4000:]
    assert (tmp_path / "out0" / "comparison.csv").is_file()
    assert not (tmp_path / "out1").exists()  # process 1 computes, process 0 writes
    single = subprocess.run(
        [*cli, *common, "-o", str(tmp_path / "single")], env=env, capture_output=True, text=True, timeout=900
    )
    assert single.returncode == 0, single.stderr[-4000:]
    from fovjax.eval import read_csv

    (a,), (b,) = (
        read_csv(tmp_path / "out0" / "comparison.csv"),
        read_csv(tmp_path / "single" / "comparison.csv"),
    )
    assert a["timing"].startswith("batch over 2 devices") and b["timing"] == "median of frames"
    assert float(a["rays_per_frame"]) == float(b["rays_per_frame"])
    for col in ("psnr", "psnr_lo", "psnr_hi", "ssim", "ssim_lo", "ssim_hi"):
        assert abs(float(a[col]) - float(b[col])) <= 1e-4 * max(1.0, abs(float(b[col]))), col
