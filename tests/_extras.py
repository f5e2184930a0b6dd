"""The one way a test gets an optional extra (a module of one of pyproject's optional
dependency groups): `require(module)` returns it, `needs(module, ...)` marks a test that needs
it, `have(module)` says whether it is installed (for a test that checks what the package does
without it).

Without the extra the test skips and the reason names the pip command. With
FOVJAX_REQUIRE_EXTRAS=1 (`.ci/run`, which installs every extra) a missing extra fails the test
instead, and `have` fails rather than answer False, so a broken install cannot pass as a skip
or as a silently narrower assertion. tests/test_extras_guards.py checks that no test guards an
import any other way (`pytest.importorskip`, `find_spec`, a `skipif` on a module, its own
`except ImportError`, or its own reading of the variable)."""

from __future__ import annotations

import importlib
import importlib.util
import os

import pytest

# module -> the extra (pyproject's [project.optional-dependencies]) that installs it
EXTRAS = {
    "aiohttp": "view",
    "beartype": "dev",
    "cv2": "hdr",
    "embreex": "embree",
    "fast_simplification": "lod",
    "flip_evaluator": "flip",
    "imageio_ffmpeg": "video",
    "mitsuba": "bench",
    "mkdocs": "docs",
    "mkdocstrings_handlers.python": "docs",
    "msgpack": "pupil",
    "pyfvvdp": "fvvdp",
    "pyright": "dev",
    "selenium": "dev",
    "torch": "fvvdp",
    "warp": "gpu",
    "zmq": "pupil",
}
REQUIRE_VARIABLE = "FOVJAX_REQUIRE_EXTRAS"


def required() -> bool:
    """Whether a missing extra fails (FOVJAX_REQUIRE_EXTRAS=1) rather than skips."""
    return os.environ.get(REQUIRE_VARIABLE, "").strip() == "1"


def _extra(module: str) -> str:
    if module not in EXTRAS:
        raise KeyError(f"tests/_extras.py: {module!r} is not an optional extra's module; add it to EXTRAS")
    return EXTRAS[module]


def _missing(module: str, why: str | None = None) -> str:
    extra = _extra(module)
    because = f" ({why})" if why else ""
    return f"{module} is not installed{because}: pip install 'fovjax[{extra}]'"


def require(module: str, *, module_level: bool = False):
    """`module` imported, or a skip naming the extra (a failure with FOVJAX_REQUIRE_EXTRAS=1).
    `module_level`: called at a test file's top level, skipping the whole file."""
    _extra(module)
    try:
        return importlib.import_module(module)
    except ImportError as err:
        text = _missing(module, str(err) if importlib.util.find_spec(module) else None)
        if required():
            pytest.fail(f"{text}; {REQUIRE_VARIABLE}=1 requires every extra", pytrace=False)
        pytest.skip(text, allow_module_level=module_level)


def have(module: str) -> bool:
    """Whether `module` is installed. With FOVJAX_REQUIRE_EXTRAS=1 a missing module fails here:
    a test may narrow its assertions to what is installed only outside CI."""
    _extra(module)
    present = importlib.util.find_spec(module) is not None
    if not present and required():
        pytest.fail(f"{_missing(module)}; {REQUIRE_VARIABLE}=1 requires every extra", pytrace=False)
    return present


def needs(*modules: str) -> pytest.MarkDecorator:
    """Mark a test that needs `modules`: tests/conftest.py calls `require` on each before the
    test runs."""
    for module in modules:
        _extra(module)
    return pytest.mark.extras(*modules)
