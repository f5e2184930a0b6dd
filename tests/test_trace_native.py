"""The native ray-query backends' plumbing: the Embree FFI handler builds where embreex is installed,
falls back (and says why) where it cannot, answers per-ray levels of a merged BVH, ties on shared
edges, batches under vmap, keeps gradients, frees its scenes; and every frame program lowers for
CUDA without a CPU-only op (no GPU needed).

The hit results themselves are checked against brute force and the JAX traversal for every
backend in tests/test_trace.py."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import _extras
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fovjax
from fovjax.native import cached_scenes as cached_embree_scenes
from fovjax.native import release_scenes as release_embree_scenes
from fovjax.native import status as embree_status
from fovjax.trace import brute_force_closest_hit, build_bvh, closest_hit, merge_bvhs, occluded


def need_native():
    """The Embree FFI handler: embreex through the suite's one guard, and a handler that built
    (where it cannot be built here, e.g. no C++ compiler, a skip naming why; a failure where CI
    requires every extra)."""
    _extras.require("embreex")
    status = embree_status()
    if not status:
        if _extras.required():
            pytest.fail(f"the Embree FFI handler is unavailable: {status.reason}")
        pytest.skip(f"the Embree FFI handler is unavailable here: {status.reason}")


def test_backend_names_agree_with_the_command_line():
    from fovjax import cli

    assert cli.BACKENDS == fovjax.trace.BACKENDS


def test_embree_handler_builds_where_embreex_is_installed():
    _extras.require("embreex")
    status = embree_status()
    assert status, f"the Embree FFI handler did not build or load: {status.reason}"
    assert status.reason.startswith("Embree 4.")
    assert fovjax.trace.resolve_backend("auto", "cpu") == "embree"
    assert fovjax.trace.describe_backend("auto", "cpu").startswith("embree (Embree 4.")
    assert fovjax.render.RenderConfig().backend == "auto"


def test_a_gpu_platform_reads_as_cuda():
    """JAX names a GPU platform "gpu"; "auto" chooses for the platform a program lowers for
    ("cuda"): Warp where it is installed, the same answer for both names."""
    from fovjax.trace._backends import lowering_platform

    assert lowering_platform("cpu") == "cpu"
    assert lowering_platform("gpu") in ("cuda", "rocm")
    assert fovjax.trace.resolve_backend("auto", "gpu") == fovjax.trace.resolve_backend("auto", "cuda")
    assert fovjax.trace.describe_backend("auto", "gpu") == fovjax.trace.describe_backend("auto", "cuda")


FALLBACK_SCRIPT = textwrap.dedent(
    """
    import numpy as np
    import fovjax
    from fovjax.trace import brute_force_closest_hit, build_bvh, closest_hit
    print("STARTED", fovjax.native.start_build())  # what `fovjax render` does first
    print("BUILDING", fovjax.native.building())
    print("STATUS", fovjax.trace.embree_status().reason)
    print("LIBRARY", fovjax.native.status().library)
    print("BUILT", fovjax.native.building())
    print("AUTO", fovjax.trace.describe_backend("auto", "cpu"))
    if "{check}" == "trace":
        rng = np.random.default_rng(0)
        V = rng.uniform(-1, 1, (60, 3)).astype(np.float32)
        F = np.arange(60).reshape(20, 3)
        bvh = build_bvh(vertices=V, faces=F, cache=False)
        o = rng.uniform(-2, 2, (300, 3)).astype(np.float32)
        d = rng.normal(size=(300, 3)).astype(np.float32)
        t_ref, _, _ = brute_force_closest_hit(V, F, o, d)
        hit = closest_hit(bvh, o, d)
        print("AGREE", np.mean(np.isfinite(np.asarray(hit.t)) == np.isfinite(t_ref)))
    """
)


def _fallback(env_extra, check, tmp_path):
    env = {**os.environ, "FOVJAX_NATIVE_DIR": str(tmp_path / "native"), "JAX_PLATFORMS": "cpu", **env_extra}
    done = subprocess.run(
        [sys.executable, "-c", FALLBACK_SCRIPT.replace("{check}", check)],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return dict(line.split(" ", 1) for line in done.stdout.splitlines() if " " in line)


def test_a_handler_that_cannot_build_falls_back_to_the_jax_traversal_and_says_why(tmp_path):
    """A compiler that fails: the package still imports and traces (the JAX traversal, correct
    hits), and 'auto' says in one line why it is not Embree."""
    out = _fallback({"CXX": "/bin/false"}, "trace", tmp_path)
    assert out["STARTED"] != "None" and out["BUILDING"] == "True"  # it failed in the background
    assert out["STATUS"].startswith("could not build the native handlers: false failed to compile")
    assert out["AUTO"].startswith("jax (the JAX traversal; Embree FFI unavailable: could not build")
    assert float(out["AGREE"]) == 1.0
    assert not list((tmp_path / "native").glob("*.so")), "a failed build left a library behind"


def test_the_handler_compiles_from_source_in_a_fresh_directory(tmp_path):
    """What a fresh machine does on first use: compile the native handlers with the system's
    compiler into the cache directory, load it, check the library's struct layout, register it.
    Without optimisation (`FOVJAX_NATIVE_FLAGS=-O0`, the build's slowest part left out): the
    optimised build is `.ci/run`'s first step on a fresh machine, whose library the suite runs."""
    _extras.require("embreex")
    out = _fallback({"FOVJAX_NATIVE_FLAGS": "-O0"}, "trace", tmp_path)
    assert out["STATUS"].startswith("Embree 4."), out["STATUS"]
    assert out["AUTO"].startswith("embree (Embree 4.")
    assert float(out["AGREE"]) == 1.0
    # Built in the background (`start_build`), and that library is the one loaded.
    assert out["BUILDING"] == "True" and out["BUILT"] == "False"
    assert [str(p) for p in (tmp_path / "native").glob("fovjax_native-*.so")] == [out["STARTED"]]
    assert out["LIBRARY"] == out["STARTED"]


def test_extra_flags_build_their_own_library_and_a_bad_one_is_named(tmp_path, monkeypatch):
    """`FOVJAX_NATIVE_FLAGS` goes into the library's name (a build with other flags is never
    loaded in its place), and a flag the compiler refuses is named where the build's failure is
    said, the JAX traversal running instead."""
    from fovjax.native import _library

    compiler = _library._compiler()
    assert compiler is not None
    names = set()
    for value in ("", "-O0", "-O0 -march=native"):
        monkeypatch.setenv("FOVJAX_NATIVE_FLAGS", value)
        names.add(_library.library_path(compiler).name)
    assert len(names) == 3
    out = _fallback({"FOVJAX_NATIVE_FLAGS": "--no-such-flag"}, "status", tmp_path)
    assert out["STATUS"].startswith("could not build the native handlers: "), out["STATUS"]
    assert "FOVJAX_NATIVE_FLAGS='--no-such-flag'" in out["STATUS"]
    assert out["AUTO"].startswith("jax (the JAX traversal; Embree FFI unavailable: could not build")
    monkeypatch.setenv("FOVJAX_NATIVE_FLAGS", '"-O0')
    with pytest.raises(ValueError, match="FOVJAX_NATIVE_FLAGS='\"-O0' cannot be split"):
        _library.library_path(compiler)


def test_the_user_s_flags_come_last(monkeypatch):
    """`FOVJAX_NATIVE_FLAGS` follows every flag of the project's, link-time optimisation's
    included, so the user's win (`-fno-lto` builds plainly); without them the first choice is
    the project's flags and `PARALLEL_FLAGS` (the library's name unchanged)."""
    from fovjax.native import _library

    compiler = _library._compiler()
    assert compiler is not None
    monkeypatch.setenv("FOVJAX_NATIVE_FLAGS", "-fno-lto -O1")
    monkeypatch.delenv("FOVJAX_NATIVE_SANITIZE", raising=False)
    choices = _library._choices(compiler)
    assert all(choice[-2:] == ("-fno-lto", "-O1") for choice in choices)
    if len(choices) == 2:  # GCC
        assert set(_library.PARALLEL_FLAGS) <= set(choices[0])
    monkeypatch.delenv("FOVJAX_NATIVE_FLAGS")
    assert _library._choices(compiler)[0][: len(_library.FLAGS)] == _library.FLAGS


def test_a_library_without_the_entry_points_is_refused_by_name(tmp_path, monkeypatch):
    """A library that loads but lacks the handlers' entry points (a build whose flags left it
    without code: GCC's `-flto` with `-fno-lto` before it) is named in the status, with what
    it lacks and how to rebuild it, and nothing is registered (the JAX traversal runs)."""
    _extras.require("embreex")
    from fovjax.native import _library

    compiler = _library._compiler()
    assert compiler is not None
    source, empty = tmp_path / "empty.cc", tmp_path / "fovjax_native-empty.so"
    source.write_text('extern "C" int fovjax_nothing() { return 0; }\n')
    subprocess.run([compiler, "-shared", "-fPIC", str(source), "-o", str(empty)], check=True, timeout=120)
    monkeypatch.setattr(_library, "_built_library", lambda compiler: (empty, 0.0))
    monkeypatch.setenv("FOVJAX_NATIVE_FLAGS", "-O1")
    status = _library._load()
    assert not status.available
    assert str(empty) in status.reason and "fovjax_native_layout" in status.reason
    assert "FOVJAX_NATIVE_FLAGS='-O1'" in status.reason and "remove it" in status.reason


def test_the_native_backend_can_be_turned_off(tmp_path):
    out = _fallback({"FOVJAX_NATIVE": "0"}, "status", tmp_path)
    assert out["STARTED"] == "None" and out["BUILDING"] == "False"
    assert out["STATUS"] == "turned off by FOVJAX_NATIVE=0"
    assert out["AUTO"] == "jax (the JAX traversal; Embree FFI unavailable: turned off by FOVJAX_NATIVE=0)"


def _soup(seed, n, spread=2.0):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-spread, spread, (n, 1, 3))
    V = (centres + rng.normal(0, 0.3, (n, 3, 3))).reshape(-1, 3).astype(np.float32)
    return V, np.arange(3 * n).reshape(n, 3).astype(np.int32)


