"""Distortion measures of adversarial meshes: the paper's two, in both conventions, plus bounding-box displacements.

Shape (MeshAdv, Xiao et al., CVPR 2019, Eq. 4): the Laplacian loss of the vertex flow ``dv``,
``sum_i sum_{q in N(i)} ||dv_i - dv_q||^2``. Read literally it is a *sum* over vertices and their neighbours (every
undirected edge counted from both ends); the paper's reported magnitudes (~1e-4 on meshes of a few thousand vertices)
match the *mean over those (vertex, neighbour) pairs* instead. Both are reported, under names that say which:

* ``laplacian_sum`` -- :func:`laplacian_distance`, the literal Eq. 4 sum (also the attack's loss term);
* ``laplacian_pair_mean`` -- :func:`laplacian_pair_mean`, the sum divided by the ``2E`` ordered pairs; the
  convention comparable with the paper's tables.

Texture: ``color_rmse`` -- :func:`color_rmse`, the paper's ``sqrt(1/m sum_i ||t_i^adv - t_i||^2)`` over the ``m``
faces (``t_i`` the face's RGB colour); ``color_rmse_per_channel`` -- the same over the ``3m`` channel values
(``color_rmse / sqrt(3)``). Also ``max_displacement`` / ``mean_displacement`` (:func:`displacement_stats`), relative
to the pristine mesh's bounding-box diagonal.

The measures a person would agree with (95th-percentile displacement, area-weighted change of the face normals and
colours, SSIM of renders on held-out views) are :mod:`meshadv.perceptibility`'s; an attack's result reports them
beside these (:data:`DISTANCE_DESCRIPTIONS` describes both).

:func:`mesh_distances` computes the measures above for a pristine / adversarial mesh pair; :func:`read_distance`
reads one from a stored record, old records (one key ``laplacian``, the Eq. 4 sum) included.
:data:`PAPER_COMPARABLE` names the measure per perturbation type that the paper's tables report.
"""

from __future__ import annotations

import math
from typing import Any, Dict, Mapping, Optional

import torch
from torch import Tensor

from meshadv.attacks.losses import laplacian_flow_loss
from meshadv.mesh.structure import bbox_diagonal
from meshadv.perceptibility.measures import MEASURE_DESCRIPTIONS

__all__ = [
    "laplacian_distance",
    "laplacian_pair_mean",
    "color_rmse",
    "displacement_stats",
    "mesh_distances",
    "read_distance",
    "PAPER_COMPARABLE",
    "DISTANCE_DESCRIPTIONS",
]

#: The measure per perturbation type that is comparable with the paper's Table 1.
PAPER_COMPARABLE = {"shape": "laplacian_pair_mean", "texture": "color_rmse"}

#: One line per reported measure, for tables and reports.
DISTANCE_DESCRIPTIONS = {
    "laplacian_pair_mean": "Eq. 4 Laplacian loss of the flow divided by the 2E (vertex, neighbour) pairs "
                           "(the paper's scale)",
    "laplacian_sum": "Eq. 4 Laplacian loss of the flow, the literal sum over vertices and neighbours",
    "color_rmse": "face-colour RMSE sqrt(1/m sum_i ||t_i^adv - t_i||^2) over m faces (the paper's measure)",
    "color_rmse_per_channel": "face-colour RMSE over the 3m channel values (color_rmse / sqrt(3))",
    "max_displacement": "largest vertex displacement / bounding-box diagonal",
    "mean_displacement": "mean vertex displacement / bounding-box diagonal",
    **{k: v for k, v in MEASURE_DESCRIPTIONS.items() if k != "max_displacement"},
}


def laplacian_distance(displacement: Tensor, edges: Tensor) -> Tensor:
    """The literal Eq. 4 shape distance: the Laplacian flow loss of ``displacement`` (``losses.laplacian_flow_loss``).

    Args:
        displacement: ``(N, 3)`` or ``(B, N, 3)``.
        edges: int ``(E, 2)`` unique undirected mesh edges.

    Returns:
        A scalar or ``(B,)``.
    """
    return laplacian_flow_loss(displacement, edges)


def laplacian_pair_mean(displacement: Tensor, edges: Tensor) -> Tensor:
    """Eq. 4 divided by its number of terms, ``2E``: the mean ``||dv_i - dv_q||^2`` over (vertex, neighbour) pairs.

    This is the convention whose magnitudes match the paper's Table 1.

    Args:
        displacement: ``(N, 3)`` or ``(B, N, 3)``.
        edges: int ``(E, 2)`` unique undirected mesh edges, ``E >= 1``.

    Returns:
        A scalar or ``(B,)``.

    Raises:
        ValueError: no edges, or bad shapes.

    Example:
        >>> dv = torch.zeros(3, 3); dv[0, 0] = 1.0
        >>> float(laplacian_pair_mean(dv, torch.tensor([[0, 1], [1, 2], [0, 2]])))  # 4 / 6
        0.6666666865348816
    """
    if edges.dim() != 2 or edges.shape[0] == 0:
        raise ValueError(f"edges must be a non-empty (E, 2) tensor, got {tuple(edges.shape)}")
    return laplacian_flow_loss(displacement, edges) / (2.0 * edges.shape[0])


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
        edges: int ``(E, 2)`` unique mesh edges (needed for the Laplacian distances; omitted -> not reported).

    Returns:
        ``color_rmse``, ``color_rmse_per_channel``, ``max_displacement``, ``mean_displacement`` and, with edges,
        ``laplacian_sum``, ``laplacian_pair_mean`` and ``num_edges`` (see the module docstring).

    Raises:
        ValueError: mismatched shapes.
    """
    if vertices.shape != vertices_adv.shape:
        raise ValueError(f"vertices_adv {tuple(vertices_adv.shape)} must match vertices {tuple(vertices.shape)}")
    with torch.no_grad():
        dv = (vertices_adv - vertices).float()
        rmse = float(color_rmse(colors_adv.float(), colors.float()))
        out: Dict[str, float] = {"color_rmse": rmse, "color_rmse_per_channel": rmse / math.sqrt(3.0)}
        if edges is not None:
            total = float(laplacian_distance(dv, edges))
            out["laplacian_sum"] = total
            out["laplacian_pair_mean"] = total / (2.0 * edges.shape[0]) if edges.shape[0] else 0.0
            out["num_edges"] = int(edges.shape[0])
        out.update({k: float(v) for k, v in displacement_stats(dv, vertices.float()).items()})
    return out


def read_distance(distances: Mapping[str, Any], name: str) -> Optional[float]:
    """Read one measure from a stored ``distances`` dict, records written before both conventions existed included.

    Old records hold one key ``laplacian`` (the Eq. 4 sum): it is read as ``laplacian_sum``, and as
    ``laplacian_pair_mean`` only when the record also holds ``num_edges`` (otherwise ``None``: the edge count is
    unknown).

    Args:
        distances: a record's ``distances`` (from :func:`mesh_distances` or an older version).
        name: a key of :data:`DISTANCE_DESCRIPTIONS` (or any other key of the dict).

    Returns:
        The value, or ``None`` when the record does not allow it.
    """
    value = distances.get(name)
    if value is None and "laplacian" in distances and distances["laplacian"] is not None:
        if name == "laplacian_sum":
            value = distances["laplacian"]
        elif name == "laplacian_pair_mean" and distances.get("num_edges"):
            value = float(distances["laplacian"]) / (2.0 * float(distances["num_edges"]))
    if value is None and name == "color_rmse_per_channel" and distances.get("color_rmse") is not None:
        value = float(distances["color_rmse"]) / math.sqrt(3.0)
    return None if value is None else float(value)
