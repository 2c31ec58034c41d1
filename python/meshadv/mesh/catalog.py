"""A catalogue of PASCAL3D+ CAD models on disk.

Accepted layouts: ``<root>/<class>/NN.ply`` or ``NN.off`` (the shared data's ``pascal3d/`` folder), and the
release's ``<root>/CAD/<class>/NN.off``. When a model exists both as PLY and OFF, the PLY is listed.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Optional, Union

from meshadv.data import PASCAL3D_CLASSES, shared_data_dir
from meshadv.mesh.io import load_mesh
from meshadv.mesh.normalize import normalize_mesh
from meshadv.mesh.structure import Mesh

#: Mesh file extensions the catalogue lists, in order of preference.
MODEL_EXTENSIONS = (".ply", ".off")


class Pascal3DCatalog:
    """List the classes and models of a PASCAL3D+ folder.

    Args:
        root: the folder holding class folders, or a release root with a ``CAD`` sub-folder.

    Raises:
        FileNotFoundError: ``root`` is not a folder.

    Example:
        >>> cat = Pascal3DCatalog.shared()  # doctest: +SKIP
        >>> cat.models("chair")[0].name  # doctest: +SKIP
        '01.ply'
    """

    def __init__(self, root: "Union[str, os.PathLike[str]]") -> None:
        root = Path(root)
        if not root.is_dir():
            raise FileNotFoundError(f"root is not a folder: {root}")
        self.root = root / "CAD" if (root / "CAD").is_dir() else root

    @classmethod
    def shared(cls) -> "Pascal3DCatalog":
        """The catalogue of the shared data folder's ``pascal3d/``.

        Raises:
            FileNotFoundError: the shared data folder or its ``pascal3d`` folder is missing.
        """
        root = shared_data_dir()
        if root is None or not (root / "pascal3d").is_dir():
            raise FileNotFoundError("shared PASCAL3D+ meshes not found (set MESHADV_DATA or provide ../shared/data)")
        return cls(root / "pascal3d")

    @classmethod
    def shared_or_none(cls) -> Optional["Pascal3DCatalog"]:
        """Like :meth:`shared` but ``None`` when the data are absent."""
        try:
            return cls.shared()
        except FileNotFoundError:
            return None

    def _model_files(self, folder: Path) -> "list[Path]":
        by_stem: "dict[str, Path]" = {}
        for ext in reversed(MODEL_EXTENSIONS):  # later (preferred) extensions overwrite
            for path in folder.glob(f"*{ext}"):
                if path.is_file() and not path.name.startswith("."):
                    by_stem[path.stem] = path
        return [by_stem[stem] for stem in sorted(by_stem, key=lambda s: (len(s), s))]

    def classes(self) -> "list[str]":
        """Class folders holding at least one model, the paper's 7 first (in their order), then others sorted."""
        present = sorted(p.name for p in self.root.iterdir() if p.is_dir() and self._model_files(p))
        ordered = [c for c in PASCAL3D_CLASSES if c in present]
        return ordered + [c for c in present if c not in PASCAL3D_CLASSES]

    def models(self, cls: str) -> "list[Path]":
        """Model files of class ``cls``, ordered by model number.

        Raises:
            ValueError: ``cls`` is not a class of this catalogue.
        """
        folder = self.root / cls
        files = self._model_files(folder) if folder.is_dir() else []
        if not files:
            raise ValueError(f"cls {cls!r} is not in the catalogue at {self.root}; available: {self.classes()}")
        return files

    def model(self, cls: str, index: "Union[int, str]") -> Path:
        """The file of model ``index`` (``1`` or ``"01"``) of class ``cls``.

        Raises:
            ValueError: unknown class or model.
        """
        stem = f"{index:02d}" if isinstance(index, int) else str(index)
        for path in self.models(cls):
            if path.stem == stem:
                return path
        raise ValueError(f"index {index!r}: no model {stem} in class {cls!r} at {self.root}")

    def load(self, cls: str, index: "Union[int, str]", *, normalize: bool = True) -> Mesh:
        """Load a model; with ``normalize`` it is rotated Z-up to Y-up and scaled into ``[-1, 1]``.

        Raises:
            ValueError: unknown class or model; MeshLoadError when the file is unusable.
        """
        mesh = load_mesh(self.model(cls, index))
        return normalize_mesh(mesh, z_up=True)[0] if normalize else mesh

    def __repr__(self) -> str:
        return f"Pascal3DCatalog({str(self.root)!r})"
