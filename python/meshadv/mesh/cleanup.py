"""Order-preserving mesh clean-up: merge duplicate vertices, drop degenerate and duplicate faces and unreferenced
vertices.

Everything here keeps the first-occurrence order of vertices and the file order of faces, so a clean mesh
passes through unchanged (the property that makes save/load round trips exact).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CleanupCounts:
    """What :func:`clean_arrays` changed.

    Attributes:
        merged_vertices: vertices removed because another vertex had exactly the same position.
        degenerate_faces: faces removed because two corners coincide or the area is exactly zero.
        unreferenced_vertices: vertices removed because no face used them.
        duplicate_faces: faces removed because an earlier face has the same three vertices (in any order).
    """

    merged_vertices: int
    degenerate_faces: int
    unreferenced_vertices: int
    duplicate_faces: int = 0


def merge_duplicate_vertices(vertices: np.ndarray, faces: np.ndarray) -> "tuple[np.ndarray, np.ndarray, int]":
    """Merge vertices with bit-equal float32 positions, keeping the first occurrence's place.

    Args:
        vertices: ``(N, 3)`` float32 positions.
        faces: ``(M, 3)`` int64 indices.

    Returns:
        ``(vertices, faces, merged)`` with ``merged`` the number of vertices removed.
    """
    if len(vertices) == 0:
        return vertices, faces, 0
    # +0.0 folds -0.0 into 0.0 so that both spellings of zero merge.
    _, first, inverse = np.unique(vertices + np.float32(0.0), axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    if len(first) == len(vertices):
        return vertices, faces, 0
    order = np.argsort(first, kind="stable")  # unique rows in first-occurrence order
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    new_vertices = vertices[first[order]]
    new_faces = rank[inverse][faces]
    return new_vertices, new_faces, len(vertices) - len(new_vertices)


def degenerate_face_mask(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Boolean ``(M,)`` mask of faces with a repeated corner index or exactly zero area."""
    if len(faces) == 0:
        return np.zeros(0, dtype=bool)
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    tri = vertices.astype(np.float64)[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    zero_area = ~np.any(cross != 0.0, axis=1)
    return repeated | zero_area


def duplicate_face_mask(faces: np.ndarray) -> np.ndarray:
    """Boolean ``(M,)`` mask of faces whose vertex set repeats an earlier face (either winding).

    Duplicate faces are common in CAD exports (a third of PASCAL3D+ aeroplane 03) and make MeshLab's uniform
    resampling run out of memory.
    """
    if len(faces) == 0:
        return np.zeros(0, dtype=bool)
    _, first = np.unique(np.sort(faces, axis=1), axis=0, return_index=True)
    mask = np.ones(len(faces), dtype=bool)
    mask[first] = False
    return mask


def remove_unreferenced_vertices(vertices: np.ndarray, faces: np.ndarray) -> "tuple[np.ndarray, np.ndarray, int]":
    """Drop vertices no face uses, keeping the order of the others.

    Returns:
        ``(vertices, faces, removed)``.
    """
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.reshape(-1)] = True
    removed = int((~used).sum())
    if removed == 0:
        return vertices, faces, 0
    remap = np.cumsum(used) - 1
    return vertices[used], remap[faces], removed


def clean_arrays(
    vertices: np.ndarray, faces: np.ndarray, face_colors: np.ndarray
) -> "tuple[np.ndarray, np.ndarray, np.ndarray, CleanupCounts]":
    """Merge duplicate vertices, drop degenerate then duplicate faces, then drop unreferenced vertices.

    Args:
        vertices: ``(N, 3)`` float32 positions (finite).
        faces: ``(M, 3)`` int64 indices in range.
        face_colors: ``(M, 3)`` float32 colours, filtered with the faces.

    Returns:
        ``(vertices, faces, face_colors, counts)``.
    """
    vertices, faces, merged = merge_duplicate_vertices(vertices, faces)
    bad = degenerate_face_mask(vertices, faces)
    if bad.any():
        faces, face_colors = faces[~bad], face_colors[~bad]
    dup = duplicate_face_mask(faces)
    if dup.any():
        faces, face_colors = faces[~dup], face_colors[~dup]
    vertices, faces, unreferenced = remove_unreferenced_vertices(vertices, faces)
    return vertices, faces, face_colors, CleanupCounts(merged, int(bad.sum()), unreferenced, int(dup.sum()))
