"""A texture attack whose colour change is a smooth field over the surface, for meshes finer than the pixels.

The MeshAdv texture attack (:class:`meshadv.attacks.TextureAttack`) optimises one colour per face. When a pixel covers
many faces (the Stanford Bunny of the indoor scene: 69k faces in about 500 pixels, a hundred faces per pixel), the
rasterizer samples only the few faces under its sample points, so the attack changes those faces and leaves their
neighbours alone; a path tracer averages every face inside the pixel and sees mostly unchanged colours: the attack
does not transfer even under the same camera and lights.

:class:`SmoothTextureAttack` optimises a per-vertex offset ``d`` (``N x 3``, logit space) and applies

``colors = sigmoid(logit(original) + mean_{v in face} (S^k d)_v)``

with ``S^k`` the ``k``-round neighbour averaging of :func:`meshadv.attacks.flow.smooth_flow` (about ``sqrt(k)``
rings of vertices): neighbouring faces change together, so a pixel's average colour changes as its samples do. At
``d = 0`` the colours are the original ones exactly. The perceptual loss (image smoothness) and the reported
distance (face-colour RMSE) are those of :class:`~meshadv.attacks.TextureAttack`.

Example:
    >>> attack = SmoothTextureAttack(smoothing=32, steps=200)                          # doctest: +SKIP
    >>> result = attack(bunny, views, detector, Disappearance("dining table"))        # doctest: +SKIP
"""

from __future__ import annotations

from typing import Any, Dict

import torch
from torch import Tensor

from meshadv._validate import non_negative_int
from meshadv.attacks.flow import smooth_flow
from meshadv.attacks.norms import COLOR_EPS
from meshadv.attacks.texture import TextureAttack

__all__ = ["SmoothTextureAttack"]


class SmoothTextureAttack(TextureAttack):
    """Texture attack with a smoothed per-vertex colour offset (see the module docstring).

    Args:
        smoothing: rounds ``k`` of neighbour averaging of the per-vertex offset, ``>= 0`` (0: each vertex's offset
            is its own, faces still share their vertices' offsets).
        **kwargs: the hyper-parameters of :class:`~meshadv.attacks.TextureAttack` (keyword-only, ``face_mask``
            included; default ``lr`` 0.05 in logit space).

    Raises:
        TypeError: ``smoothing`` is not an integer.
        ValueError: ``smoothing < 0``, or a hyper-parameter of the base attack is out of range.
    """

    def __init__(self, *, smoothing: int = 16, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        if self.gradient_smoothing:
            raise ValueError(f"gradient_smoothing must be 0 for SmoothTextureAttack (its smoothing already smooths "
                             f"the colour field), got {self.gradient_smoothing}")
        self.smoothing = non_negative_int("smoothing", smoothing)

    def config(self) -> Dict[str, Any]:
        """Hyper-parameters, including ``smoothing``."""
        return {**super().config(), "smoothing": self.smoothing}

    def initial_params(self, mesh: Any, num_targets: int) -> Tensor:
        """No offset: zeros ``(T, N, 3)``."""
        return mesh.vertices.new_zeros((num_targets, *mesh.vertices.shape))

    def _colors(self, params: Tensor, mesh: Any, edges: Tensor) -> Tensor:
        """Face colours ``(K, M, 3)`` for per-vertex offsets ``params`` ``(K, N, 3)`` (before the face mask)."""
        base = torch.logit(mesh.face_colors.clamp(COLOR_EPS, 1 - COLOR_EPS))
        offset = smooth_flow(params, edges, self.smoothing)[:, mesh.faces].mean(dim=2)
        return torch.sigmoid(base.unsqueeze(0) + offset)
