"""No public function or method takes more than `MAX_PARAMETERS` parameters: options that travel
together are one small frozen object (`SessionConfig`, `ThresholdSweep`, `StudyAnimation`, ...),
not a keyword list (issue 31, "configs and strategies, not keyword lists").

The walk reaches every name in the `__all__` of `fovjax` and of each of its packages: functions,
and the public methods, class methods and static methods of classes. A parameter is anything in
the signature but `self`/`cls`, positional and keyword-only alike, `*args` and `**kwargs` one
each. A configuration object's constructor is not counted: its fields are set by keyword and
checked when it is made, which is the point of it.

The limit holds for every package (`CHECKED_PACKAGES`: all of `fovjax`).
"""

from __future__ import annotations

import importlib
import inspect

import pytest

MAX_PARAMETERS = 10
# The packages whose public callables the limit is asserted on (by the module that defines them):
# the whole package.
CHECKED_PACKAGES = ("fovjax",)
# Every package whose `__all__` is walked.
PACKAGES = (
    "fovjax",
    "fovjax.files",
    "fovjax.scene",
    "fovjax.scenes",
    "fovjax.trace",
    "fovjax.render",
    "fovjax.foveate",
    "fovjax.acuity",
    "fovjax.devices",
    "fovjax.eval",
    "fovjax.session",
    "fovjax.view",
    "fovjax.cli",
)


def parameter_count(fn) -> int:
    """Parameters of `fn` but `self`/`cls`."""
    params = inspect.signature(fn).parameters
    return sum(1 for name in params if name not in ("self", "cls"))


def _callables(obj, qualname: str):
    """(qualified name, defining module, callable) of `obj` and, for a class, its own public
    methods, class methods and static methods."""
    if inspect.isclass(obj):
        for name, member in vars(obj).items():
            if name.startswith("_"):
                continue
            if isinstance(member, staticmethod | classmethod):
                member = member.__func__
            if inspect.isfunction(member):
                yield f"{qualname}.{name}", member.__module__, member
    elif inspect.isfunction(obj) or inspect.isbuiltin(obj):
        yield qualname, getattr(obj, "__module__", "") or "", obj


def public_callables():
    """Every public callable reachable from the packages' `__all__`, each once (the first name
    it is reached by)."""
    seen, found = set(), []
    for package in PACKAGES:
        module = importlib.import_module(package)
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name)
            for qualname, defined_in, fn in _callables(obj, f"{package}.{name}"):
                if id(fn) in seen:
                    continue
                seen.add(id(fn))
                found.append((qualname, defined_in, fn))
    return found


def _checked(defined_in: str) -> bool:
    return any(defined_in == p or defined_in.startswith(p + ".") for p in CHECKED_PACKAGES)


def over_the_limit(callables) -> list[str]:
    """`name (n parameters, defined in module)` for each checked callable over the limit."""
    out = []
    for qualname, defined_in, fn in callables:
        if not _checked(defined_in):
            continue
        try:
            n = parameter_count(fn)
        except (TypeError, ValueError):  # a builtin without a signature
            continue
        if n > MAX_PARAMETERS:
            out.append(f"{qualname} ({n} parameters, defined in {defined_in})")
    return out


def test_no_public_function_takes_more_than_ten_parameters():
    assert over_the_limit(public_callables()) == []


def test_the_walk_reaches_the_entry_points_of_every_checked_package():
    reached = {qualname for qualname, _, _ in public_callables()}
    for name in (
        "fovjax.run_session",
        "fovjax.eval.compare_thresholds",
        "fovjax.eval.video_study",
        "fovjax.eval.plan_fidelity",
        "fovjax.eval.after_saccade",
        "fovjax.acuity.sample_posterior",
        "fovjax.make_scene",
        "fovjax.FoveatedRenderer.render",
        "fovjax.trace.closest_hit",
        "fovjax.render.render_stereo",
    ):
        assert name in reached, name
    checked = {defined_in.split(".")[1] for _, defined_in, _ in public_callables() if _checked(defined_in)}
    # every package with public functions is reached (by the module that defines them)
    assert {"eval", "session", "acuity", "scene", "render", "trace", "foveate", "files"} <= checked


def _eleven(a, b, c, d, e, f, g, h, i, j, k):
    """A function over the limit, for the check's own test."""


class _Wide:
    def method(self, a, b, c, d, e, f, g, h, i, j, *rest, **options):
        """Ten named parameters and `*rest`, `**options`: twelve; `self` is not counted."""


@pytest.mark.parametrize(("fn", "expected"), [(_eleven, 11), (_Wide.method, 12), (lambda self: None, 0)])
def test_the_count_is_of_the_signature_without_self(fn, expected):
    assert parameter_count(fn) == expected


def test_the_check_names_a_callable_over_the_limit():
    found = [
        ("fovjax.eval.wide", "fovjax.eval._wide", _eleven),
        ("fovjax.render.wide", "fovjax.render._wide", _eleven),
        ("elsewhere.wide", "elsewhere._wide", _eleven),  # not fovjax's
        *_callables(_Wide, "fovjax.session.Wide"),
    ]
    found[3] = (found[3][0], "fovjax.session._loop", found[3][2])
    assert over_the_limit(found) == [
        "fovjax.eval.wide (11 parameters, defined in fovjax.eval._wide)",
        "fovjax.render.wide (11 parameters, defined in fovjax.render._wide)",
        "fovjax.session.Wide.method (12 parameters, defined in fovjax.session._loop)",
    ]