@pytest.mark.parametrize("packet", [None, 16], ids=["single", "packet16"])
def test_levels_of_a_merged_bvh(packet):
    """Each ray traced only against its level's tree (rays of mixed levels in one packet),
    `prim` an index into the merged faces: against brute force per level and the JAX traversal."""
    need_native()
    (V0, F0), (V1, F1) = _soup(0, 120), _soup(1, 40)
    merged = merge_bvhs(
        [build_bvh(vertices=V0, faces=F0, cache=False), build_bvh(vertices=V1, faces=F1, cache=False)]
    )
    rng = np.random.default_rng(2)
    n = 3000
    o = rng.uniform(-3, 3, (n, 3)).astype(np.float32)
    d = rng.normal(size=(n, 3)).astype(np.float32)
    level = rng.integers(0, 2, n).astype(np.int32)
    hit = closest_hit(merged, o, d, level=level, backend="embree", packet=packet)
    ref = closest_hit(merged, o, d, level=level, backend="jax", packet=packet)
    prim = np.asarray(hit.prim)
    assert (prim == np.asarray(ref.prim)).mean() >= 0.9999
    for lv, (V, F, first) in enumerate([(V0, F0, 0), (V1, F1, len(F0))]):
        rays = level == lv
        t_ref, prim_ref, _ = brute_force_closest_hit(V, F, o[rays], d[rays])
        expect = np.where(prim_ref >= 0, prim_ref + first, -1)
        assert (prim[rays] == expect).mean() >= 0.9999
    occ = np.asarray(occluded(merged, o, d, 2.0, level=level, backend="embree", packet=packet))
    occ_ref = np.asarray(occluded(merged, o, d, 2.0, level=level, backend="jax", packet=packet))
    assert (occ == occ_ref).mean() >= 0.9999 and 0.05 < occ.mean() < 0.95


