"""The MeshAdv shape attack: optimise a per-vertex displacement ``dv`` under the 3D Laplacian flow loss.

``vertices_adv = vertices + dv``; the objective is ``L_adv + lambda * sum_i sum_{q in N(i)} ||dv_i - dv_q||^2``
(mesh-edge neighbours), minimised with Adam from ``dv = 0``. Colours and topology are unchanged.

Example:
    >>> from meshadv.attacks import ShapeAttack, TargetedMisclassification
    >>> attack = ShapeAttack(steps=200, lr=2e-3, lambda_perceptual=0.05)
    >>> result = attack(mesh, views, victim, TargetedMisclassification("bicycle"))   # doctest: +SKIP
    >>> result.save("out/")                                                            # doctest: +SKIP
"""

from __future__ import annotations

from typing import Any, Optional, Tuple

from torch import Tensor

from meshadv.attacks.base import MeshAttack
from meshadv.attacks.losses import laplacian_flow_loss

__all__ = ["ShapeAttack"]


class ShapeAttack(MeshAttack):
    """Adversarial vertex flow (the paper's shape attack); hyper-parameters as in :class:`MeshAttack`.

    Args:
        max_step: optional per-coordinate bound on ``|dv|`` (clamped after every Adam step); ``None`` = unbounded.
        **kwargs: the keyword-only hyper-parameters of :class:`~meshadv.attacks.base.MeshAttack`; the default
            ``lr`` is 1e-3 and ``lambda_perceptual`` 0.05 (meshes scaled to ``[-1, 1]``).

    Raises:
        ValueError: a hyper-parameter out of range.
    """

    perturbation = "shape"

    def __init__(self, *, max_step: Optional[float] = None, **kwargs: Any) -> None:
        kwargs.setdefault("lr", 1e-3)
        kwargs.setdefault("lambda_perceptual", 0.05)
        super().__init__(**kwargs)
        if max_step is not None and not max_step > 0:
            raise ValueError(f"max_step must be None or > 0, got {max_step}")
        self.max_step = None if max_step is None else float(max_step)

    def config(self) -> dict:
        """Hyper-parameters, including ``max_step``."""
        return {**super().config(), "max_step": self.max_step}

    def _init_params(self, mesh: Any, num_targets: int) -> Tensor:
        return mesh.vertices.new_zeros((num_targets, *mesh.vertices.shape))

    def _bounded(self, params: Tensor) -> Tensor:
        return params if self.max_step is None else params.clamp(-self.max_step, self.max_step)

    def _apply(self, params: Tensor, mesh: Any) -> Tuple[Tensor, Tensor]:
        return mesh.vertices.unsqueeze(0) + self._bounded(params), mesh.face_colors

    def _perceptual(self, params: Tensor, mesh: Any, edges: Tensor, images: Tensor, alpha: Tensor,
                    num_views: int) -> Tensor:
        return laplacian_flow_loss(self._bounded(params), edges)

    def _distance(self, params: Tensor, mesh: Any, edges: Tensor) -> Tensor:
        return laplacian_flow_loss(self._bounded(params), edges)
