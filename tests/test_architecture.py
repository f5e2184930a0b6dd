"""The layout's rules, read from the source with `ast` (docs/concepts/architecture.md).

Every `import` and `from ... import` in every module of `fovjax` is resolved to the package it
reaches (`fovjax.<package>`; the top-level modules belong to the package `fovjax` itself), then:

(a) a package never imports another package's private module (`fovjax.render._frame`) or a
    private name (`from fovjax.render import _bvh_for`): what is shared is exported;
(b) the core packages never import the application layer (the CLI, the session loop, eval, the
    viewer, or the `fovjax` top level that re-exports all of them);
(c) `render` never imports `foveate` (foveation is built on the full renderer, not inside it);
(d) every import between packages is one the table `MAY_IMPORT` allows (the table of
    docs/concepts/architecture.md);
(e) a name imported from another package's top (`from fovjax.render import run_compiled`) is in
    that package's `__all__`: what siblings share and users do not need lives in the package's
    `internal` module (`fovjax.render.internal`), imported by name;
(f) the layers a user stands on, the command line and the `fovjax` top level, import no
    `internal` module: they use the library as a user would;
(g) the foundation modules (`FOUNDATION`: the environment variables and cache directory, what
    importing fovjax does first), which any package may import, import nothing else of fovjax.

Every package, and every `internal` module, defines `__all__` (`test_every_package_defines_all`).

Imports inside functions count as much as those at the top of a file.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "fovjax"
ROOT = "fovjax"  # the top level: fovjax/__init__.py and fovjax/_*.py

CORE = ("native", "files", "scene", "trace", "render", "foveate", "acuity", "devices")
# Top-level modules below every package, each imported by name by any of them (docs/concepts/
# architecture.md): every environment variable and the cache directory, and what every process
# does as it imports fovjax, before JAX starts.
FOUNDATION = ("fovjax._environment", "fovjax._startup")
APPLICATION = ("eval", "session", "view", "cli", ROOT)

# Which package may import which (besides itself). Core first, bottom-up.
MAY_IMPORT = {
    # The native handlers' build, load and the native/JAX choice: below every package that
    # owns a native stage.
    "native": set(),
    "files": set(),
    "scene": set(),
    "trace": {"native", "scene"},
    "acuity": set(),
    "devices": set(),
    "render": {"native", "files", "scene", "trace"},
    "foveate": {"native", "files", "scene", "trace", "render", "acuity"},
    "eval": {"files", "scene", "trace", "render", "foveate", "acuity", "devices"},
    "session": {"files", "scene", "trace", "render", "foveate", "acuity", "devices"},
    "view": {"files", "scene", "trace", "render", "foveate", "acuity", "devices", "session"},
    # The commands call the library as a user would, through `fovjax.*` (ROOT) too.
    "cli": {
        "files",
        "scene",
        "trace",
        "render",
        "foveate",
        "acuity",
        "devices",
        "eval",
        "session",
        "view",
        ROOT,
    },
    # The top level re-exports the public API; `python -m fovjax` (__main__) runs the CLI;
    # `fovjax.plan_fidelity` comes from eval (imported on first use).
    ROOT: {"files", "scene", "trace", "render", "foveate", "acuity", "devices", "session", "eval", "cli"},
}


def _private(part: str) -> bool:
    return part.startswith("_") and not (part.startswith("__") and part.endswith("__"))


# Top-level modules that only re-export one package, counted as that package.
ALIASES = {"scenes": "scene"}  # fovjax/scenes.py: `fovjax.scenes.atrium()` as it always was


def package_of(module: str) -> str:
    """`fovjax.render._frame` -> "render"; `fovjax`, `fovjax._dispatch` -> the top level;
    `fovjax.scenes` -> "scene"."""
    parts = module.split(".")
    if len(parts) > 1 and parts[1] in ALIASES:
        return ALIASES[parts[1]]
    if len(parts) == 1 or (PACKAGE / parts[1]).is_dir() is False:
        return ROOT
    return parts[1]


def module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports(path: Path, tree: ast.AST | None = None):
    """(line, target module, imported names) for each import of a `fovjax` module in `path`;
    relative imports are resolved. `from fovjax import scene` targets `fovjax.scene`."""
    tree = tree or ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    me = module_name(path).split(".")
    here = me if path.name == "__init__.py" else me[:-1]  # the package a relative import starts in
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == ROOT:
                    yield node.lineno, alias.name, ()
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = here[: len(here) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != ROOT:
                continue
            names = tuple(a.name for a in node.names)
            if target == ROOT:  # `from fovjax import render, tonemap`: a subpackage or a name
                for name in names:
                    if (PACKAGE / name).is_dir() or (PACKAGE / f"{name}.py").is_file():
                        yield node.lineno, f"{ROOT}.{name}", ()
                    else:
                        yield node.lineno, ROOT, (name,)
            else:
                yield node.lineno, target, names


def _sources():
    return sorted(p for p in PACKAGE.rglob("*.py") if "static" not in p.parts)


@functools.cache  # the package's sources do not change while the suite runs
def declared_all(module: str) -> set[str] | None:
    """The names in `module`'s `__all__` (read from its source), None when it has none."""
    parts = module.split(".")[1:]
    path = PACKAGE.joinpath(*parts)
    path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    if not path.is_file():
        return None
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "__all__" for t in node.targets):
            return {ast.literal_eval(e) for e in node.value.elts}
    return None


