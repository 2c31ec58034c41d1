"""Built-in generated shapes, so the package works without the shared data folder.

Every shape is generated (nothing is shipped), Y-up like the renderer's world, centred at the origin with its
largest half-extent equal to 1 (the normalisation of :func:`meshadv.mesh.normalize_mesh`). The ``bottle``,
``chair``, ``diningtable`` and ``sofa`` are crude stand-ins for those PASCAL3D+ classes, built from boxes and a
solid of revolution.
"""

from __future__ import annotations

from typing import Callable, Union

import numpy as np
import trimesh

from meshadv.data import shared_data_dir
from meshadv.mesh.catalog import Pascal3DCatalog
from meshadv.mesh.cleanup import clean_arrays
from meshadv.mesh.io import load_mesh
from meshadv.mesh.normalize import Z_UP_TO_Y_UP, normalize_mesh
from meshadv.mesh.structure import Mesh

#: Shared PASCAL3D+ model :func:`default_mesh` uses when the shared data folder is present.
DEFAULT_SHARED_MODEL = ("chair", "01")
_GREY = (0.7, 0.7, 0.7)


def _boxes(boxes: "list[tuple[tuple[float, float, float], tuple[float, float, float]]]") -> trimesh.Trimesh:
    """Concatenate axis-aligned boxes given as ``(centre, size)`` (Y-up)."""
    parts = []
    for centre, size in boxes:
        transform = np.eye(4)
        transform[:3, 3] = centre
        parts.append(trimesh.creation.box(extents=size, transform=transform))
    return trimesh.util.concatenate(parts)


def _sphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=3, radius=1.0)


def _cube() -> trimesh.Trimesh:
    return trimesh.creation.box(extents=(2.0, 2.0, 2.0))


def _torus() -> trimesh.Trimesh:
    torus = trimesh.creation.torus(major_radius=0.7, minor_radius=0.3, major_sections=48, minor_sections=24)
    torus.vertices = torus.vertices @ Z_UP_TO_Y_UP.T  # ring in the XZ plane, hole along Y
    return torus


def _bottle() -> trimesh.Trimesh:
    # (radius, height) profile from the bottom centre to the top centre, revolved about the Z axis.
    profile = np.array(
        [
            [0.0, 0.0],
            [0.35, 0.0],
            [0.4, 0.05],
            [0.4, 1.1],
            [0.3, 1.35],
            [0.14, 1.55],
            [0.14, 1.9],
            [0.17, 1.92],
            [0.17, 2.0],
            [0.0, 2.0],
        ]
    )
    bottle = trimesh.creation.revolve(profile, sections=48)
    bottle.vertices = bottle.vertices @ Z_UP_TO_Y_UP.T
    return bottle


def _chair() -> trimesh.Trimesh:
    leg = (0.08, 0.9, 0.08)
    return _boxes(
        [
            ((0.0, 0.95, 0.0), (1.0, 0.1, 1.0)),  # seat
            ((0.0, 1.55, -0.45), (1.0, 1.1, 0.08)),  # back rest
            ((0.44, 0.45, 0.44), leg),
            ((-0.44, 0.45, 0.44), leg),
            ((0.44, 0.45, -0.44), leg),
            ((-0.44, 0.45, -0.44), leg),
        ]
    )


def _diningtable() -> trimesh.Trimesh:
    leg = (0.1, 1.4, 0.1)
    return _boxes(
        [
            ((0.0, 1.45, 0.0), (3.0, 0.1, 1.6)),
            ((1.35, 0.7, 0.65), leg),
            ((-1.35, 0.7, 0.65), leg),
            ((1.35, 0.7, -0.65), leg),
            ((-1.35, 0.7, -0.65), leg),
        ]
    )


def _sofa() -> trimesh.Trimesh:
    return _boxes(
        [
            ((0.0, 0.3, 0.0), (2.4, 0.6, 1.0)),  # base and seat
            ((0.0, 0.85, -0.4), (2.4, 0.9, 0.2)),  # back
            ((1.1, 0.5, 0.0), (0.2, 0.6, 1.0)),
            ((-1.1, 0.5, 0.0), (0.2, 0.6, 1.0)),
        ]  # arms
    )


_BUILDERS: "dict[str, Callable[[], trimesh.Trimesh]]" = {
    "sphere": _sphere,
    "cube": _cube,
    "torus": _torus,
    "bottle": _bottle,
    "chair": _chair,
    "diningtable": _diningtable,
    "sofa": _sofa,
}

#: Names accepted by :func:`builtin_mesh`.
BUILTIN_SHAPES = tuple(_BUILDERS)


def builtin_mesh(name: str = "sphere", *, color: "tuple[float, float, float]" = _GREY) -> Mesh:
    """Generate a built-in shape (Y-up, centred, largest half-extent 1).

    Args:
        name: one of :data:`BUILTIN_SHAPES` (``sphere`` is a level-3 icosphere with 1280 faces).
        color: RGB reflectance of every face.

    Returns:
        A CPU :class:`Mesh`.

    Raises:
        ValueError: unknown ``name``.

    Example:
        >>> builtin_mesh("sphere").num_faces
        1280
    """
    if name not in _BUILDERS:
        raise ValueError(f"name must be one of {', '.join(BUILTIN_SHAPES)}, got {name!r}")
    tm = _BUILDERS[name]()
    verts = np.asarray(tm.vertices, dtype=np.float32)
    faces = np.asarray(tm.faces, dtype=np.int64)
    colors = np.broadcast_to(np.asarray(color, dtype=np.float32), (len(faces), 3)).copy()
    verts, faces, colors, _ = clean_arrays(verts, faces, colors)
    mesh, _ = normalize_mesh(Mesh.from_numpy(verts, faces, colors))
    return mesh


def default_mesh() -> Mesh:
    """A ready-to-render mesh: the shared PASCAL3D+ chair 01 when the shared data folder exists, else a built-in.

    The shared model is loaded raw (not resampled), rotated from Z-up to Y-up and normalised into ``[-1, 1]``;
    without shared data the built-in ``chair`` is returned, so commands and quick tests run on a fresh machine.

    Returns:
        A CPU :class:`Mesh`, Y-up, centred, largest half-extent 1.
    """
    root = shared_data_dir()
    if root is not None:
        cls, model = DEFAULT_SHARED_MODEL
        path = root / "pascal3d" / cls / f"{model}.ply"
        if path.is_file():
            mesh, _ = normalize_mesh(load_mesh(path), z_up=True)
            return mesh
    return builtin_mesh("chair")


def class_mesh(cls: str, model: "Union[int, str]" = 1) -> Mesh:
    """A ready-to-render mesh of a PASCAL3D+ class: the shared model when present, else a built-in stand-in.

    Args:
        cls: a class name, e.g. ``"chair"``.
        model: model number (``1`` or ``"01"``) in the shared catalogue; ignored for built-in stand-ins.

    Returns:
        A CPU :class:`Mesh`, Y-up, centred, largest half-extent 1.

    Raises:
        ValueError: the shared catalogue has no such class or model.
        FileNotFoundError: no shared data and no built-in stand-in for ``cls`` (aeroplane, bicycle, boat).
    """
    root = shared_data_dir()
    if root is not None and (root / "pascal3d").is_dir():
        return Pascal3DCatalog(root / "pascal3d").load(cls, model)
    if cls in _BUILDERS and cls not in ("sphere", "cube", "torus"):
        return builtin_mesh(cls)
    raise FileNotFoundError(
        f"cls {cls!r}: the shared PASCAL3D+ meshes are not available and there is no built-in stand-in "
        "(built-in classes: bottle, chair, diningtable, sofa)"
    )
