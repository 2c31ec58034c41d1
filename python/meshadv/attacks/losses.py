"""Loss terms of MeshAdv (Xiao et al., CVPR 2019): perceptual losses and adversarial losses.

The attack objective is ``L = L_adv + lambda * L_perceptual``; every function here returns one value per batch item
(``(B,)``) so that several targets can be optimised in one batch and summed without interacting.

Perceptual losses:
    * :func:`laplacian_flow_loss` -- shape: ``sum_i sum_{q in N(i)} ||dv_i - dv_q||^2`` over mesh-edge neighbours
      (each undirected edge is visited from both ends, exactly as the paper's double sum; the value is twice
      the sum over undirected edges).
    * :func:`image_smoothness_loss` -- texture: ``sum_p sum_{q in N4(p)} ||I_p - I_q||^2`` over the 4-neighbours of
      every pixel of the rendered image (again each neighbouring pair counted from both ends).

Adversarial losses (lower = more adversarial), on classifier logits ``(B, K)``:
    * :func:`targeted_cross_entropy` -- ``-log sum_{c in T} softmax(z)_c``; for a single class this is the usual
      cross-entropy, for a group (e.g. all ImageNet classes of "boat") it is ``-(logsumexp(z_T) - logsumexp(z))``.
    * :func:`untargeted_cross_entropy` -- ``log sum_{c in Y} softmax(z)_c`` (minus the cross-entropy of the true group).
    * :func:`cw_targeted_margin` / :func:`cw_untargeted_margin` -- Carlini & Wagner margins with confidence ``kappa``,
      a group's logit being ``logsumexp`` of its members.
    * :func:`disappearance_loss` -- detectors: ``max_{z,b} score_{y'}(z, b)`` over anchors / grid cells and boxes.
"""

from __future__ import annotations

from typing import Optional, Sequence, Tuple, Union

import torch
from torch import Tensor

__all__ = [
    "laplacian_flow_loss",
    "image_smoothness_loss",
    "group_logit",
    "best_other_logit",
    "targeted_cross_entropy",
    "untargeted_cross_entropy",
    "cw_targeted_margin",
    "cw_untargeted_margin",
    "classification_margin",
    "disappearance_loss",
]

ClassIndices = Union[int, Sequence[int], Tensor]


def _check_edges(edges: Tensor, num_vertices: int) -> Tensor:
    """Validate an ``(E, 2)`` integer edge list against ``num_vertices``."""
    if not isinstance(edges, Tensor) or edges.dim() != 2 or edges.shape[1] != 2:
        shape = tuple(edges.shape) if isinstance(edges, Tensor) else type(edges).__name__
        raise ValueError(f"edges must be an integer tensor of shape (E, 2), got {shape}")
    if edges.is_floating_point():
        raise ValueError(f"edges must have an integer dtype, got {edges.dtype}")
    if edges.numel() and (int(edges.min()) < 0 or int(edges.max()) >= num_vertices):
        raise ValueError(f"edges must index vertices in [0, {num_vertices}), got range "
                         f"[{int(edges.min())}, {int(edges.max())}]")
    return edges.long()


def laplacian_flow_loss(displacement: Tensor, edges: Tensor) -> Tensor:
    """The 3D Laplacian loss of a vertex flow: ``sum_i sum_{q in N(i)} ||dv_i - dv_q||^2``.

    ``N(i)`` are the mesh-edge neighbours of vertex ``i``. Each undirected edge ``(i, q)`` appears in the double
    sum twice (from ``i`` and from ``q``), so the value is ``2 * sum_{(i,q) in E} ||dv_i - dv_q||^2``. It is zero
    for any rigid translation (all ``dv_i`` equal) and is the paper's shape distance.

    Args:
        displacement: ``(N, 3)`` or ``(B, N, 3)`` vertex displacements ``dv``.
        edges: int ``(E, 2)`` unique undirected edges (``meshadv.mesh.vertex_edges(faces)``).

    Returns:
        A scalar for ``(N, 3)`` input, else ``(B,)``.

    Raises:
        ValueError: bad shapes or edge indices out of range.

    Example:
        >>> dv = torch.zeros(3, 3); dv[0, 0] = 1.0
        >>> float(laplacian_flow_loss(dv, torch.tensor([[0, 1], [1, 2], [0, 2]])))
        4.0
    """
    if not isinstance(displacement, Tensor) or displacement.dim() not in (2, 3) or displacement.shape[-1] != 3:
        shape = tuple(displacement.shape) if isinstance(displacement, Tensor) else type(displacement).__name__
        raise ValueError(f"displacement must have shape (N, 3) or (B, N, 3), got {shape}")
    edges = _check_edges(edges, displacement.shape[-2])
    diff = displacement[..., edges[:, 0], :] - displacement[..., edges[:, 1], :]
    return 2.0 * diff.pow(2).sum(dim=(-1, -2))