def _is_submodule(module: str, name: str) -> bool:
    path = PACKAGE.joinpath(*module.split(".")[1:], name)
    return path.is_dir() or path.with_suffix(".py").is_file()


def check(path: Path, tree: ast.AST | None = None) -> dict[str, list[str]]:
    """Every rule `path` breaks, by rule letter, as `file:line: what`."""
    found = {"a": [], "b": [], "c": [], "d": [], "e": [], "f": [], "g": []}
    me = module_name(path)
    mine = package_of(me)
    where = path.relative_to(PACKAGE.parent)
    for line, target, names in imports(path, tree):
        if me in FOUNDATION and target not in FOUNDATION:
            found["g"].append(f"{where}:{line}: foundation module {me} imports {target}")
        if target in FOUNDATION:
            continue
        theirs = package_of(target)
        if theirs == mine:
            continue
        at = f"{where}:{line}"
        if any(_private(p) for p in target.split(".")[1:]):
            found["a"].append(f"{at}: imports the private module {target}")
        hidden = [n for n in names if _private(n)]
        if hidden:
            found["a"].append(f"{at}: imports the private name(s) {', '.join(hidden)} from {target}")
        if mine in CORE and theirs in APPLICATION:
            found["b"].append(f"{at}: core package {mine!r} imports {target} (application layer)")
        if mine == "render" and theirs == "foveate":
            found["c"].append(f"{at}: render imports {target}")
        if theirs not in MAY_IMPORT.get(mine, set()):
            found["d"].append(f"{at}: {mine!r} imports {theirs!r} ({target}), not in MAY_IMPORT")
        if target == f"{ROOT}.{theirs}" and theirs in MAY_IMPORT:  # a package's top
            public = declared_all(target) or set()
            unlisted = [
                n for n in names if not _private(n) and n not in public and not _is_submodule(target, n)
            ]
            if unlisted:
                found["e"].append(
                    f"{at}: imports {', '.join(unlisted)} from {target}, not in its __all__ "
                    f"(shared plumbing comes from {target}.internal)"
                )
        reaches_internal = target.split(".")[-1] == "internal" or "internal" in names
        if mine in ("cli", ROOT) and reaches_internal:
            found["f"].append(f"{at}: {mine!r} imports an internal module ({target})")
    return found


@functools.cache  # read once for every rule's test
def violations() -> dict[str, list[str]]:
    found = {"a": [], "b": [], "c": [], "d": [], "e": [], "f": [], "g": []}
    for path in _sources():
        for rule, hits in check(path).items():
            found[rule] += hits
    return found


def test_every_package_has_a_place_in_the_table():
    packages = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()}
    message = "a new package needs a row in MAY_IMPORT and docs/concepts/architecture.md"
    assert packages == set(MAY_IMPORT) - {ROOT}, message
    assert set(CORE) | set(APPLICATION) == set(MAY_IMPORT)
    for core in CORE:  # the table itself keeps the layers apart
        assert not MAY_IMPORT[core] & set(APPLICATION), core
    assert "foveate" not in MAY_IMPORT["render"]