def test_ties_on_shared_edges_and_vertices():
    """A flat grid of triangles hit exactly on shared edges and vertices: never a leak, the
    distance exact, and the face one of those that contain the point (a tie either may take)."""
    need_native()
    k = 6
    xs = np.linspace(-1, 1, k + 1)
    X, Y = np.meshgrid(xs, xs)
    V = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1).astype(np.float32)
    idx = np.arange(X.size).reshape(k + 1, k + 1)
    a, b, c, e = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    F = np.concatenate([np.stack([a, b, e], 1), np.stack([a, e, c], 1)]).astype(np.int32)
    bvh = build_bvh(vertices=V, faces=F, cache=False)
    inner = V[(np.abs(V[:, 0]) < 1) & (np.abs(V[:, 1]) < 1)]
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    mids = 0.5 * (V[edges[:, 0]] + V[edges[:, 1]])
    targets = np.concatenate([inner, mids[(np.abs(mids[:, 0]) < 1) & (np.abs(mids[:, 1]) < 1)]])
    o = (targets + np.array([0.0, 0.0, 2.0], np.float32)).astype(np.float32)
    d = np.broadcast_to(np.array([0.0, 0.0, -1.0], np.float32), o.shape)

    def contains(prim):  # the target inside face `prim`, barycentrics in float64 with a margin
        p0, p1, p2 = (V[F[prim]][:, i].astype(np.float64) for i in range(3))
        m = np.stack([p1 - p0, p2 - p0], -1)[:, :2]
        uv = np.linalg.solve(m, (targets - p0)[:, :2, None].astype(np.float64))[..., 0]
        return (uv >= -1e-6).all(1) & (uv.sum(1) <= 1 + 1e-6)

    for backend in ("embree", "jax"):
        for packet in (None, 16):
            hit = closest_hit(bvh, o, d, backend=backend, packet=packet)
            prim, t = np.asarray(hit.prim), np.asarray(hit.t)
            assert (prim >= 0).all(), f"{backend} {packet}: a ray leaked through a shared edge or vertex"
            np.testing.assert_allclose(t, 2.0, rtol=0, atol=1e-6)
            assert contains(prim).all(), f"{backend} {packet}: a face that does not contain the point"
            assert np.asarray(occluded(bvh, o, d, 3.0, backend=backend, packet=packet)).all()


