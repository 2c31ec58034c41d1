"""Conversions of the estimation's inputs: a mask, an image and a mesh's geometry as float tensors."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

__all__ = ["as_geometry", "as_image", "as_mask"]


def as_mask(mask: Any, name: str = "mask") -> torch.Tensor:
    """(H, W) float32 tensor in [0, 1] from an array / tensor of shape (H, W), (1, H, W) or (1, 1, H, W).

    Raises:
        ValueError: another shape, or values that are not finite (``name`` in the message).
    """
    t = torch.as_tensor(np.asarray(mask.detach().cpu() if hasattr(mask, "detach") else mask), dtype=torch.float32)
    while t.dim() > 2 and t.shape[0] == 1:
        t = t[0]
    if t.dim() != 2:
        raise ValueError(f"{name} must have shape (H, W), got {tuple(t.shape)}")
    if not bool(torch.isfinite(t).all()):
        raise ValueError(f"{name} contains NaN or Inf")
    return t.clamp(0.0, 1.0)


def as_image(image: Any, name: str = "image") -> torch.Tensor:
    """(3, H, W) float32 tensor from an array / tensor of shape (3, H, W), (H, W, 3) or (1, 3, H, W).

    Raises:
        ValueError: another shape (``name`` in the message).
    """
    img = torch.as_tensor(np.asarray(image.detach().cpu() if hasattr(image, "detach") else image), dtype=torch.float32)
    if img.dim() == 4 and img.shape[0] == 1:
        img = img[0]
    if img.dim() == 3 and img.shape[-1] == 3 and img.shape[0] != 3:
        img = img.permute(2, 0, 1)
    if img.dim() != 3 or img.shape[0] != 3:
        raise ValueError(f"{name} must have shape (3, H, W) or (H, W, 3), got {tuple(img.shape)}")
    return img


def as_geometry(vertices: Any, faces: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """``(N, 3)`` float32 vertices (detached: the estimation never changes the mesh) and ``(M, 3)`` int64 faces.

    Raises:
        ValueError: ``vertices`` or ``faces`` does not have shape ``(N, 3)`` / ``(M, 3)`` with ``M > 0``.
    """
    verts = torch.as_tensor(vertices, dtype=torch.float32).detach()
    faces_t = torch.as_tensor(faces, dtype=torch.int64)
    if verts.dim() != 2 or verts.shape[1] != 3:
        raise ValueError(f"vertices must have shape (N, 3), got {tuple(verts.shape)}")
    if faces_t.dim() != 2 or faces_t.shape[1] != 3 or faces_t.shape[0] == 0:
        raise ValueError(f"faces must have shape (M, 3) with M > 0, got {tuple(faces_t.shape)}")
    return verts, faces_t
