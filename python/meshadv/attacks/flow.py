"""The smoothed vertex-flow parametrisation of :class:`~meshadv.attacks.ShapeAttack` (``smoothing=k``) and of
:class:`~meshadv.attacks.SmoothTextureAttack`'s per-vertex colour offset: the one place it lives.

Instead of optimising the displacement ``dv`` itself, an attack may optimise parameters ``p`` and apply
``dv = S^k p`` with ``S p = p + 0.5 * L p`` (``L`` the uniform Laplacian, ``L p_i = mean_{j in N(i)} p_j - p_i``), i.e.
``k`` rounds of "half the vertex, half the mean of its mesh-edge neighbours". ``S`` is linear, keeps rigid
translations (``S c = c``) and damps the mesh's high frequencies (the eigenvalues of ``S`` are ``(1 + mu) / 2`` for the
eigenvalues ``mu in [-1, 1]`` of the neighbour-mean operator: a vertex-by-vertex alternating pattern is removed).

Why: Adam moves every coordinate that receives any gradient by about ``lr`` per step whatever the gradient's size,
and NMR's rasterization gradient plus the shading gradient are noisy from vertex to vertex, so plain per-vertex flow
(``k = 0``, the paper's method) roughens a dense mesh. With ``k > 0`` the gradient on ``p`` is ``(S^T)^k`` of the
gradient on ``dv`` (spread over about ``sqrt(k)`` rings of neighbours) and each Adam step moves smooth patches, in
the spirit of Nicolet et al., "Large Steps in Inverse Rendering of Geometry" (2021), whose ``(I + lambda L)^-1``
reparametrisation this cheap explicit filter approximates. The scene attack uses it on the dense Stanford bunny; on
coarse meshes the filter removes the per-vertex detail that changes the label fastest. The perturbation is always
measured (Laplacian loss, displacement) on the applied ``dv``.

Example:
    >>> import torch
    >>> edges = torch.tensor([[0, 1], [1, 2]])              # a path 0 - 1 - 2
    >>> p = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    >>> smooth_flow(p, edges, 1)[:, 0].tolist()             # 0: 0.5*1 + 0.5*0, 1: 0.5*0 + 0.5*(1+0)/2, 2: 0
    [0.5, 0.25, 0.0]
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["smooth_flow"]


def smooth_flow(params: Tensor, edges: Tensor, rounds: int) -> Tensor:
    """``rounds`` rounds of neighbour averaging ``p <- p + 0.5 * L p`` over mesh edges (differentiable, linear).

    Each round replaces every vertex's value by the average of itself and the mean of its mesh-edge neighbours;
    vertices without neighbours keep their value. ``rounds = 0`` returns ``params`` unchanged (the same tensor).

    Args:
        params: float ``(N, C)`` or ``(B, N, C)`` per-vertex values (``C = 3`` for a vertex flow).
        edges: int ``(E, 2)`` unique undirected mesh edges (``meshadv.mesh.vertex_edges(faces)``).
        rounds: number of averaging rounds, ``>= 0``.

    Returns:
        A tensor of the shape and dtype of ``params``.

    Shape:
        ``params (..., N, C)``, ``edges (E, 2)`` with indices in ``[0, N)`` -> ``(..., N, C)``.

    Raises:
        ValueError: negative ``rounds``, bad shapes or edge indices out of range.
    """
    if isinstance(rounds, bool) or int(rounds) != rounds or rounds < 0:
        raise ValueError(f"rounds must be an integer >= 0, got {rounds!r}")
    if not isinstance(params, Tensor) or params.dim() not in (2, 3):
        shape = tuple(params.shape) if isinstance(params, Tensor) else type(params).__name__
        raise ValueError(f"params must have shape (N, C) or (B, N, C), got {shape}")
    if not isinstance(edges, Tensor) or edges.dim() != 2 or edges.shape[1] != 2 or edges.is_floating_point():
        shape = tuple(edges.shape) if isinstance(edges, Tensor) else type(edges).__name__
        raise ValueError(f"edges must be an integer tensor of shape (E, 2), got {shape}")
    n = params.shape[-2]
    if edges.numel() and (int(edges.min()) < 0 or int(edges.max()) >= n):
        raise ValueError(f"edges index vertices outside [0, {n}) (params has {n} vertices)")
    if rounds == 0:
        return params
    edges = edges.to(device=params.device, dtype=torch.long)
    src = torch.cat([edges[:, 0], edges[:, 1]])
    dst = torch.cat([edges[:, 1], edges[:, 0]])
    count = torch.bincount(src, minlength=n)
    # the same operations, in the same order, as ``p + 0.5 * meshadv.mesh.uniform_laplacian(p, edges)``
    degree = count.to(params.dtype).clamp(min=1).unsqueeze(-1)
    has_neighbors = (count > 0).to(params.dtype).unsqueeze(-1)
    p = params
    for _ in range(int(rounds)):
        mean = torch.zeros_like(p).index_add(-2, src, p.index_select(-2, dst)) / degree
        p = p + 0.5 * ((mean - p) * has_neighbors)
    return p