def test_vmap_gradients_and_the_scene_cache():
    need_native()
    V, F = _soup(3, 200)
    bvh = build_bvh(vertices=V, faces=F, cache=False)
    rng = np.random.default_rng(4)
    o = rng.uniform(-3, 3, (3, 700, 3)).astype(np.float32)
    d = rng.normal(size=(3, 700, 3)).astype(np.float32)
    # Frames under vmap: one call for all of them, the same hits as one call per frame.
    batched = jax.vmap(lambda o, d: closest_hit(bvh, o, d, backend="embree").prim)(o, d)
    each = np.stack([np.asarray(closest_hit(bvh, o[i], d[i], backend="embree").prim) for i in range(3)])
    np.testing.assert_array_equal(np.asarray(batched), each)
    blocked = jax.vmap(lambda o, d: occluded(bvh, o, d, 1.5, backend="embree"))(o, d)
    np.testing.assert_array_equal(np.asarray(blocked), np.asarray(occluded(bvh, o, d, 1.5, backend="jax")))

    # Gradients come from the recomputed hit, not from the backend.
    def loss(origins, backend):
        hit = closest_hit(bvh, origins, d[0], backend=backend)
        return jnp.sum(jnp.where(jnp.isfinite(hit.t), hit.t * hit.u, 0.0))

    g_embree = jax.grad(loss)(jnp.asarray(o[0]), "embree")
    g_jax = jax.grad(loss)(jnp.asarray(o[0]), "jax")
    np.testing.assert_allclose(np.asarray(g_embree), np.asarray(g_jax), rtol=1e-5, atol=1e-6)
    assert np.abs(np.asarray(g_embree)).sum() > 0

    # Scenes are built once per BVH, freed on request and rebuilt on next use.
    assert cached_embree_scenes() >= 1
    assert release_embree_scenes(int(bvh.host_id)) == 1
    assert release_embree_scenes(int(bvh.host_id)) == 0
    again = closest_hit(bvh, o[0], d[0], backend="embree")
    np.testing.assert_array_equal(np.asarray(again.prim), each[0])


