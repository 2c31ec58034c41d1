"""The attack of a black-box run: shape, or texture (the paper's per-face one or the smoothed per-vertex one).

Attacks restricted to one object of a merged scene are the ordinary attacks of :mod:`meshadv.attacks` with a mask
hyper-parameter (``ShapeAttack(vertex_mask=...)``, ``TextureAttack(face_mask=...)``,
``SmoothTextureAttack(face_mask=...)``).
"""

from __future__ import annotations

from typing import Any, Optional

import torch

__all__ = ["check_smoothing", "object_attack", "texture_attack"]


def check_smoothing(texture_smoothing: Optional[int], perturbation: str) -> None:
    """Raise ValueError unless ``texture_smoothing`` is None, or an int >= 0 with ``perturbation == "texture"``."""
    if texture_smoothing is None:
        return
    if perturbation != "texture":
        raise ValueError("texture_smoothing applies to texture attacks only (perturbation='texture')")
    if isinstance(texture_smoothing, bool) or not isinstance(texture_smoothing, int) or texture_smoothing < 0:
        raise ValueError(f"texture_smoothing must be None or an int >= 0, got {texture_smoothing!r}")


def texture_attack(smoothing: Optional[int], face_mask: Optional[torch.Tensor], kwargs: dict[str, Any]) -> Any:
    """The paper's per-face texture attack (``smoothing`` None) or the smoothed per-vertex one."""
    from meshadv.attacks import SmoothTextureAttack, TextureAttack

    if smoothing is None:
        return TextureAttack(face_mask=face_mask, **kwargs)
    return SmoothTextureAttack(smoothing=smoothing, face_mask=face_mask, **kwargs)


def object_attack(perturbation: str, smoothing: Optional[int], kwargs: dict[str, Any],
                   mask: Optional[torch.Tensor] = None) -> Any:
    """The attack of a black-box run: a texture attack (:func:`texture_attack`, ``mask`` its face mask) or a
    ``ShapeAttack`` (``mask`` its vertex mask); ``mask`` None: the whole mesh may change."""
    from meshadv.attacks import ShapeAttack

    if perturbation == "texture":
        return texture_attack(smoothing, mask, kwargs)
    return ShapeAttack(**kwargs) if mask is None else ShapeAttack(vertex_mask=mask, **kwargs)
