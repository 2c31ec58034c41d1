"""glTF vertex colours (``COLOR_0``) and base-colour factor: the checks trimesh does not make, and the values.

trimesh reads ``COLOR_0`` as the accessor's raw numbers (0-255 for ``UNSIGNED_BYTE``, 0-65535 for
``UNSIGNED_SHORT``, as stored for ``FLOAT``) and drops a ``COLOR_0`` whose count differs from the positions' without a
word; :func:`check_color_accessors` reads the file's JSON (:func:`gltf_json`) so that such a file is an error naming
the file and field. trimesh rounds a material's ``baseColorFactor`` to 8 bits; :func:`base_color_factor` reads it
exactly.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Any

import numpy as np

from meshadv.mesh.errors import MeshLoadError

__all__ = ["base_color_factor", "check_color_accessors", "color_values", "gltf_json"]

#: The ``componentType`` codes glTF 2.0 allows for ``COLOR_0``, and the value each one's 1.0 is stored as.
_COLOR_SCALES = {5126: 1.0, 5121: 255.0, 5123: 65535.0}
_GLB_MAGIC = b"glTF"
_JSON_CHUNK = 0x4E4F534A


def gltf_json(path: Path) -> dict[str, Any]:
    """The JSON of a ``.gltf`` file or of a ``.glb``'s first chunk.

    Raises:
        MeshLoadError: not glTF JSON (the message names the file).
    """
    data = path.read_bytes()
    try:
        if data[:4] == _GLB_MAGIC:
            length, kind = struct.unpack_from("<II", data, 12)
            if kind != _JSON_CHUNK:
                raise MeshLoadError(f"{path}: the first GLB chunk is not JSON")
            return json.loads(data[20:20 + length])
        return json.loads(data)
    except (struct.error, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MeshLoadError(f"{path}: cannot be read as glTF ({exc})") from exc


def check_color_accessors(tree: dict[str, Any], path: Path) -> bool:
    """Check every mesh primitive's ``COLOR_0`` of a glTF/GLB file against glTF 2.0: one colour per ``POSITION``,
    ``VEC3`` or ``VEC4``, of ``FLOAT``, ``UNSIGNED_BYTE`` or ``UNSIGNED_SHORT`` components.

    Args:
        tree: the file's JSON (:func:`gltf_json`). path: the file, for the messages.

    Returns:
        Whether any primitive has a ``COLOR_0``.

    Raises:
        MeshLoadError: a ``COLOR_0`` that breaks one of these rules; the message names the file, the mesh and
            primitive, and ``COLOR_0``.
    """
    accessors = tree.get("accessors") or []
    found = False
    for m, mesh in enumerate(tree.get("meshes") or []):
        for p, primitive in enumerate(mesh.get("primitives") or []):
            attributes = primitive.get("attributes") or {}
            if "COLOR_0" not in attributes:
                continue
            found = True
            where = f"{path}: mesh {m} primitive {p}: COLOR_0"
            index, position = attributes["COLOR_0"], attributes.get("POSITION")
            if not isinstance(index, int) or not 0 <= index < len(accessors):
                raise MeshLoadError(f"{where}: accessor {index!r} does not exist ({len(accessors)} accessors)")
            color = accessors[index]
            if color.get("type") not in ("VEC3", "VEC4"):
                raise MeshLoadError(f"{where}: type must be VEC3 or VEC4, got {color.get('type')!r}")
            if color.get("componentType") not in _COLOR_SCALES:
                raise MeshLoadError(f"{where}: componentType must be 5126 (FLOAT), 5121 (UNSIGNED_BYTE) or 5123 "
                                    f"(UNSIGNED_SHORT), got {color.get('componentType')!r}")
            if isinstance(position, int) and 0 <= position < len(accessors):
                n_color, n_position = color.get("count"), accessors[position].get("count")
                if n_color != n_position:
                    raise MeshLoadError(f"{where}: {n_color} colours for {n_position} vertices (POSITION)")
    return found


def color_values(raw: np.ndarray, path: Path) -> np.ndarray:
    """(N,3) float64 RGB in ``[0, 1]`` of the ``COLOR_0`` numbers trimesh read (alpha dropped).

    Raises:
        MeshLoadError: not (N,3) or (N,4), NaN or infinite values, or float colours outside ``[0, 1]``; the message
            names the file and ``COLOR_0``.
    """
    values = np.asarray(raw)
    if values.ndim != 2 or values.shape[1] not in (3, 4):
        raise MeshLoadError(f"{path}: COLOR_0: colours must have 3 or 4 components, got shape {values.shape}")
    scale = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(values.dtype, 1.0)
    rgb = values[:, :3].astype(np.float64) / scale
    if not np.isfinite(rgb).all():
        raise MeshLoadError(f"{path}: COLOR_0: NaN or infinite colours")
    if rgb.min() < 0.0 or rgb.max() > 1.0:
        raise MeshLoadError(f"{path}: COLOR_0: colours must lie in [0, 1], got [{rgb.min():g}, {rgb.max():g}]")
    return rgb


def base_color_factor(tree: dict[str, Any], path: Path) -> np.ndarray:
    """(3,) float64 RGB ``baseColorFactor`` of the materials the file's primitives use (1 where a material or a
    primitive gives none), which glTF multiplies with the base-colour texture and ``COLOR_0``.

    Raises:
        MeshLoadError: primitives whose factors differ (one mesh of meshadv has one reflectance rule), or a factor
            that is not 3 or 4 numbers in ``[0, 1]``; the message names the file and ``baseColorFactor``.
    """
    materials = tree.get("materials") or []
    factors = set()
    for mesh in tree.get("meshes") or []:
        for primitive in mesh.get("primitives") or []:
            index = primitive.get("material")
            material = materials[index] if isinstance(index, int) and 0 <= index < len(materials) else {}
            raw = (material.get("pbrMetallicRoughness") or {}).get("baseColorFactor", [1.0, 1.0, 1.0, 1.0])
            try:
                rgb = tuple(float(x) for x in raw[:3])
            except (TypeError, ValueError) as exc:
                raise MeshLoadError(f"{path}: baseColorFactor: not numbers: {raw!r}") from exc
            if len(raw) not in (3, 4) or not all(0.0 <= x <= 1.0 for x in rgb):
                raise MeshLoadError(f"{path}: baseColorFactor: needs 3 or 4 numbers in [0, 1], got {raw!r}")
            factors.add(rgb)
    if len(factors) > 1:
        raise MeshLoadError(f"{path}: baseColorFactor: the primitives' materials have different factors "
                            f"{sorted(factors)}; meshadv draws one mesh with one (merge the materials)")
    return np.asarray(factors.pop() if factors else (1.0, 1.0, 1.0), dtype=np.float64)