def test_not_watertight_scenes():
    """`BVH.with_watertight(False)`: Embree's default intersector, answering as the JAX traversal
    does up to ties (another face at the same distance) and to rays that graze an edge or a
    vertex; its own cached scene beside the watertight one (both freed with the BVH's host id);
    a frame through the native integrator the same image up to such rays; the flag checked,
    kept by `merge_bvhs`, and read by no other backend."""
    need_native()
    V, F = _soup(5, 300)
    bvh = build_bvh(vertices=V, faces=F, cache=False)
    fast = bvh.with_watertight(False)
    assert bvh.watertight and not fast.watertight and fast.host_id == bvh.host_id
    with pytest.raises(TypeError, match="(?s)watertight.*'no'"):  # the parameter and the value
        bvh.with_watertight("no")
    assert not merge_bvhs([fast, build_bvh(vertices=V[:30], faces=F[:10], cache=False)]).watertight
    rng = np.random.default_rng(6)
    o = rng.uniform(-3, 3, (4000, 3)).astype(np.float32)
    d = rng.normal(size=(4000, 3)).astype(np.float32)
    ref = closest_hit(bvh, o, d, backend="jax")
    for packet in (None, 16):
        hit = closest_hit(fast, o, d, backend="embree", packet=packet)
        assert (np.asarray(hit.prim) >= 0).mean() > 0.2  # the rays do meet the soup
        same = (np.asarray(hit.prim) >= 0) == (np.asarray(ref.prim) >= 0)
        assert same.mean() >= 0.9999
        both = same & (np.asarray(ref.prim) >= 0)
        np.testing.assert_allclose(np.asarray(hit.t)[both], np.asarray(ref.t)[both], rtol=1e-5, atol=1e-6)
        blocked = np.asarray(occluded(fast, o, d, 1.5, backend="embree", packet=packet))
        assert (blocked == np.asarray(occluded(bvh, o, d, 1.5, backend="jax"))).mean() >= 0.9999
    np.testing.assert_array_equal(  # the JAX traversal does not read the flag
        np.asarray(closest_hit(fast, o, d, backend="jax").prim), np.asarray(ref.prim)
    )
    closest_hit(bvh, o, d, backend="embree")
    assert release_embree_scenes(int(bvh.host_id)) == 2  # the watertight scene and the other

    scene = fovjax.scenes.cornell_box()
    rig = fovjax.render.StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=24, eye_height=16)
    scene_bvh = build_bvh(scene)
    tight = fovjax.render_stereo(scene, rig, bvh=scene_bvh).image
    loose = fovjax.render_stereo(scene, rig, bvh=scene_bvh.with_watertight(False)).image
    assert np.mean(np.all(np.abs(np.asarray(tight) - np.asarray(loose)) < 1e-4, axis=-1)) >= 0.99


def test_every_frame_program_lowers_for_cuda():
    """Each frame program (full, foveated, an eval batch, the other foveation methods') exported
    for CUDA, on this CPU: the backend and the native stages are chosen per platform inside the
    program, so the CUDA lowering carries no CPU-only op (no Embree FFI call, no foveation
    handler, no host callback); where Warp is installed, each runs the Warp integrator there
    (its mesh id and its kernel, `fovjax/render/_warp_whitted.py`)."""
    from fovjax.eval import render_foveated_batch
    from fovjax.foveate import Foveation
    from fovjax.render import RenderConfig, StereoRig
    from fovjax.render._native import warp_integrator_plan
    from fovjax.render.internal import LOWERING_HOOKS

    exported = {}
    config = RenderConfig(max_depth=1)
    integrator = []  # the Warp integrator's FFI targets, where it runs on CUDA
    if warp_integrator_plan(config).cuda:
        from fovjax.render._warp_whitted import warp_targets

        integrator += warp_targets()

    class Exported(Exception):
        pass

    def export_for_cuda(entry, jitted, args):
        targets = ["fovjax_embree_query", *integrator]
        if fovjax.trace.resolve_backend("auto", "cuda") == "warp":
            from fovjax.trace._warp import ffi_target_names

            targets += ffi_target_names()
        checks = [jax.export.DisabledSafetyCheck.custom_call(t) for t in targets]
        exp = jax.export.export(jitted, platforms=("cuda",), disabled_checks=checks)(*args)
        exported[entry] = exp.mlir_module()
        raise Exported  # lowering is the check; nothing needs to compile or run here

    LOWERING_HOOKS.append(export_for_cuda)
    try:
        scene = fovjax.scenes.cornell_box()
        rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=16, eye_height=16)
        for call in (
            lambda: fovjax.render_stereo(scene, rig, config=config),
            lambda: fovjax.render_stereo(scene, rig, foveation=Foveation(), config=config),
            lambda: render_foveated_batch(
                scene, rig, gazes=[((0.5, 0.5), (0.5, 0.5))], keys=[0], config=config
            ),
            *(
                lambda m=method: fovjax.render_stereo(
                    scene, rig, foveation=Foveation(method=m), config=config
                )
                for method in ("guenter2012", "patney2016", "weier2016")
            ),
        ):
            with pytest.raises(Exported):
                call()
    finally:
        LOWERING_HOOKS.remove(export_for_cuda)
    methods = {"foveated-guenter2012", "foveated-patney2016", "foveated-weier2016"}
    assert set(exported) == {"stereo", "foveated"} | methods | {e for e in exported if e.startswith("batch")}
    assert any(e.startswith("batch") for e in exported)
    for entry, module in exported.items():
        assert "fovjax_embree_query" not in module, f"{entry}: the Embree call is on the CUDA path"
        for target in (
            "fovjax_select_samples",
            "fovjax_whitted_slots",
            "fovjax_fill_and_blur",
            "fovjax_patney_prefilter",
            "fovjax_taa_blend",
            "fovjax_layer_blend",
        ):
            assert target not in module, f"{entry}: the CPU handler {target} is on the CUDA path"
        assert "callback" not in module, f"{entry}: a host callback is on the CUDA path"
        for target in integrator:
            assert target in module, f"{entry}: the Warp integrator's {target} is not on the CUDA path"


