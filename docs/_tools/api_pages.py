"""Write the API reference pages (docs/api/*.md) from the packages' public names.

A package's public names are its `__all__` when it has one, else what its `__init__.py` defines
without a leading underscore and what it re-exports as `from ._x import name as name` (the
explicit re-export the packages use). Each page lists them for mkdocstrings, so a name added to a
package appears on its page when this is re-run; tests/test_docs.py fails while a page is stale
and checks that the built site has an entry for every name. A page lists functions and classes
first, then constants and type aliases; a name two packages export for two different functions
gets a line on both pages saying which is which.

    python docs/_tools/api_pages.py          # rewrite the pages
    python docs/_tools/api_pages.py --check  # exit 1 if a page would change
"""

import argparse
import ast
import functools
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
API = ROOT / "docs" / "api"

# (module, page, one line on what it is). The order is the reference's.
PACKAGES = [
    (
        "fovjax",
        "fovjax.md",
        "The flat public API: the calls most programs need, re-exported from the packages.",
    ),
    ("fovjax.scene", "scene.md", "Scenes, cameras, loaders, built-in scenes and geometry level of detail."),
    ("fovjax.scenes", "scenes.md", "The built-in procedural scenes and their default cameras."),
    ("fovjax.files", "files.md", "Images in and out; writes that are complete or absent."),
    ("fovjax.trace", "trace.md", "BVH construction, ray queries and ray-query backends."),
    ("fovjax.native", "native.md", "The native handlers: whether they built here, their Embree scenes."),
    ("fovjax.render", "render.md", "The Whitted renderer, the stereo HMD rig and the compile cache."),
    (
        "fovjax.render.internal",
        "render_internal.md",
        "What the packages built on the renderer share: not stable API.",
    ),
    ("fovjax.foveate", "foveate.md", "Eccentricity, regions, sampling, the ray budget, fill and blur."),
    ("fovjax.foveate.internal", "foveate_internal.md", "The foveated frame's parts (not stable)."),
    ("fovjax.acuity", "acuity.md", "Acuity models, fits, posteriors and model choice."),
    ("fovjax.devices", "devices.md", "Eye and head tracking sources, filters, recordings, fallback."),
    ("fovjax.session", "session.md", "The session loop: foveated frames following gaze and head sources."),
    ("fovjax.eval", "eval.md", "Metrics, threshold comparison, study protocols, failure cases, plans."),
    ("fovjax.view", "view.md", "The live viewer."),
    ("fovjax.cli", "cli.md", "The `fovjax` command and the argument checkers its subcommands share."),
]

# Names reachable on a package that its `__init__.py` does not bind (module `__getattr__`).
LAZY = {"fovjax": ["compare_thresholds", "plan_fidelity", "video_study"]}


def init_file(module: str) -> Path:
    path = ROOT / Path(*module.split("."))
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


