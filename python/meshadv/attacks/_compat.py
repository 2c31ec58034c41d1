"""Small adapters to the mesh layer, so the attacks work while it grows."""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["vertex_edges"]


def vertex_edges(faces: Tensor) -> Tensor:
    """Unique undirected edges ``(E, 2)`` (int64, ``i < j``) of a triangle list ``(M, 3)``.

    Uses ``meshadv.mesh.vertex_edges`` when the mesh layer exports it, else computes the same thing here.

    Raises:
        ValueError: ``faces`` is not an integer ``(M, 3)`` tensor.
    """
    try:
        from meshadv.mesh import vertex_edges as mesh_vertex_edges
    except ImportError:
        mesh_vertex_edges = None
    if mesh_vertex_edges is not None:
        return mesh_vertex_edges(faces).long()
    if not isinstance(faces, Tensor) or faces.dim() != 2 or faces.shape[1] != 3 or faces.is_floating_point():
        raise ValueError("faces must be an integer tensor of shape (M, 3)")
    f = faces.long()
    pairs = torch.cat([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]], dim=0)
    pairs = torch.sort(pairs, dim=1).values
    return torch.unique(pairs, dim=0)