def test_auto_traces_the_jax_traversal_only_where_another_platform_is_seen(monkeypatch):
    """ "auto" traces one branch per platform it may lower for: CPU's and CUDA's backends, and the
    JAX traversal only where JAX sees a device of another platform (ROCm, TPU); then the program
    also lowers for such a platform, on the JAX traversal."""
    import fovjax.native._dispatch as dispatch
    import fovjax.trace._query as query

    traced = []
    run_backend = query._run_backend

    def spy(name, *args, **kwargs):
        traced.append(name)
        return run_backend(name, *args, **kwargs)

    monkeypatch.setattr(query, "_run_backend", spy)
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    bvh = build_bvh(vertices=v, faces=np.array([[0, 1, 2]], np.int32), cache=False)

    def rays(n):
        o = np.tile(np.array([[0.2, 0.2, 1.0]], np.float32), (n, 1))
        return o, np.tile(np.array([[0.0, 0.0, -1.0]], np.float32), (n, 1))

    # Ray counts no other test uses: a fresh trace of the query's program each time.
    jax.jit(lambda o, d: closest_hit(bvh, o, d, backend="auto")).lower(*rays(7))
    on_cpu, on_cuda = (fovjax.trace.resolve_backend("auto", p) for p in ("cpu", "cuda"))
    assert not dispatch.other_platforms()  # this machine: CPU (and CUDA) only
    assert traced == ([on_cpu, on_cuda] if (on_cpu, on_cuda) != ("jax", "jax") else ["jax"])

    traced.clear()
    monkeypatch.setattr(dispatch, "other_platforms", lambda: True)
    jitted = jax.jit(lambda o, d: closest_hit(bvh, o, d, backend="auto"))
    exported = jax.export.export(jitted, platforms=("rocm",))(*rays(9))
    assert traced[-1] == "jax" and "jax" in traced
    assert "fovjax_embree_query" not in exported.mlir_module()


def test_other_platforms_setting_is_read_and_a_bad_value_named(monkeypatch):
    import fovjax.native._dispatch as dispatch

    dispatch.other_platforms.cache_clear()
    try:
        monkeypatch.setenv("FOVJAX_AUTO_OTHER_PLATFORMS", "yes")
        with pytest.raises(ValueError, match=r"FOVJAX_AUTO_OTHER_PLATFORMS='yes': expected 0 \(off\) or 1"):
            dispatch.other_platforms()
        monkeypatch.setenv("FOVJAX_AUTO_OTHER_PLATFORMS", "1")
        assert dispatch.other_platforms()
    finally:
        dispatch.other_platforms.cache_clear()  # the next caller reads the suite's own setting
