"""OBJ + MTL writing with one material per distinct face colour, and reading face colours back in file order.

trimesh's OBJ reader groups faces by material (which reorders faces) and keeps material colours in 8 bits, so
meshadv reads OBJ geometry through trimesh with the material statements removed and recovers each face's
``Kd`` colour itself from the ``usemtl`` statements in file order, at full precision.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from meshadv.mesh.errors import MeshLoadError


def encode_obj(
    vertices: np.ndarray, faces: np.ndarray, face_colors: np.ndarray, mtl_name: str, comment: str
) -> "tuple[str, str]":
    """Encode a coloured triangle mesh as OBJ text and its MTL library.

    Faces keep their order; a ``usemtl`` statement is written whenever the colour changes. Values are written
    with 9 significant digits, which reproduces float32 exactly.

    Args:
        vertices: ``(N, 3)`` positions.
        faces: ``(M, 3)`` zero-based indices.
        face_colors: ``(M, 3)`` RGB (the ``Kd`` of the materials, clamped to ``[0, 1]``).
        mtl_name: file name of the material library, referenced by ``mtllib``.
        comment: a comment for the first line.

    Returns:
        ``(obj_text, mtl_text)``.
    """
    colors = np.clip(np.asarray(face_colors, dtype=np.float32), 0.0, 1.0)
    unique, first, inverse = np.unique(colors, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    material = rank[inverse.reshape(-1)]
    mtl_lines = [f"# {comment}"]
    for k, idx in enumerate(order):
        r, g, b = (float(x) for x in unique[idx])
        mtl_lines += [f"newmtl color_{k}", f"Kd {r:.9g} {g:.9g} {b:.9g}", "Ka 0 0 0", "Ks 0 0 0", "d 1", "illum 1", ""]
    lines = [f"# {comment}", f"mtllib {mtl_name}"]
    verts = np.asarray(vertices, dtype=np.float32)
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in verts.tolist()]
    current = -1
    for (a, b, c), mat in zip((np.asarray(faces, dtype=np.int64) + 1).tolist(), material.tolist()):
        if mat != current:
            lines.append(f"usemtl color_{mat}")
            current = mat
        lines.append(f"f {a} {b} {c}")
    return "\n".join(lines) + "\n", "\n".join(mtl_lines)


def strip_materials(text: str) -> str:
    """Return OBJ text without ``mtllib``/``usemtl`` statements, so trimesh reads one geometry in file order."""
    keep = [line for line in text.splitlines() if not line.lstrip().startswith(("usemtl", "mtllib"))]
    return "\n".join(keep) + "\n"


def _parse_mtl(path: Path, warnings: "list[str]") -> "dict[str, np.ndarray]":
    """Read the ``Kd`` colour of each material of an MTL file.

    Colours must be 3 finite numbers; values outside ``[0, 1]`` are clamped with a warning appended to
    ``warnings``.

    Raises:
        MeshLoadError: a ``Kd`` line without 3 numbers, or with NaN/infinite values (naming file and line).
    """
    colors: dict = {}
    name = None
    clamped = []
    for lineno, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
        tokens = line.split("#", 1)[0].split()
        if not tokens:
            continue
        if tokens[0] == "newmtl" and len(tokens) > 1:
            name = " ".join(tokens[1:])
        elif tokens[0] == "Kd" and name is not None:
            if tokens[1:2] == ["spectral"] or tokens[1:2] == ["xyz"]:
                warnings.append(f"{path.name}:{lineno}: Kd {tokens[1]} colours are not supported; ignored")
                continue
            try:
                values = [float(t) for t in tokens[1:]]
            except ValueError:
                values = []
            if len(values) != 3:
                raise MeshLoadError(f"{path}:{lineno}: Kd needs 3 numbers (r g b), got {line.strip()!r}")
            rgb = np.array(values, dtype=np.float64)
            if not np.isfinite(rgb).all():
                raise MeshLoadError(f"{path}:{lineno}: Kd colour must be finite, got {line.strip()!r}")
            if (rgb < 0).any() or (rgb > 1).any():
                clamped.append(name)
            colors[name] = np.clip(rgb, 0.0, 1.0).astype(np.float32)
    if clamped:
        warnings.append(f"{path.name}: Kd colours outside [0, 1] clamped for materials {', '.join(clamped[:5])}")
    return colors


def face_colors_in_file_order(
    text: str, folder: Path, default_color: np.ndarray
) -> "tuple[Optional[np.ndarray], int, list[str]]":
    """Recover one ``Kd`` colour per triangle from the ``usemtl`` statements of an OBJ file.

    Polygons count as ``n - 2`` triangles (trimesh fan-triangulates them).

    Args:
        text: the OBJ file content.
        folder: folder of the OBJ file, where ``mtllib`` paths are resolved.
        default_color: ``(3,)`` colour of faces without a known material.

    Returns:
        ``(colors, triangles, warnings)``: ``colors`` is ``(T, 3)`` float32, or ``None`` when the file uses
        no material; ``triangles`` the number of triangles the face statements describe.

    Raises:
        MeshLoadError: a malformed or non-finite ``Kd`` colour in a material library.
    """
    library: dict = {}
    warnings: "list[str]" = []
    per_face: "list[Optional[str]]" = []
    current: Optional[str] = None
    used_material = False
    for line in text.splitlines():
        tokens = line.split()
        if not tokens:
            continue
        head = tokens[0]
        if head == "mtllib":
            for name in tokens[1:]:
                mtl_path = folder / name
                if mtl_path.is_file():
                    library.update(_parse_mtl(mtl_path, warnings))
                else:
                    warnings.append(f"material library {name} not found beside the OBJ file")
        elif head == "usemtl":
            current = " ".join(tokens[1:])
            used_material = True
        elif head == "f" and len(tokens) >= 4:
            per_face.extend([current] * (len(tokens) - 3))
    if not used_material:
        return None, len(per_face), warnings
    missing = sorted({name for name in per_face if name is not None and name not in library})
    if missing:
        warnings.append(f"materials without a Kd colour (painted the default colour): {', '.join(missing[:5])}")
    colors = np.empty((len(per_face), 3), dtype=np.float32)
    cache: dict = {}
    for i, name in enumerate(per_face):
        if name not in cache:
            cache[name] = library.get(name, default_color) if name is not None else default_color
        colors[i] = cache[name]
    return colors, len(per_face), warnings
