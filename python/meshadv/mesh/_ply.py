"""PLY writing with per-face colours, and reading back meshadv's exact float colours.

The file is standard binary PLY that MeshLab, Blender and trimesh open: float ``x y z`` vertices, a
``vertex_indices`` list and 8-bit ``red green blue`` per face. meshadv adds float32 ``reflectance_red``,
``reflectance_green`` and ``reflectance_blue`` face properties (ignored by other tools) so that colours
reload bit-exactly instead of quantised to 1/255.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

#: Names of the exact float colour properties meshadv writes on PLY faces.
EXACT_COLOR_PROPERTIES = ("reflectance_red", "reflectance_green", "reflectance_blue")


def encode_ply(vertices: np.ndarray, faces: np.ndarray, face_colors: np.ndarray, comment: str) -> bytes:
    """Encode a coloured triangle mesh as binary little-endian PLY.

    Args:
        vertices: ``(N, 3)`` positions, written as float32.
        faces: ``(M, 3)`` indices, written as int32.
        face_colors: ``(M, 3)`` RGB, written exactly as float32 and clamped to 8 bits.
        comment: one header comment line (no newline).

    Returns:
        The file content.
    """
    face_dtype = np.dtype([("n", "u1"), ("idx", "<i4", (3,)), ("rgb", "u1", (3,)), ("exact", "<f4", (3,))])
    face_rec = np.zeros(len(faces), dtype=face_dtype)
    face_rec["n"] = 3
    face_rec["idx"] = faces
    colors = np.asarray(face_colors, dtype=np.float32)
    face_rec["rgb"] = np.round(np.clip(np.nan_to_num(colors), 0.0, 1.0) * 255.0).astype(np.uint8)
    face_rec["exact"] = colors
    header = "\n".join(
        [
            "ply",
            "format binary_little_endian 1.0",
            f"comment {comment}",
            f"element vertex {len(vertices)}",
            "property float x",
            "property float y",
            "property float z",
            f"element face {len(faces)}",
            "property list uchar int vertex_indices",
            "property uchar red",
            "property uchar green",
            "property uchar blue",
            *[f"property float {name}" for name in EXACT_COLOR_PROPERTIES],
            "end_header",
            "",
        ]
    )
    verts = np.ascontiguousarray(vertices, dtype="<f4")
    return header.encode("ascii") + verts.tobytes() + face_rec.tobytes()


def exact_face_colors(metadata: dict) -> Optional[np.ndarray]:
    """Return the float colours meshadv stored in a PLY trimesh loaded, or ``None`` when absent.

    Args:
        metadata: the ``metadata`` dict of the loaded ``trimesh.Trimesh`` (holds ``_ply_raw``).
    """
    raw = metadata.get("_ply_raw") if isinstance(metadata, dict) else None
    try:
        data = raw["face"]["data"]
        names = data.dtype.names or ()
    except (KeyError, TypeError, AttributeError):
        return None
    if not all(name in names for name in EXACT_COLOR_PROPERTIES):
        return None
    return np.stack([np.asarray(data[name], dtype=np.float32).reshape(-1) for name in EXACT_COLOR_PROPERTIES], 1)