def image_smoothness_loss(images: Tensor, mask: Optional[Tensor] = None) -> Tensor:
    """Smoothness of rendered images: ``sum_p sum_{q in N4(p)} ||I_p - I_q||^2`` (the paper's texture loss).

    Each horizontally or vertically adjacent pixel pair is visited from both ends, so the value is twice the sum
    of squared differences over adjacent pairs (all channels).

    Args:
        images: ``(B, C, H, W)`` images.
        mask: optional ``(B, 1, H, W)`` or ``(B, H, W)`` weights in ``[0, 1]``; a pair counts with the product of
            its two pixels' weights (e.g. the alpha mask, to ignore the background).

    Returns:
        ``(B,)``.

    Raises:
        ValueError: bad shapes.
    """
    if not isinstance(images, Tensor) or images.dim() != 4:
        shape = tuple(images.shape) if isinstance(images, Tensor) else type(images).__name__
        raise ValueError(f"images must have shape (B, C, H, W), got {shape}")
    dx = (images[..., :, 1:] - images[..., :, :-1]).pow(2).sum(dim=1)
    dy = (images[..., 1:, :] - images[..., :-1, :]).pow(2).sum(dim=1)
    if mask is not None:
        if mask.dim() == 4:
            mask = mask[:, 0]
        if mask.shape != (images.shape[0], images.shape[2], images.shape[3]):
            raise ValueError(f"mask must have shape (B, 1, H, W) or (B, H, W) matching images, got {tuple(mask.shape)}")
        dx = dx * mask[..., :, 1:] * mask[..., :, :-1]
        dy = dy * mask[..., 1:, :] * mask[..., :-1, :]
    return 2.0 * (dx.sum(dim=(-1, -2)) + dy.sum(dim=(-1, -2)))


def _class_index_tensor(classes: ClassIndices, num_classes: int, device: torch.device, name: str) -> Tensor:
    """Turn a class index or a group of indices into a 1-D int64 tensor, validated."""
    idx = torch.as_tensor(classes, dtype=torch.long, device=device).reshape(-1)
    if idx.numel() == 0:
        raise ValueError(f"{name} must name at least one class")
    if int(idx.min()) < 0 or int(idx.max()) >= num_classes:
        raise ValueError(f"{name} must be class indices in [0, {num_classes}), got {idx.tolist()}")
    return idx


def _check_logits(logits: Tensor) -> Tensor:
    """Validate ``(B, K)`` logits."""
    if not isinstance(logits, Tensor) or logits.dim() != 2:
        shape = tuple(logits.shape) if isinstance(logits, Tensor) else type(logits).__name__
        raise ValueError(f"logits must have shape (B, K), got {shape}")
    return logits


def _logits_and_classes(logits: Tensor, classes: ClassIndices) -> Tuple[Tensor, Tensor]:
    """Validated ``(B, K)`` logits and the int64 indices of ``classes`` (argument name ``classes``)."""
    logits = _check_logits(logits)
    return logits, _class_index_tensor(classes, logits.shape[1], logits.device, "classes")


def group_logit(logits: Tensor, classes: ClassIndices) -> Tensor:
    """The logit of a class group: ``logsumexp`` of its members' logits (the member's logit for one class).

    Args:
        logits: ``(B, K)``.
        classes: a class index or a group of indices.

    Returns:
        ``(B,)``.
    """
    logits, idx = _logits_and_classes(logits, classes)
    return torch.logsumexp(logits[:, idx], dim=1)


