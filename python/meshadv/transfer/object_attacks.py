"""The attack of a black-box run: shape, or texture (the paper's per-face one or the smoothed per-vertex one).

Attacks restricted to one object of a merged scene are the ordinary attacks of :mod:`meshadv.attacks` with a mask
hyper-parameter (``ShapeAttack(vertex_mask=...)``, ``TextureAttack(face_mask=...)``,
``SmoothTextureAttack(face_mask=...)``).
"""

from __future__ import annotations

from typing import Any, Optional

import torch

from meshadv import _validate

__all__ = ["check_smoothing", "object_attack", "texture_attack"]


def check_smoothing(texture_smoothing: Optional[int], perturbation: str) -> None:
    """Check that ``texture_smoothing`` is None, or an int >= 0 with ``perturbation == "texture"``.

    Raises:
        TypeError: ``texture_smoothing`` is neither None nor an int.
        ValueError: it is negative, or given for a shape attack.
    """
    if texture_smoothing is None:
        return
    if perturbation != "texture":
        raise ValueError("texture_smoothing applies to texture attacks only (perturbation='texture')")
    _validate.non_negative_int("texture_smoothing", texture_smoothing)


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
