"""Mesh paths of a rendering set: the PASCAL3D+ files to build from, how a set stores them and how a record finds its
mesh again."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Optional

from meshadv.datasets.rendering_set.set_file import PathLike
from meshadv.victims.labels import PASCAL3D_CLASSES

__all__ = ["pascal3d_mesh_paths", "rendering_mesh_path", "stored_mesh_path"]


def pascal3d_mesh_paths(
    root: Optional[PathLike] = None, classes: Optional[Sequence[str]] = None
) -> dict[str, list[Path]]:
    """Mesh files per class of a PASCAL3D+ folder, ready for :func:`.build.build_rendering_set`.

    Args:
        root: a PASCAL3D+ folder (``<root>/<class>/NN.ply`` or a release with ``CAD/``); default the shared data's.
        classes: the classes to list; default all of :data:`~meshadv.victims.labels.PASCAL3D_CLASSES` present.

    Raises:
        FileNotFoundError: no such folder (or no shared data).
        ValueError: an unknown class.
    """
    from meshadv.mesh import Pascal3DCatalog

    catalog = Pascal3DCatalog.shared() if root is None else Pascal3DCatalog(root)
    wanted = list(classes) if classes is not None else [c for c in PASCAL3D_CLASSES if c in catalog.classes()]
    for cls in wanted:
        if cls not in PASCAL3D_CLASSES:
            raise ValueError(f"classes: unknown class {cls!r}; classes: {', '.join(PASCAL3D_CLASSES)}")
    return {cls: list(catalog.models(cls)) for cls in wanted}


def stored_mesh_path(path: str, root: Optional[Path]) -> str:
    """How a set stores mesh file ``path``: as given, or relative to the resolved folder ``root`` when there is one.

    Raises:
        ValueError: ``path`` is not inside ``root`` (named as ``mesh_paths_by_class`` and ``mesh_root``).
    """
    if root is None:
        return path
    resolved = Path(path).resolve()
    try:
        return resolved.relative_to(root).as_posix()
    except ValueError:
        raise ValueError(f"mesh_paths_by_class: mesh {path} is not inside mesh_root {root}") from None


def rendering_mesh_path(record: Mapping[str, Any], mesh_root: Optional[PathLike] = None) -> Path:
    """The mesh file of a rendering-set record (absolute paths as stored; relative ones under ``mesh_root``).

    Args:
        record: an entry of ``doc["renderings"]``.
        mesh_root: folder the stored relative paths refer to; default the shared data folder
            (:func:`meshadv.data.shared_data_dir`).

    Raises:
        FileNotFoundError: the mesh file does not exist, or a relative path and no ``mesh_root`` / shared data.
    """
    stored = Path(record["mesh"])
    if not stored.is_absolute():
        if mesh_root is None:
            from meshadv.data import require_shared_data

            mesh_root = require_shared_data()
        stored = Path(mesh_root) / stored
    if not stored.is_file():
        raise FileNotFoundError(f"record: mesh file {stored} does not exist (pass mesh_root=the folder it is under)")
    return stored
