"""Mesh connectivity as tensors: unique edges, vertex neighbourhoods (CSR), face adjacency, uniform Laplacian.

All functions accept int64 ``(M, 3)`` face tensors (numpy arrays are converted) and return tensors on the faces'
device. Non-manifold inputs (an edge shared by more than two faces) are handled: such an edge appears once in
:func:`vertex_edges` and links every pair of its faces in :func:`face_adjacency`.
"""

from __future__ import annotations

from typing import Optional, Union

import numpy as np
import torch

FacesLike = Union[torch.Tensor, np.ndarray]


def _as_faces(faces: FacesLike) -> torch.Tensor:
    f = torch.as_tensor(faces)
    if f.dim() != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must have shape (M, 3), got {tuple(f.shape)}")
    if f.dtype.is_floating_point or f.dtype == torch.bool:
        raise ValueError(f"faces must hold integers, got {f.dtype}")
    return f.long()


def vertex_edges(faces: FacesLike) -> torch.Tensor:
    """Unique undirected edges of a triangle mesh.

    Args:
        faces: int ``(M, 3)`` vertex indices.

    Returns:
        int64 ``(E, 2)`` tensor with ``edges[:, 0] < edges[:, 1]``, sorted lexicographically.

    Example:
        >>> vertex_edges(torch.tensor([[0, 1, 2], [0, 2, 3]])).tolist()
        [[0, 1], [0, 2], [0, 3], [1, 2], [2, 3]]
    """
    f = _as_faces(faces)
    pairs = torch.cat([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]], dim=0)
    pairs = torch.sort(pairs, dim=1).values
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    if pairs.numel() == 0:
        return pairs.reshape(0, 2)
    # One int64 key per pair orders the pairs as (first, second) does: a 1-D unique, much cheaper than one over rows.
    low = int(pairs.min())
    n = int(pairs.max()) - low + 1
    keys = torch.unique((pairs[:, 0] - low) * n + (pairs[:, 1] - low))
    return torch.stack([keys // n + low, keys % n + low], dim=1)


def vertex_neighbors(faces: FacesLike, num_vertices: Optional[int] = None) -> "tuple[torch.Tensor, torch.Tensor]":
    """Neighbours of every vertex in compressed sparse row form.

    Args:
        faces: int ``(M, 3)`` vertex indices.
        num_vertices: ``N``; defaults to ``faces.max() + 1``.

    Returns:
        ``(offsets, indices)``: int64 ``(N + 1,)`` and ``(2E,)``; the neighbours of vertex ``i`` are
        ``indices[offsets[i]:offsets[i + 1]]`` in increasing order.

    Raises:
        ValueError: ``num_vertices`` is smaller than an index in ``faces``.
    """
    f = _as_faces(faces)
    n = int(f.max()) + 1 if f.numel() else 0
    if num_vertices is not None:
        if num_vertices < n:
            raise ValueError(f"num_vertices={num_vertices} but faces index vertex {n - 1}")
        n = num_vertices
    edges = vertex_edges(f)
    directed = torch.cat([edges, edges.flip(1)], dim=0)
    key = directed[:, 0] * max(n, 1) + directed[:, 1]
    directed = directed[torch.argsort(key)]
    counts = torch.bincount(directed[:, 0], minlength=n)
    offsets = torch.zeros(n + 1, dtype=torch.int64, device=f.device)
    offsets[1:] = torch.cumsum(counts, dim=0)
    return offsets, directed[:, 1].contiguous()


def vertex_degrees(faces: FacesLike, num_vertices: int) -> torch.Tensor:
    """Number of distinct neighbours of each vertex, int64 ``(N,)``."""
    edges = vertex_edges(faces)
    return torch.bincount(edges.reshape(-1), minlength=num_vertices)


def face_adjacency(faces: FacesLike) -> torch.Tensor:
    """Pairs of faces sharing an edge.

    Args:
        faces: int ``(M, 3)`` vertex indices.

    Returns:
        int64 ``(K, 2)`` tensor of face index pairs ``(a, b)`` with ``a < b``, unique, sorted. An edge with
        ``k`` faces contributes all ``k (k - 1) / 2`` pairs.
    """
    f = _as_faces(faces)
    m = f.shape[0]
    pairs = torch.cat([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]], dim=0)
    pairs = torch.sort(pairs, dim=1).values
    face_ids = torch.arange(m, device=f.device).repeat(3)
    keep = pairs[:, 0] != pairs[:, 1]
    pairs, face_ids = pairs[keep], face_ids[keep]
    if pairs.numel() == 0:
        return torch.zeros((0, 2), dtype=torch.int64, device=f.device)
    _, edge_id = torch.unique(pairs, dim=0, return_inverse=True)
    order = torch.argsort(edge_id * max(m, 1) + face_ids)
    edge_id, face_ids = edge_id[order], face_ids[order]
    # Group faces by edge; pair each face with every later face of the same edge.
    counts = torch.bincount(edge_id)
    starts = torch.cumsum(counts, 0) - counts
    max_k = int(counts.max())
    result = []
    pos = torch.arange(edge_id.shape[0], device=f.device) - starts[edge_id]
    for shift in range(1, max_k):
        later = torch.arange(edge_id.shape[0], device=f.device) + shift
        valid = pos + shift < counts[edge_id]
        src = torch.nonzero(valid).reshape(-1)
        result.append(torch.stack([face_ids[src], face_ids[later[src]]], dim=1))
    if not result:
        return torch.zeros((0, 2), dtype=torch.int64, device=f.device)
    out = torch.cat(result, dim=0)
    out = out[out[:, 0] != out[:, 1]]  # a face can meet an edge twice only if degenerate
    out = torch.sort(out, dim=1).values
    return torch.unique(out, dim=0)


def boundary_vertex_mask(faces: FacesLike, num_vertices: int) -> torch.Tensor:
    """Bool ``(N,)`` mask of vertices on an open boundary (an edge used by exactly one face)."""
    f = _as_faces(faces)
    pairs = torch.cat([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]], dim=0)
    pairs = torch.sort(pairs, dim=1).values
    uniq, counts = torch.unique(pairs, dim=0, return_counts=True)
    mask = torch.zeros(num_vertices, dtype=torch.bool, device=f.device)
    mask[uniq[counts == 1].reshape(-1)] = True
    return mask


