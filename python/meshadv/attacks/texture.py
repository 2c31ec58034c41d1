"""The MeshAdv texture attack: optimise per-face colours under the rendered image's 4-neighbour smoothness loss.

Colours stay physically valid, in ``[0, 1]``, by optimising in logit space: ``colors = sigmoid(w)`` with
``w`` initialised to ``logit(clamp(colors, 1e-4, 1 - 1e-4))`` (chosen over clamping after each step because it keeps
Adam's state consistent and the gradient defined at the bounds). The perceptual loss is the paper's
``sum_p sum_{q in N4(p)} ||I_p - I_q||^2`` on each rendered adversarial image, averaged over the views.
The reported distance is the face-colour RMSE ``sqrt(1/m sum_i ||t_i^adv - t_i||^2)``.

Example:
    >>> from meshadv.attacks import TextureAttack, TargetedMisclassification
    >>> attack = TextureAttack(steps=200, lr=0.05, lambda_perceptual=1e-4)
    >>> result = attack(mesh, views, victim, TargetedMisclassification("bicycle"))   # doctest: +SKIP
"""

from __future__ import annotations

from typing import Any, Tuple

import torch
from torch import Tensor

from meshadv.attacks.base import MeshAttack
from meshadv.attacks.distances import color_rmse
from meshadv.attacks.losses import image_smoothness_loss

__all__ = ["TextureAttack"]

_EPS = 1e-4


class TextureAttack(MeshAttack):
    """Adversarial per-face colours (the paper's texture attack); hyper-parameters as in :class:`MeshAttack`.

    Args:
        **kwargs: the keyword-only hyper-parameters of :class:`~meshadv.attacks.base.MeshAttack`; the default
            ``lr`` is 0.05 (in logit space) and ``lambda_perceptual`` 1e-4 (the image loss sums over pixels).

    Raises:
        ValueError: a hyper-parameter out of range.
    """

    perturbation = "texture"

    def __init__(self, **kwargs: Any) -> None:
        kwargs.setdefault("lr", 0.05)
        kwargs.setdefault("lambda_perceptual", 1e-4)
        super().__init__(**kwargs)

    def _init_params(self, mesh: Any, num_targets: int) -> Tensor:
        logits = torch.logit(mesh.face_colors.clamp(_EPS, 1 - _EPS))
        return logits.unsqueeze(0).repeat(num_targets, 1, 1)

    def _apply(self, params: Tensor, mesh: Any, edges: Tensor) -> Tuple[Tensor, Tensor]:
        verts = mesh.vertices.unsqueeze(0).expand(params.shape[0], -1, -1)
        return verts, torch.sigmoid(params)

    def _perceptual(self, params: Tensor, mesh: Any, edges: Tensor, images: Tensor, alpha: Tensor,
                    num_views: int) -> Tensor:
        return image_smoothness_loss(images).view(params.shape[0], num_views).mean(dim=1)

    def _distance(self, params: Tensor, mesh: Any, edges: Tensor) -> Tensor:
        return color_rmse(torch.sigmoid(params), mesh.face_colors)