def public_names(module: str) -> tuple[list[str], list[str]]:
    """(names, subpackages): the public names of `module` in source order; subpackages re-exported
    as `from . import x as x` are listed apart (they have their own pages)."""
    tree = ast.parse(init_file(module).read_text())
    names, modules = [], []
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "__all__" for t in node.targets):
            return [ast.literal_eval(e) for e in node.value.elts], []
    for node in tree.body:
        if isinstance(node, ast.ImportFrom):
            for alias in node.names:
                if alias.asname and alias.asname == alias.name and not alias.name.startswith("_"):
                    (modules if node.module is None else names).append(alias.name)
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef)) and not node.name.startswith("_"):
            names.append(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names += [t.id for t in targets if isinstance(t, ast.Name) and not t.id.startswith("_")]
    return names, modules


def _module_file(module: str) -> Path | None:
    path = ROOT / Path(*module.split("."))
    for candidate in (path / "__init__.py", path.with_suffix(".py")):
        if candidate.exists():
            return candidate
    return None


def _top_level(tree: ast.Module):
    """The module's top-level statements, those under `if`/`try` included."""
    for node in tree.body:
        if isinstance(node, (ast.If, ast.Try)):
            for block in (node.body, getattr(node, "orelse", []), getattr(node, "finalbody", [])):
                yield from block
            for handler in getattr(node, "handlers", []):
                yield from handler.body
        else:
            yield node


@functools.cache
def _parse(path: Path) -> ast.Module:
    return ast.parse(path.read_text())


@functools.cache
def definition(module: str, name: str) -> tuple[str, ast.AST]:
    """(module, node): where `module.name` is defined in the source, following the packages'
    re-exports (`from ._x import name`). The node is a def, a class or an assignment."""
    path = _module_file(module)
    if path is None:
        raise LookupError(f"{module}.{name}: no source file for {module}")
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in _top_level(_parse(path)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node.name == name:
            return module, node
        if isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            if any(isinstance(t, ast.Name) and t.id == name for t in targets):
                return module, node
        if isinstance(node, ast.ImportFrom) and node.level > 0:
            for alias in node.names:
                if (alias.asname or alias.name) == name:
                    base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                    source = f"{base}.{node.module}" if node.module else base
                    return definition(source, alias.name)
    raise LookupError(f"{module}.{name}: not defined or re-exported in {path.relative_to(ROOT)}")


def is_data(module: str, name: str) -> bool:
    """A constant or a type alias (an assignment), not a function or a class."""
    return isinstance(definition(module, name)[1], (ast.Assign, ast.AnnAssign))


def summary(node: ast.AST) -> str:
    """The first sentence of a def's or class's docstring, on one line."""
    doc = " ".join((ast.get_docstring(node) or "").split())
    return doc.split(". ")[0].rstrip(".") + "." if doc else ""


def _shape(node: ast.AST) -> str:
    """What tells two definitions of one name apart: a function's parameters; a class is its own."""
    if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
        return ast.unparse(node.args)
    return f"class at line {node.lineno}"


@functools.cache
def same_names() -> dict[str, list[tuple[str, str, str, str]]]:
    """Names that packages export for different functions (other parameters) or classes: name ->
    [(module, page, summary, "function" or "class"), ...] in the reference's order. The reference
    says which is which on each of their pages. A function re-exported, or wrapped with the same
    parameters, is one."""
    found: dict[str, dict[tuple[str, str], tuple[str, str, str, str]]] = {}
    for module, page_name, _ in PACKAGES:
        for name in public_names(module)[0]:
            where, node = definition(module, name)
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                continue
            kind = "class" if isinstance(node, ast.ClassDef) else "function"
            key = (kind, _shape(node) + where if kind == "class" else _shape(node))
            found.setdefault(name, {}).setdefault(key, (module, page_name, summary(node), kind))
    return {name: list(defs.values()) for name, defs in found.items() if len(defs) > 1}


def page(module: str, blurb: str) -> str:
    names, modules = public_names(module)
    # Functions and classes first (in the package's order), then constants and type aliases.
    names = [n for n in names if not is_data(module, n)] + [n for n in names if is_data(module, n)]
    lines = [
        f"# `{module}`",
        "",
        "<!-- Written by docs/_tools/api_pages.py from the package's public names; do not edit. -->",
        "",
        blurb,
        "",
    ]
    if modules:
        pages = {m: p for m, p, _ in PACKAGES}
        links = ", ".join(f"[`{module}.{m}`]({pages[f'{module}.{m}']})" for m in modules)
        lines += [f"Subpackages re-exported here: {links}.", ""]
    for name in LAZY.get(module, []):
        lines += [
            f"`{module}.{name}` is [`fovjax.eval.{name}`](eval.md#fovjax.eval.{name}), imported on use.",
            "",
        ]
    for name, defs in same_names().items():
        if module not in [d[0] for d in defs]:
            continue
        kinds = {d[3] for d in defs}
        what = f"{kinds.pop()}s" if len(kinds) == 1 else "names"
        count = {2: "two", 3: "three"}.get(len(defs), str(len(defs)))
        lines += [f"`{name}` names {count} different {what}:", ""]
        lines += [f"- [`{m}.{name}`]({p}#{m}.{name})" + (f": {s}" if s else "") for m, p, s, _ in defs]
        lines.append("")
    lines += [f"::: {module}", "    options:", "      members:"]
    lines += [f"        - {n}" for n in names]
    return "\n".join(lines) + "\n"


def index() -> str:
    lines = [
        "# API reference",
        "",
        "<!-- Written by docs/_tools/api_pages.py; do not edit. -->",
        "",
        "Every public name of `fovjax` and of each package's `__init__`, from the docstrings. "
        "Modules whose names start with an underscore are private: import from the package.",
        "",
        "| module | what |",
        "|---|---|",
    ]
    lines += [f"| [`{m}`]({p}) | {b} |" for m, p, b in PACKAGES]
    return "\n".join(lines) + "\n"


def expected() -> dict[Path, str]:
    out = {API / "index.md": index()}
    for module, name, blurb in PACKAGES:
        out[API / name] = page(module, blurb)
    return out


def main_check() -> list[Path]:
    """The pages that are missing or differ from what this script writes."""
    return [p for p, text in expected().items() if not p.exists() or p.read_text() != text]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if a page is missing or stale")
    args = parser.parse_args()
    stale = main_check()
    if args.check:
        for p in stale:
            print(f"stale: {p.relative_to(ROOT)} (run python docs/_tools/api_pages.py)")
        return 1 if stale else 0
    API.mkdir(parents=True, exist_ok=True)
    for p, text in expected().items():
        p.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
