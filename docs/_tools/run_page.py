"""Run the Python code blocks of documentation pages, as tests/test_docs.py does, and keep the
images they make for the pages to show.

Every ```python block of a page runs, in order, in one namespace, in a fresh directory holding
a link to the repository's `data/` (so the pages' relative paths work and their outputs land in
the scratch directory). Blocks in other languages (bash, text) are not run.

A page shows an image its code writes by naming it under `docs/images/pages/<page>/`, followed by
the path the code wrote it to: `![...](../images/pages/sessions/out/session/frame_00000.png)` is
the file `out/session/frame_00000.png` that docs/tutorials/sessions.md writes. The images are
committed; `--images` runs the pages and copies each image a page names from its run into
`docs/images/pages/<page>/` (and removes the ones it no longer names). tests/test_docs.py checks
that every run writes the images its page names and that every image a page names exists.

    python docs/_tools/run_page.py docs/tutorials/acuity-fit.md [...]
    python docs/_tools/run_page.py --images docs/index.md docs/tutorials/*.md
"""

import argparse
import os
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
PAGE_IMAGES = DOCS / "images" / "pages"
FENCE = re.compile(r"^```python\n(.*?)^```$", re.S | re.M)
IMAGE = re.compile(r"!\[[^\]]*\]\(([^)\s]+)")


def code_blocks(page: Path) -> list[str]:
    return FENCE.findall(page.read_text())


def images(page: Path) -> list[Path]:
    """Every local image the page shows, as a path (resolved against the page's folder)."""
    page = Path(page).resolve()
    targets = [t for t in IMAGE.findall(page.read_text()) if not re.match(r"[a-z]+:", t)]
    return [(page.parent / t).resolve() for t in targets]


def outputs(page: Path) -> dict[Path, Path]:
    """The images the page shows from its own run: {path its code writes (relative to the run's
    directory): the committed copy under docs/images/pages/<page>/}."""
    folder = PAGE_IMAGES / Path(page).stem
    return {image.relative_to(folder): image for image in images(page) if image.is_relative_to(folder)}


def missing_outputs(page: Path, workdir: Path) -> list[str]:
    """The images the page shows from its run that the run in `workdir` did not write."""
    return [str(made) for made in outputs(page) if not (Path(workdir) / made).is_file()]


def run_page(page: Path, workdir: Path) -> float:
    """Run the page's blocks in `workdir`; return the seconds it took."""
    page = Path(page).resolve()
    (workdir / "data").symlink_to(ROOT / "data")
    namespace = {"__name__": f"docs_page_{page.stem}"}
    cwd = os.getcwd()
    start = time.perf_counter()
    os.chdir(workdir)
    try:
        for i, block in enumerate(code_blocks(page)):
            exec(compile(block, f"{page.relative_to(ROOT)}[block {i + 1}]", "exec"), namespace)
    finally:
        os.chdir(cwd)
    return time.perf_counter() - start


def keep_images(page: Path, workdir: Path) -> list[Path]:
    """Copy the images the page shows from its run in `workdir` to docs/images/pages/<page>/, and
    remove the files there it no longer shows. Returns the copies."""
    missing = missing_outputs(page, workdir)
    if missing:
        raise FileNotFoundError(f"{page}: the page shows images its code did not write: {', '.join(missing)}")
    shown = outputs(page)
    for made, copy in shown.items():
        copy.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(Path(workdir) / made, copy)
    folder = PAGE_IMAGES / Path(page).stem
    for old in folder.rglob("*") if folder.exists() else ():
        if old.is_file() and old not in shown.values():
            old.unlink()
    return list(shown.values())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pages", nargs="+", type=Path, help="Markdown pages to run")
    parser.add_argument(
        "--images",
        action="store_true",
        help="copy the images each page shows from its run into docs/images/pages/",
    )
    args = parser.parse_args()
    for page in args.pages:
        if not page.is_file():
            print(f"run_page.py: error: {page}: no such page", file=sys.stderr)
            return 2
    for page in args.pages:
        with tempfile.TemporaryDirectory() as tmp:
            seconds = run_page(page, Path(tmp))
            print(f"{page}: {seconds:.1f} s", flush=True)
            if args.images:
                for copy in keep_images(page, Path(tmp)):
                    print(f"  {copy.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
