"""CONTRIBUTING.md's "Add a ray backend" example, run as written: the registered backend answers
closest_hit and occluded as the JAX traversal does (the oracle), renders through RenderConfig,
and names the registry's rules when misused."""

from __future__ import annotations

import re
from pathlib import Path

import jax
import numpy as np
import pytest

import fovjax
import fovjax.trace as ft

CONTRIBUTING = Path(__file__).resolve().parents[1] / "CONTRIBUTING.md"


def _example() -> str:
    text = CONTRIBUTING.read_text(encoding="utf-8")
    section = text.split("## Add a ray backend", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert len(blocks) == 1, "the section shows one example"
    return blocks[0]


@pytest.fixture(scope="module")
def brute_force():
    namespace: dict = {}
    exec(compile(_example(), "CONTRIBUTING.md", "exec"), namespace)
    yield namespace["BruteForce"]
    ft.unregister_backend("brute-force")


def test_the_example_backend_answers_as_the_jax_traversal(brute_force):
    rng = np.random.default_rng(0)
    vertices = rng.uniform(-1, 1, (30, 3)).astype(np.float32)
    faces = np.arange(30).reshape(10, 3).astype(np.int32)
    bvh = ft.build_bvh(vertices=vertices, faces=faces, cache=False)
    o = rng.uniform(-2, 2, (64, 3)).astype(np.float32)
    centroids = vertices[faces].mean(axis=1)
    d = centroids[rng.integers(0, 10, 64)] - o  # most rays aimed at a face (some blocked by another)
    d[::4] = rng.normal(size=(16, 3))  # and some anywhere
    assert "brute-force" in ft.backend_names()
    mine = ft.closest_hit(bvh, o, d, backend="brute-force")
    oracle = ft.closest_hit(bvh, o, d, backend="jax")
    assert np.array_equal(np.asarray(mine.prim), np.asarray(oracle.prim))
    assert np.isfinite(np.asarray(oracle.t)).sum() >= 40  # the rays hit something
    np.testing.assert_allclose(np.asarray(mine.t), np.asarray(oracle.t), rtol=1e-5, atol=1e-6)
    near = np.asarray(oracle.t) * 0.5
    assert np.array_equal(
        np.asarray(ft.occluded(bvh, o, d, near, backend="brute-force")),
        np.asarray(ft.occluded(bvh, o, d, near, backend="jax")),
    )
    assert ft.describe_backend("brute-force", "cpu") == "brute-force"


def test_the_example_backend_renders(brute_force):
    """The renderer takes a registered backend by name (with the JAX integrator: the native one
    traces with Embree) and its image is the native integrator's, whose oracle is the JAX
    traversal (tests/test_render_native.py): one JAX integrator compile, the example's."""
    from _frames import assert_native_radiance

    from fovjax.render import RenderConfig, StereoRig, scene_arrays

    scene = fovjax.scenes.cornell_box()
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=12, eye_height=8)
    mine, native = (
        fovjax.render_stereo(scene, rig, key=jax.random.key(0), config=RenderConfig(backend=b, max_depth=1))
        for b in ("brute-force", "auto")
    )
    assert "ray backend is 'brute-force'" in fovjax.render.describe_integrator(
        RenderConfig(backend="brute-force"), "cpu"
    )
    assert fovjax.render.describe_integrator(RenderConfig(), "cpu").startswith("native")
    assert mine.stats.rays == native.stats.rays
    assert_native_radiance(mine.image, native.image, scene_arrays(scene))


def test_the_registry_names_its_rules(brute_force):
    with pytest.raises(ValueError, match="'brute-force' is registered already"):
        ft.register_backend(brute_force())
    with pytest.raises(TypeError, match="backend"):
        ft.register_backend("brute-force")
    with pytest.raises(ValueError, match="built-in backend 'embree' cannot be removed"):
        ft.unregister_backend("embree")
    with pytest.raises(ValueError, match=r"backend must be one of \('auto', 'jax'.*got 'nope'"):
        ft.closest_hit(
            ft.build_bvh(fovjax.scenes.cornell_box()), np.zeros((1, 3)), np.ones((1, 3)), backend="nope"
        )