def is_watertight(faces: FacesLike) -> bool:
    """True when every edge is shared by exactly two faces (closed, edge-manifold)."""
    f = _as_faces(faces)
    if f.numel() == 0:
        return False
    pairs = torch.cat([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]], dim=0)
    pairs = torch.sort(pairs, dim=1).values
    _, counts = torch.unique(pairs, dim=0, return_counts=True)
    return bool((counts == 2).all())


def uniform_laplacian(vertices: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
    """Uniform (umbrella) Laplacian ``L v_i = mean_{j in N(i)} v_j - v_i``, differentiable in ``vertices``.

    The MeshAdv Laplacian flow loss is ``sum_i ||L delta_i||^2`` of the perturbation ``delta``.

    Args:
        vertices: float ``(N, 3)`` or ``(B, N, 3)`` positions (or perturbations).
        edges: int64 ``(E, 2)`` from :func:`vertex_edges`.

    Returns:
        A tensor of the shape of ``vertices``; isolated vertices get 0.
    """
    if vertices.dim() not in (2, 3) or vertices.shape[-1] != 3:
        raise ValueError(f"vertices must have shape (N, 3) or (B, N, 3), got {tuple(vertices.shape)}")
    if edges.dim() != 2 or edges.shape[1] != 2:
        raise ValueError(f"edges must have shape (E, 2), got {tuple(edges.shape)}")
    n = vertices.shape[-2]
    src = torch.cat([edges[:, 0], edges[:, 1]])
    dst = torch.cat([edges[:, 1], edges[:, 0]])
    deg = torch.bincount(src, minlength=n).to(vertices.dtype).clamp(min=1)
    summed = torch.zeros_like(vertices).index_add(-2, src, vertices.index_select(-2, dst))
    mean = summed / deg.unsqueeze(-1)
    has_neighbors = (torch.bincount(src, minlength=n) > 0).to(vertices.dtype).unsqueeze(-1)
    return (mean - vertices) * has_neighbors
