"""Which files a scene is read from: one file, a folder, a glob pattern, or a list of these,
in the order `load_scene`'s `skip` counts them."""

from __future__ import annotations

import glob
import os
import re
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

from ._parts import SUPPORTED_FORMATS

_GLOB_CHARACTERS = re.compile(r"[*?\[]")


def scene_files(path) -> list[Path]:
    """The files `load_scene(path)` reads, in the order its `skip` counts them (from 0).

    Args:
        path: one of
            - a file: that file alone;
            - a folder: the scene files directly in it (suffixes in `SUPPORTED_FORMATS`);
            - a glob pattern (`*`, `?`, `[...]`, and `**` across folders): the scene files it
              matches (other matches, such as `.mtl` files and textures, are left out);
            - a list or tuple of the above: each expanded in turn, in the order given.

            A folder's or a pattern's files are ordered by name with runs of digits compared as
            numbers, so `part_2.obj` comes before `part_10.obj`: for files numbered from 0
            without gaps, as the thesis's Sponza (`sponza_0.obj` ... `sponza_381.obj`), the
            index of a file is its number.

    Returns:
        The paths, in order. A path that names no existing file and no pattern is returned as it
        is: `load_scene` reports it missing.

    Raises:
        FileNotFoundError: a folder with no scene file in it, a pattern that matches none.
        ValueError: a folder's or a pattern's scene files are of more than one format (the same
            model saved twice would be loaded twice; name the files you mean), or an empty list.
        TypeError: `path` is not a path, a pattern or a list of them.
    """
    if isinstance(path, str | os.PathLike):
        return _expand(path)
    if isinstance(path, Sequence) and not isinstance(path, bytes):
        if len(path) == 0:
            raise ValueError("load_scene: an empty list of scene files")
        files: list[Path] = []
        for i, item in enumerate(path):
            if not isinstance(item, str | os.PathLike):
                raise TypeError(
                    f"load_scene: item {i} of the list of scene files is {item!r} "
                    f"({type(item).__name__}); expected a path or a glob pattern"
                )
            files.extend(_expand(item))
        return files
    raise TypeError(
        f"load_scene: expected a scene file, a folder, a glob pattern or a list of these, "
        f"got {path!r} ({type(path).__name__})"
    )


def _expand(item) -> list[Path]:
    p = Path(item)
    if p.is_dir():
        found = [c for c in p.iterdir() if c.is_file() and c.suffix.lower() in SUPPORTED_FORMATS]
        if not found:
            raise FileNotFoundError(f"{p}: the folder holds no scene file ({', '.join(SUPPORTED_FORMATS)})")
        return _one_format(sorted(found, key=_natural_key), f"folder {p}")
    text = os.fspath(item)
    if p.exists() or not _GLOB_CHARACTERS.search(text):
        return [p]
    matches = [Path(m) for m in glob.glob(text, recursive=True)]
    found = [m for m in matches if m.is_file() and m.suffix.lower() in SUPPORTED_FORMATS]
    if not found:
        also = f" ({len(matches)} other match{'es' if len(matches) != 1 else ''})" if matches else ""
        raise FileNotFoundError(
            f"{text}: the pattern matches no scene file ({', '.join(SUPPORTED_FORMATS)}){also}"
        )
    return _one_format(sorted(found, key=_natural_key), f"pattern {text}")


def _one_format(files: list[Path], where: str) -> list[Path]:
    counts = Counter(f.suffix.lower() for f in files)
    if len(counts) > 1:
        listed = ", ".join(f"{n} {suffix}" for suffix, n in sorted(counts.items()))
        raise ValueError(
            f"{where}: scene files of {len(counts)} formats ({listed}); "
            "name the files of one format, e.g. with a pattern such as '*.obj'"
        )
    return files


def _natural_key(p: Path):
    """Path parts with runs of digits as numbers; the split alternates text and digits, so
    keys compare text with text and numbers with numbers."""
    parts = tuple(
        [int(t) if i % 2 else t.lower() for i, t in enumerate(re.split(r"(\d+)", part))] for part in p.parts
    )
    return parts, str(p)
