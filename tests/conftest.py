"""Shared test set-up. The suite runs in two pytest-xdist workers (pyproject's addopts): on a
GPU each worker is its own JAX process, so neither may preallocate most of the device memory.

The package's jaxtyping annotations are checked while the tests run: jaxtyping's import hook
wraps every function and dataclass of `fovjax` in a beartype check of its arguments and return
value (array kinds, dtypes and shapes included) when the package is first imported, which is
here, before any test module imports it. beartype is configured with PEP 484's numeric tower (an
int is a valid `float`), as the annotations mean it. Set FOVJAX_TYPECHECK=0 to run without (e.g.
to time something)."""

import os
import shutil
import signal
import sys
import tempfile
import types

import _extras
import pytest
from _frames import FAST_COMPILE_FLAGS

os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
# A shell starts a background job (`pytest &`) with Ctrl-C ignored, and the programs the tests
# start would inherit that and never see the Ctrl-C the interrupt tests send them.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
# The command line keeps compiled programs on disk (`fovjax.render.enable_compile_cache`); the
# suite runs without it, so no test depends on what an earlier test or run left there
# (tests/test_compile_cache.py turns it on in its own processes and directories).
os.environ["FOVJAX_COMPILE_CACHE"] = "0"
# ... but one run's two workers share what they compile: a fresh directory made by the run's
# first process (xdist's controller, whose environment the workers inherit) and removed at its
# end, so a program both workers need (the same frame configuration in two test files) is
# compiled once. Nothing outlives the run. FOVJAX_TEST_SHARED_COMPILES=0 turns it off.
_SHARED = "FOVJAX_TEST_COMPILE_DIR"
if os.environ.get("FOVJAX_TEST_SHARED_COMPILES", "1") != "0" and _SHARED not in os.environ:
    os.environ[_SHARED] = tempfile.mkdtemp(prefix="fovjax-test-compiles-")
    _OWN_SHARED = True
else:
    _OWN_SHARED = False

# The suite compiles for a short compile, not a fast program (tests/_frames.py FAST_COMPILE_FLAGS):
# LLVM's lowest optimisation level, and XLA:CPU's loop emitters for every program (the frame
# programs use them anyway, `fovjax.render.internal.LOOP_EMITTERS`). A frame program then
# compiles about three times faster, the trace tests' programs about a third faster, and the
# tests' small frames run a few times slower; most of the suite's time is compiling. The
# arithmetic is the same IEEE float32 (no fast-math either way); instruction choices such as
# fused multiply-adds differ, so two programs that compute one thing agree to float32 rounding
# (tests/_frames.py), not always bit for bit. The processes the suite starts inherit the flags;
# tests/test_compile_cache.py runs the command line as users do and compares its frame with one
# compiled the suite's way. FOVJAX_TEST_FAST_COMPILE=0 compiles the whole suite as users do.
if os.environ.get("FOVJAX_TEST_FAST_COMPILE", "1") != "0":
    _flags = os.environ.get("XLA_FLAGS", "").split()
    os.environ["XLA_FLAGS"] = " ".join(_flags + [f for f in FAST_COMPILE_FLAGS if f not in _flags])

if os.environ.get("FOVJAX_TYPECHECK", "1") != "0":
    from beartype import BeartypeConf, beartype
    from jaxtyping import install_import_hook

    # The hook names its typechecker by import path: register one configured for the package.
    checker = types.ModuleType("_fovjax_typecheck")
    checker.typecheck = beartype(conf=BeartypeConf(is_pep484_tower=True))
    sys.modules[checker.__name__] = checker
    install_import_hook("fovjax", "_fovjax_typecheck.typecheck")


# FOVJAX_TEST_COMPILE_LOG=DIR: every worker appends what JAX spends compiling (tracing, lowering,
# XLA, persistent-cache reads) to DIR/compiles-<worker>.jsonl, one line per event, with the test
# that caused it; `python tests/compile_report.py DIR` sums it by file and test. Timing only: the
# suite's results do not depend on it.
_COMPILE_LOG = os.environ.get("FOVJAX_TEST_COMPILE_LOG")
_current_test = ["(collection)"]


