"""Masks of the attacks: which vertices (shape) or faces (texture) may change, as hyper-parameters.

A mask is a 1-D bool tensor over the mesh's vertices or faces; ``None`` means everything may change. The attack
shows it in ``config()`` as the sorted list of selected indices and the mask's length, so a record says exactly
what was allowed to move.
"""

from __future__ import annotations

from typing import Any, Dict, Optional

import torch
from torch import Tensor

__all__ = ["check_mask", "mask_config", "check_mask_fits"]


def check_mask(mask: Any, name: str, element: str) -> Optional[Tensor]:
    """Validate an attack mask at construction.

    Args:
        mask: ``None`` or a 1-D bool tensor.
        name: the argument's name (for messages).
        element: what it selects (``"vertex"`` or ``"face"``).

    Returns:
        The mask (detached, on the CPU) or ``None``.

    Raises:
        TypeError: not a tensor.
        ValueError: not bool, not 1-D, or selects nothing.
    """
    if mask is None:
        return None
    if not isinstance(mask, Tensor):
        raise TypeError(f"{name} must be None or a 1-D bool tensor, got {type(mask).__name__}")
    if mask.dtype != torch.bool:
        raise ValueError(f"{name} must be a 1-D bool tensor, got dtype {mask.dtype}")
    if mask.dim() != 1:
        raise ValueError(f"{name} must be a 1-D bool tensor, got shape {tuple(mask.shape)}")
    if not bool(mask.any()):
        raise ValueError(f"{name} selects no {element}")
    return mask.detach().cpu()


def check_mask_fits(mask: Optional[Tensor], name: str, count: int, element: str) -> None:
    """Raise ``ValueError`` when ``mask`` does not have one entry per mesh ``element`` (``count`` of them)."""
    if mask is not None and mask.shape[0] != count:
        raise ValueError(f"{name} has {mask.shape[0]} entries for a mesh of {count} {element}")


def mask_config(mask: Optional[Tensor]) -> Optional[Dict[str, Any]]:
    """JSON-able form of a mask: ``{"size": n, "indices": [...]}`` or ``None``."""
    if mask is None:
        return None
    return {"size": int(mask.shape[0]), "indices": torch.nonzero(mask).flatten().tolist()}