@pytest.mark.parametrize(
    "rule",
    [
        pytest.param("a", id="no-private-reach-ins"),
        pytest.param("b", id="core-imports-no-application"),
        pytest.param("c", id="render-imports-no-foveate"),
        pytest.param("d", id="only-allowed-package-imports"),
        pytest.param("e", id="only-public-names-from-a-package-top"),
        pytest.param("f", id="user-layers-import-no-internal"),
        pytest.param("g", id="foundation-imports-nothing-of-fovjax"),
    ],
)
def test_import_rules(rule):
    broken = violations()[rule]
    assert not broken, "\n".join(broken)


BAD = {
    # file written into a copy of the package -> the rule it must break
    "render/_bad.py": ("from ..foveate import Foveation\n", {"c", "d"}),
    "foveate/_bad.py": ("from ..render._frame import render_image\n", {"a"}),
    "eval/_bad.py": ("from fovjax.render import _bvh_for\n", {"a"}),
    "scene/_bad.py": ("def f():\n    from ..cli import main\n", {"b", "d"}),
    "trace/_bad.py": ("import fovjax.session\n", {"b", "d"}),
    "devices/_bad.py": ("from .. import run_session\n", {"b", "d"}),
    "acuity/_bad.py": ("from ..render import render_image\n", {"d"}),
    "foveate/_bad2.py": ("from ..render import run_compiled\n", {"e"}),
    "cli/_bad.py": ("from ..foveate.internal import foveated_stereo\n", {"f"}),
    "_bad.py": ("from .render import internal\n", {"f"}),
    "_environment.py": ("from .trace import build_bvh\n", {"g"}),
    "_startup.py": ("import fovjax.render\n", {"g"}),
    # any package may import a foundation module, private as its name is
    "trace/_bad2.py": ("from .. import _environment\nfrom fovjax._startup import MALLOC\n", set()),
}


def _packages_and_internals():
    packages = sorted(p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file())
    internals = sorted(f"{p.parent.name}.internal" for p in PACKAGE.glob("*/internal.py"))
    return [ROOT] + [f"{ROOT}.{p}" for p in packages + internals]


@pytest.mark.parametrize("module", _packages_and_internals())
def test_every_package_defines_all(module):
    """`__all__` says what a package offers; every name in it exists."""
    import importlib

    names = declared_all(module)
    assert names, f"{module} defines no __all__"
    loaded = importlib.import_module(module)
    missing = [n for n in sorted(names) if not hasattr(loaded, n)]
    assert not missing, f"{module}.__all__ names what it does not define: {missing}"


def test_moved_names_still_import_with_a_deprecation():
    """Old import paths of what moved to an internal module keep working, and say where it went."""
    import fovjax.foveate
    import fovjax.render

    with pytest.warns(DeprecationWarning, match="fovjax.render.internal"):
        assert fovjax.render.run_compiled is fovjax.render.internal.run_compiled
    with pytest.warns(DeprecationWarning, match="fovjax.foveate.internal"):
        assert fovjax.foveate.foveated_stereo is fovjax.foveate.internal.foveated_stereo


@pytest.mark.parametrize("name", sorted(BAD))
def test_the_checker_catches_a_bad_import(name):
    """Each rule fails on a module that breaks it (so the rules above can fail)."""
    source, rules = BAD[name]
    found = check(PACKAGE / name, ast.parse(source))
    assert {rule for rule, hits in found.items() if hits} == rules, found


def test_the_scenes_alias_counts_as_scene():
    got = list(imports(PACKAGE / "eval" / "_x.py", ast.parse("from ..scenes import default_camera\n")))
    assert [package_of(t) for _, t, _ in got] == ["scene"]
    assert (PACKAGE / "scenes.py").read_text().count("from .scene import") >= 1


def test_a_private_module_of_the_same_package_is_fine():
    path = PACKAGE / "render" / "_x.py"
    got = list(imports(path, ast.parse("from ._frame import render_image\nfrom . import _vec\n")))
    assert [package_of(t) for _, t, _ in got] == ["render", "render"]


# ---- the native sources -------------------------------------------------------------------------
#
# Each native stage lives with the package that owns its JAX oracle: a `.cc`/`.h` file under
# fovjax/<package>/ belongs to that package. The handlers each package may define, and the
# packages whose sources a package's source may include, follow the Python layers.