def _log_compiles(directory: str) -> None:
    import json

    import jax.monitoring

    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    os.makedirs(directory, exist_ok=True)
    log = open(os.path.join(directory, f"compiles-{worker}.jsonl"), "a", buffering=1)  # noqa: SIM115
    events = {
        "/jax/core/compile/jaxpr_trace_duration": "trace",
        "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
        "/jax/core/compile/backend_compile_duration": "xla",
        "/jax/compilation_cache/cache_retrieval_time_sec": "cache_read",
    }

    def listener(event, duration, **kwargs):
        kind = events.get(event)
        if kind is not None and duration >= 0.01:
            row = {
                "test": _current_test[0],
                "kind": kind,
                "s": round(duration, 4),
                "fun": kwargs.get("fun_name"),
            }
            log.write(json.dumps(row) + "\n")

    jax.monitoring.register_event_duration_secs_listener(listener)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    _current_test[0] = item.nodeid
    yield
    _current_test[0] = "(between tests)"


def pytest_configure(config):
    if _COMPILE_LOG:
        _log_compiles(_COMPILE_LOG)
    if os.environ.get(_SHARED):
        import jax

        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
        jax.config.update("jax_compilation_cache_dir", os.environ[_SHARED])
    config.addinivalue_line(
        "markers",
        "no_typecheck: the test checks the package's own validation of bad arguments (its ValueError "
        "and message), which the annotation check would otherwise preempt with a TypeError",
    )
    config.addinivalue_line(
        "markers",
        "extras(*modules): the test needs these optional extras' modules (tests/_extras.py `needs`)",
    )


@pytest.fixture(autouse=True)
def _required_extras(request):
    """A test marked by `_extras.needs` gets its modules through `_extras.require`: a skip that
    names the extra, or a failure with FOVJAX_REQUIRE_EXTRAS=1."""
    for mark in request.node.iter_markers("extras"):
        for module in mark.args:
            _extras.require(module)


@pytest.fixture(autouse=True)
def _annotation_checks(request):
    """Annotation checks stay on, except in tests marked `no_typecheck`."""
    if request.node.get_closest_marker("no_typecheck") is None:
        yield
        return
    import jaxtyping

    jaxtyping.config.update("jaxtyping_disable", True)
    try:
        yield
    finally:
        jaxtyping.config.update("jaxtyping_disable", False)


def pytest_unconfigure(config):
    if _OWN_SHARED:
        shutil.rmtree(os.environ.pop(_SHARED), ignore_errors=True)


# pytest-xdist hands each worker whole files (pyproject: --dist loadfile), in collection order
# (--no-loadscope-reorder). The files that take longest go first, so that the last files the two
# workers take are short ones and neither waits long for the other at the end. Mostly compile
# time; the order changes only how long the run takes. Ranked by `--durations=0` summed per file,
# the mean of four runs (the suite's compile settings, 2 and 3 workers); every file of 5 s or more.
SLOWEST_FIRST = (
    "test_render_native.py",
    "test_trace.py",
    "test_trace_native.py",
    "test_view_study.py",
    "test_eval_shard.py",
    "test_docs.py",
    "test_compile_cache.py",
    "test_view_xr.py",
    "test_bad_inputs.py",
    "test_foveate_tiles.py",
    "test_fidelity_texture_lod.py",
    "test_fidelity_lod.py",
    "test_view.py",
    "test_compare_video.py",
    "test_acuity_posterior.py",
    "test_foveate.py",
    "test_eval_compare.py",
    "test_foveate_methods.py",
    "test_bvh.py",
    "test_renderer.py",
    "test_shading_options.py",
    "test_render_grad.py",
    "test_eval_failures.py",
    "test_foveate_batches.py",
    "test_eval_study_cli.py",
    "test_render.py",
    "test_eval_video_study.py",
    "test_acuity_compare_cli.py",
    "test_render_warp.py",
    "test_foveate_frame.py",
    "test_session.py",
    "test_render_replay.py",
    "test_foveate_blur.py",
    "test_thesis_rule.py",
    "test_acuity_fit.py",
    "test_trace_properties.py",
    "test_eval_stability.py",
    "test_trace_sorted.py",
    "test_malloc_settings.py",
    "test_foveate_gradients.py",
    "test_compile_once.py",
    "test_fidelity.py",
    "test_plan_fidelity.py",
    "test_inspect.py",
    "test_lod.py",
    "test_acuity_measured.py",
    "test_foveate_positions.py",
)


def pytest_collection_modifyitems(config, items):
    here = os.path.dirname(__file__)
    for name in SLOWEST_FIRST:
        if not os.path.isfile(os.path.join(here, name)):
            raise pytest.UsageError(f"tests/conftest.py SLOWEST_FIRST names {name!r}, which is not in tests/")
    rank = {name: i for i, name in enumerate(SLOWEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: the rest keep their order
