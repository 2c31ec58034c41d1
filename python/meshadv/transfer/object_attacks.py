"""Attacks restricted to one object of a merged scene (the others keep their colours and vertices).

Also builds the texture attack of a black-box run: the paper's per-face one or the smoothed per-vertex one
(:class:`~meshadv.transfer.smooth_texture.SmoothTextureAttack`).
"""

from __future__ import annotations

from typing import Any, Optional

import torch

__all__ = ["object_shape_attack", "object_texture_attack"]


def _check_mask(mask: Any, name: str, element: str) -> None:
    """Raise ValueError unless ``mask`` (called ``name``) is a 1-D bool tensor selecting at least one ``element``."""
    if not isinstance(mask, torch.Tensor) or mask.dtype != torch.bool or mask.dim() != 1:
        raise ValueError(f"{name} must be a 1-D bool tensor")
    if not bool(mask.any()):
        raise ValueError(f"{name} selects no {element}")


def object_texture_attack(face_mask: torch.Tensor, **kwargs: Any) -> Any:
    """A :class:`meshadv.attacks.TextureAttack` that changes only the faces in ``face_mask`` (one object of a scene).

    Args:
        face_mask: bool (M,) faces whose colours may change.
        **kwargs: the attack's hyper-parameters.

    Raises:
        ValueError: ``face_mask`` is not a non-empty 1-D bool tensor.
    """
    from meshadv.attacks import TextureAttack
    from meshadv.attacks.distances import color_rmse

    _check_mask(face_mask, "face_mask", "face")

    class _ObjectTextureAttack(TextureAttack):
        def _apply(self, params: torch.Tensor, mesh: Any, edges: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            verts, colors = super()._apply(params, mesh, edges)
            fixed = mesh.face_colors.unsqueeze(0).expand_as(colors)
            return verts, torch.where(face_mask[None, :, None], colors, fixed)

        def _distance(self, params: torch.Tensor, mesh: Any, edges: torch.Tensor) -> torch.Tensor:
            colors = torch.sigmoid(params)[:, face_mask]
            return color_rmse(colors, mesh.face_colors[face_mask])

    return _ObjectTextureAttack(**kwargs)


def object_shape_attack(vertex_mask: torch.Tensor, **kwargs: Any) -> Any:
    """A :class:`meshadv.attacks.ShapeAttack` that moves only the vertices in ``vertex_mask`` (one object of a scene).

    The parameters of the other vertices are multiplied by zero before the attack's parametrisation (smoothing,
    clamp) is applied, so they get no gradient and stay at zero; the objects of a merged scene share no edge, so
    neither the smoothing nor the Laplacian loss crosses from one object to another.

    Args:
        vertex_mask: bool (N,) vertices that may move.
        **kwargs: the attack's hyper-parameters (:class:`~meshadv.attacks.ShapeAttack`).

    Raises:
        ValueError: ``vertex_mask`` is not a non-empty 1-D bool tensor.
    """
    from meshadv.attacks import ShapeAttack

    _check_mask(vertex_mask, "vertex_mask", "vertex")
    keep = vertex_mask[None, :, None].float()

    class _ObjectShapeAttack(ShapeAttack):
        def _apply(self, params: torch.Tensor, mesh: Any, edges: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            return super()._apply(params * keep, mesh, edges)

        def _perceptual(self, params: torch.Tensor, mesh: Any, edges: torch.Tensor, images: torch.Tensor,
                        alpha: torch.Tensor, num_views: int) -> torch.Tensor:
            return super()._perceptual(params * keep, mesh, edges, images, alpha, num_views)

        def _distance(self, params: torch.Tensor, mesh: Any, edges: torch.Tensor) -> torch.Tensor:
            return super()._distance(params * keep, mesh, edges)

    return _ObjectShapeAttack(**kwargs)


def _check_smoothing(texture_smoothing: Optional[int], attack_type: str) -> None:
    """Raise ValueError unless ``texture_smoothing`` is None, or an int >= 0 with ``attack_type == "texture"``."""
    if texture_smoothing is None:
        return
    if attack_type != "texture":
        raise ValueError("texture_smoothing applies to texture attacks only (attack_type='texture')")
    if isinstance(texture_smoothing, bool) or not isinstance(texture_smoothing, int) or texture_smoothing < 0:
        raise ValueError(f"texture_smoothing must be None or an int >= 0, got {texture_smoothing!r}")


def _texture_attack(smoothing: Optional[int], face_mask: Optional[torch.Tensor], kwargs: dict[str, Any]) -> Any:
    """The paper's per-face texture attack (``smoothing`` None) or the smoothed per-vertex one."""
    from meshadv.attacks import TextureAttack
    from meshadv.transfer.smooth_texture import SmoothTextureAttack

    if smoothing is None:
        return TextureAttack(**kwargs)
    return SmoothTextureAttack(smoothing=smoothing, face_mask=face_mask, **kwargs)
