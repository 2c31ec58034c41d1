"""Where meshadv finds the shared data folder (real meshes, scenes, photos), and the PASCAL3D+ classes it holds.

The data are never shipped inside the package. They are looked up, in order, at the path in the
``MESHADV_DATA`` environment variable and at ``../shared/data`` beside the repository checkout.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Optional

#: The 7 PASCAL3D+ classes of the MeshAdv paper, in its order (the one definition; the mesh catalogue, the
#: victims' label groups and sweep files import it from here).
PASCAL3D_CLASSES: tuple[str, ...] = ("aeroplane", "bicycle", "boat", "bottle", "chair", "diningtable", "sofa")
#: Environment variable that points at the shared data folder.
DATA_ENV_VAR = "MESHADV_DATA"
#: What the shared data are and where they come from (for error messages).
DATA_WHAT = ("pascal3d/<class>/NN.ply (the PASCAL3D+ CAD models, public), bunny/ (the Stanford Bunny), "
             "scenes/indoor/ (a desk scene built for the paper's detector experiment), scenes/living-room/ "
             "(Bitterli's living room) and photos/ (darknet's sample photos)")

_REPO_ROOT = Path(__file__).resolve().parents[2]


def shared_data_dir() -> Optional[Path]:
    """Return the shared data folder, or ``None`` when it is not available.

    Returns:
        The first existing folder among ``$MESHADV_DATA`` and ``<repo>/../shared/data``.
    """
    candidates = []
    env = os.environ.get(DATA_ENV_VAR)
    if env:
        candidates.append(Path(env))
    candidates.append(_REPO_ROOT.parent / "shared" / "data")
    candidates.append(Path.cwd().parent / "shared" / "data")
    for candidate in candidates:
        if candidate.is_dir():
            return candidate
    return None


def require_shared_data(subpath: str = "") -> Path:
    """Return ``shared_data_dir() / subpath``, raising ``FileNotFoundError`` with a clear reason if absent.

    Args:
        subpath: path inside the data folder, e.g. ``"pascal3d/chair/01.ply"``.

    Raises:
        FileNotFoundError: the data folder or the requested entry does not exist.
    """
    root = shared_data_dir()
    if root is None:
        raise FileNotFoundError(
            f"{subpath or 'this'} is part of meshadv's shared data, which the package does not ship: {DATA_WHAT}. "
            f"Set {DATA_ENV_VAR} to a folder holding it (docs/guide/install.md, 'Shared data'), or use a built-in mesh "
            "(builtin:sofa, builtin:chair, ...) or your own files instead"
        )
    path = root / subpath
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist in the shared data folder {root} ({DATA_WHAT})")
    return path
