"""Distortion measures of adversarial meshes, as reported by the paper plus bounding-box-relative displacements.

* shape: :func:`laplacian_distance` -- the Laplacian loss value of the vertex flow ``dv`` (the paper's measure);
  :func:`displacement_stats` -- max and mean ``||dv_i||`` divided by the pristine mesh's bounding-box diagonal.
* texture: :func:`color_rmse` -- ``sqrt(1/m sum_i ||t_i^adv - t_i||^2)`` over the ``m`` faces.

:func:`mesh_distances` computes all of them for a pristine / adversarial mesh pair.
"""

from __future__ import annotations

from typing import Dict, Optional

import torch
from torch import Tensor

from meshadv.attacks.losses import laplacian_flow_loss

__all__ = ["laplacian_distance", "color_rmse", "bbox_diagonal", "displacement_stats", "mesh_distances"]


def laplacian_distance(displacement: Tensor, edges: Tensor) -> Tensor:
    """The paper's shape distance: the Laplacian flow loss of ``displacement`` (see ``losses.laplacian_flow_loss``).

    Args:
        displacement: ``(N, 3)`` or ``(B, N, 3)``.
        edges: int ``(E, 2)`` unique undirected mesh edges.

    Returns:
        A scalar or ``(B,)``.
    """
    return laplacian_flow_loss(displacement, edges)


def color_rmse(colors_adv: Tensor, colors: Tensor) -> Tensor:
    """The paper's texture distance ``sqrt(1/m sum_i ||t_i^adv - t_i||^2)`` over the ``m`` faces.

    Args:
        colors_adv: ``(M, 3)`` or ``(B, M, 3)`` adversarial face colours.
        colors: ``(M, 3)`` pristine face colours.

    Returns:
        A scalar or ``(B,)``.

    Raises:
        ValueError: mismatched shapes.
    """
    if colors_adv.shape[-2:] != colors.shape[-2:] or colors.dim() != 2:
        raise ValueError(f"colors_adv {tuple(colors_adv.shape)} and colors {tuple(colors.shape)} must be (…, M, 3) "
                         "and (M, 3) with the same M")
    return (colors_adv - colors).pow(2).sum(dim=-1).mean(dim=-1).sqrt()


def bbox_diagonal(vertices: Tensor) -> Tensor:
    """Length of the axis-aligned bounding-box diagonal of ``(N, 3)`` vertices (a scalar tensor)."""
    if vertices.dim() != 2 or vertices.shape[1] != 3 or vertices.shape[0] == 0:
        raise ValueError(f"vertices must have shape (N, 3) with N > 0, got {tuple(vertices.shape)}")
    return (vertices.max(dim=0).values - vertices.min(dim=0).values).norm()


def displacement_stats(displacement: Tensor, vertices: Tensor) -> Dict[str, Tensor]:
    """Max and mean per-vertex displacement norms relative to the pristine bounding-box diagonal.

    Args:
        displacement: ``(N, 3)`` or ``(B, N, 3)``.
        vertices: ``(N, 3)`` pristine vertices.

    Returns:
        ``{"max_displacement": ..., "mean_displacement": ...}``, scalars or ``(B,)``.
    """
    diag = bbox_diagonal(vertices).clamp_min(1e-12)
    norms = displacement.norm(dim=-1)
    return {"max_displacement": norms.max(dim=-1).values / diag, "mean_displacement": norms.mean(dim=-1) / diag}


def mesh_distances(
    vertices: Tensor,
    colors: Tensor,
    vertices_adv: Tensor,
    colors_adv: Tensor,
    edges: Optional[Tensor] = None,
) -> Dict[str, float]:
    """Every distance between a pristine mesh and its adversarial version, as plain floats.

    Args:
        vertices: ``(N, 3)`` pristine vertices.
        colors: ``(M, 3)`` pristine face colours.
        vertices_adv: ``(N, 3)`` adversarial vertices.
        colors_adv: ``(M, 3)`` adversarial face colours.
        edges: int ``(E, 2)`` unique mesh edges (needed for the Laplacian distance; omitted -> not reported).

    Returns:
        ``{"laplacian", "color_rmse", "max_displacement", "mean_displacement"}`` (``laplacian`` only with edges).

    Raises:
        ValueError: mismatched shapes.
    """
    if vertices.shape != vertices_adv.shape:
        raise ValueError(f"vertices_adv {tuple(vertices_adv.shape)} must match vertices {tuple(vertices.shape)}")
    with torch.no_grad():
        dv = (vertices_adv - vertices).float()
        out = {"color_rmse": float(color_rmse(colors_adv.float(), colors.float()))}
        if edges is not None:
            out["laplacian"] = float(laplacian_distance(dv, edges))
        out.update({k: float(v) for k, v in displacement_stats(dv, vertices.float()).items()})
    return out