def best_other_logit(logits: Tensor, classes: ClassIndices) -> Tensor:
    """The largest logit among the classes NOT in ``classes``.

    Args:
        logits: ``(B, K)``.
        classes: a class index or a group of indices.

    Returns:
        ``(B,)``.
    """
    logits, idx = _logits_and_classes(logits, classes)
    masked = logits.index_fill(1, idx, float("-inf"))
    return masked.max(dim=1).values


def targeted_cross_entropy(logits: Tensor, target: ClassIndices) -> Tensor:
    """Cross-entropy towards a target class or group: ``-log sum_{c in T} softmax(logits)_c``.

    Args:
        logits: ``(B, K)``.
        target: a class index or a group of class indices (e.g. every ImageNet index of one PASCAL3D+ class).

    Returns:
        ``(B,)``, non-negative, zero when the target group holds all the probability.
    """
    return torch.logsumexp(logits, dim=1) - group_logit(logits, target)


def untargeted_cross_entropy(logits: Tensor, true_class: ClassIndices) -> Tensor:
    """Untargeted loss: minus the cross-entropy of the true class or group, ``log sum_{c in Y} softmax(logits)_c``.

    Args:
        logits: ``(B, K)``.
        true_class: the true class index or group.

    Returns:
        ``(B,)``, non-positive; falls as the true class loses probability.
    """
    return -targeted_cross_entropy(logits, true_class)


def classification_margin(logits: Tensor, classes: ClassIndices) -> Tensor:
    """``group_logit(classes) - best_other_logit(classes)``: positive when the group wins the top-1."""
    return group_logit(logits, classes) - best_other_logit(logits, classes)


def _check_kappa(kappa: float) -> None:
    """``ValueError`` naming ``kappa`` when it is negative."""
    if kappa < 0:
        raise ValueError(f"kappa must be >= 0, got {kappa}")


def cw_targeted_margin(logits: Tensor, target: ClassIndices, kappa: float = 0.0) -> Tensor:
    """Carlini & Wagner targeted loss ``max(max_{j not in T} z_j - z_T, -kappa)``.

    Args:
        logits: ``(B, K)``.
        target: class index or group (group logit = ``logsumexp`` of its members).
        kappa: confidence (>= 0): the loss stops falling once the target leads by ``kappa``.

    Returns:
        ``(B,)``.

    Raises:
        ValueError: negative ``kappa``.
    """
    _check_kappa(kappa)
    return torch.clamp(-classification_margin(logits, target), min=-float(kappa))


def cw_untargeted_margin(logits: Tensor, true_class: ClassIndices, kappa: float = 0.0) -> Tensor:
    """Carlini & Wagner untargeted loss ``max(z_Y - max_{j not in Y} z_j, -kappa)``.

    Args:
        logits: ``(B, K)``.
        true_class: class index or group.
        kappa: confidence (>= 0).

    Returns:
        ``(B,)``.

    Raises:
        ValueError: negative ``kappa``.
    """
    _check_kappa(kappa)
    return torch.clamp(classification_margin(logits, true_class), min=-float(kappa))


def disappearance_loss(scores: Tensor, classes: Optional[ClassIndices] = None) -> Tensor:
    """Detector disappearance loss: ``max_{z, b} score_{y'}(z, b)``, the best score of the hidden class(es).

    Args:
        scores: ``(B, A, K)`` per-anchor class scores (objectness x class probability where the model has one,
            ``DetectorOutput.scores()``).
        classes: the class index or indices to hide; ``None`` hides every class (max over all K).

    Returns:
        ``(B,)`` the highest score of the hidden classes in each image.

    Raises:
        ValueError: bad shapes or class indices.
    """
    if not isinstance(scores, Tensor) or scores.dim() != 3:
        shape = tuple(scores.shape) if isinstance(scores, Tensor) else type(scores).__name__
        raise ValueError(f"scores must have shape (B, A, K), got {shape}")
    if classes is not None:
        idx = _class_index_tensor(classes, scores.shape[2], scores.device, "classes")
        scores = scores[..., idx]
    return scores.flatten(1).max(dim=1).values
