"""Paths written into files that travel: relative to the folder that holds them, so a copied folder still points
at its neighbours."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Union

PathLike = Union[str, "os.PathLike[str]"]


def relative_path(target: PathLike, base: PathLike) -> str:
    """``target`` relative to the folder ``base``, with forward slashes.

    Both are resolved first (symbolic links followed, ``..`` removed), so ``target`` may lie anywhere, including
    above ``base``. Where no relative path exists (another drive on Windows) the resolved absolute path is returned.

    Args:
        target: the file or folder to point at (need not exist).
        base: the folder the result is relative to (need not exist).

    Returns:
        A POSIX-style path, e.g. ``"../results.db"``.

    Example:
        >>> relative_path("/runs/a/results.db", "/runs/a/report")
        '../results.db'
    """
    resolved = Path(target).resolve()
    try:
        return Path(os.path.relpath(resolved, Path(base).resolve())).as_posix()
    except ValueError:  # no common root (Windows drives)
        return resolved.as_posix()
