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

from typing import Any, Optional, Tuple

import torch
from torch import Tensor

from meshadv.attacks import TextureAttack
from meshadv.attacks.distances import color_rmse
from meshadv.attacks.flow import smooth_flow

__all__ = ["SmoothTextureAttack"]

_EPS = 1e-4


class SmoothTextureAttack(TextureAttack):
    """Texture attack with a smoothed per-vertex colour offset (see the module docstring).

    Args:
        smoothing: rounds ``k`` of neighbour averaging of the per-vertex offset, ``>= 0`` (0: each vertex's offset
            is its own, faces still share their vertices' offsets).
        face_mask: optional bool ``(M,)``: only these faces change colour (one object of a merged scene); the
            distance is then measured on them only.
        **kwargs: the hyper-parameters of :class:`~meshadv.attacks.TextureAttack` (keyword-only; default ``lr``
            0.05 in logit space).

    Raises:
        ValueError: ``smoothing`` is not an int ``>= 0``, ``face_mask`` is not a non-empty 1-D bool tensor, or a
            hyper-parameter of the base attack is out of range.
    """

    def __init__(self, *, smoothing: int = 16, face_mask: Optional[Tensor] = None, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        if isinstance(smoothing, bool) or not isinstance(smoothing, int) or smoothing < 0:
            raise ValueError(f"smoothing must be an int >= 0, got {smoothing!r}")
        if face_mask is not None:
            if not isinstance(face_mask, Tensor) or face_mask.dtype != torch.bool or face_mask.dim() != 1:
                raise ValueError("face_mask must be None or a 1-D bool tensor")
            if not bool(face_mask.any()):
                raise ValueError("face_mask selects no face")
        self.smoothing = int(smoothing)
        self.face_mask = face_mask

    def config(self) -> dict:
        """Hyper-parameters, including ``smoothing`` (and whether a face mask is used)."""
        return {**super().config(), "smoothing": self.smoothing, "face_mask": self.face_mask is not None}

    def _check_mask(self, mesh: Any) -> None:
        if self.face_mask is not None and self.face_mask.shape[0] != mesh.faces.shape[0]:
            raise ValueError(f"face_mask has {self.face_mask.shape[0]} entries for a mesh of "
                             f"{mesh.faces.shape[0]} faces")

    def _init_params(self, mesh: Any, num_targets: int) -> Tensor:
        self._check_mask(mesh)
        return mesh.vertices.new_zeros((num_targets, *mesh.vertices.shape))

    def colors(self, params: Tensor, mesh: Any, edges: Tensor) -> Tensor:
        """Face colours ``(K, M, 3)`` for per-vertex offsets ``params`` ``(K, N, 3)``."""
        base = torch.logit(mesh.face_colors.clamp(_EPS, 1 - _EPS))
        offset = smooth_flow(params, edges, self.smoothing)[:, mesh.faces].mean(dim=2)
        colors = torch.sigmoid(base.unsqueeze(0) + offset)
        if self.face_mask is not None:
            colors = torch.where(self.face_mask[None, :, None], colors, mesh.face_colors.unsqueeze(0))
        return colors

    def _apply(self, params: Tensor, mesh: Any, edges: Tensor) -> Tuple[Tensor, Tensor]:
        verts = mesh.vertices.unsqueeze(0).expand(params.shape[0], -1, -1)
        return verts, self.colors(params, mesh, edges)

    def _distance(self, params: Tensor, mesh: Any, edges: Tensor) -> Tensor:
        colors = self.colors(params, mesh, edges)
        if self.face_mask is None:
            return color_rmse(colors, mesh.face_colors)
        return color_rmse(colors[:, self.face_mask], mesh.face_colors[self.face_mask])