NATIVE_HANDLERS = {
    "native": set(),
    "trace": {"FovjaxEmbreeQuery"},
    "render": {"FovjaxEmbreeWhitted", "FovjaxWhittedAdjoint", "FovjaxCameraFrame"},
    "foveate": {
        "FovjaxSelectSamples",
        "FovjaxWhittedSlots",
        "FovjaxFillAndBlur",
        "FovjaxTaaBlend",
        "FovjaxPatneyPrefilter",
        "FovjaxLayerBlend",
    },
}
NATIVE_ENTRY = PACKAGE / "native" / "csrc" / "library.cc"
# The one `thread_local`: `ThreadLocal<T>()` takes the thread's address once per call, where each
# use of a `thread_local` in a shared library may call __tls_get_addr, inside loops too.
THREAD_LOCAL_HOME = PACKAGE / "native" / "csrc" / "thread_pool.h"


def _native_sources():
    return sorted(p for p in PACKAGE.rglob("*") if p.suffix in (".cc", ".h"))


def native_check(path: Path, text: str | None = None) -> list[str]:
    """Every rule the native source `path` breaks, as `file:line: what`."""
    import re

    text = path.read_text(encoding="utf-8") if text is None else text
    mine = path.relative_to(PACKAGE).parts[0]
    where = path.relative_to(PACKAGE.parent)
    found = []
    if mine not in NATIVE_HANDLERS:
        found.append(f"{where}: native source in {mine!r}, which owns no native stage")
        return found
    for line, row in enumerate(text.splitlines(), start=1):
        handler = re.match(r"\s*XLA_FFI_DEFINE_HANDLER_SYMBOL\((\w+)", row)
        if handler and handler.group(1) not in NATIVE_HANDLERS[mine]:
            owner = [p for p, names in NATIVE_HANDLERS.items() if handler.group(1) in names]
            found.append(f"{where}:{line}: defines {handler.group(1)} (owned by {owner or 'nobody'})")
        code = row.split("//")[0]
        if re.search(r"\bthread_local\b", code) and path != THREAD_LOCAL_HOME:
            home = THREAD_LOCAL_HOME.name
            found.append(f"{where}:{line}: a thread_local variable (use ThreadLocal<T>(), {home})")
        include = re.match(r'\s*#include "(\w+)/', row)
        if include and path != NATIVE_ENTRY and (PACKAGE / include.group(1)).is_dir():
            theirs = include.group(1)
            if theirs != mine and theirs not in MAY_IMPORT.get(mine, set()):
                found.append(f"{where}:{line}: includes {theirs!r}'s source, not in MAY_IMPORT[{mine!r}]")
    return found


def test_native_sources_follow_their_owners():
    broken = [hit for path in _native_sources() for hit in native_check(path)]
    assert not broken, "\n".join(broken)


def test_every_native_source_is_built_and_every_handler_is_owned():
    """The build's one translation unit includes every native source, and each handler the
    library registers is defined in its owner's source."""
    import re

    from fovjax.native._library import HANDLERS

    included, todo = set(), [NATIVE_ENTRY]
    while todo:
        path = todo.pop()
        for name in re.findall(r'#include "([\w/.]+)"', path.read_text(encoding="utf-8")):
            target = PACKAGE / name
            if target.is_file() and target not in included:
                included.add(target)
                todo.append(target)
    assert set(_native_sources()) - {NATIVE_ENTRY} == included
    defined = {}
    for path in _native_sources():
        for name in re.findall(r"XLA_FFI_DEFINE_HANDLER_SYMBOL\((\w+)", path.read_text(encoding="utf-8")):
            defined[name] = path.relative_to(PACKAGE).parts[0]
    assert set(defined) == set(HANDLERS.values())
    assert all(name in NATIVE_HANDLERS[owner] for name, owner in defined.items())


NATIVE_BAD = {
    # a source written into a package -> what the checker must say
    "trace/_bad.cc": ("XLA_FFI_DEFINE_HANDLER_SYMBOL(FovjaxEmbreeWhitted, Whitted,\n", "owned by ['render']"),
    "render/_bad.cc": ('#include "foveate/_slots.cc"\n', "includes 'foveate'"),
    "trace/_bad2.cc": ('#include "render/_whitted.cc"\n', "includes 'render'"),
    "acuity/_bad.cc": ("int x;\n", "owns no native stage"),
    "render/_bad3.cc": ("  thread_local std::vector<float> rows;  // a band's\n", "thread_local variable"),
}


@pytest.mark.parametrize("name", sorted(NATIVE_BAD))
def test_the_checker_catches_a_misplaced_native_stage(name):
    source, says = NATIVE_BAD[name]
    found = native_check(PACKAGE / name, source)
    assert len(found) == 1 and says in found[0], found
