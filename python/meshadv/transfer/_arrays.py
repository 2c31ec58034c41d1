"""Numpy helpers of the scene values (:mod:`meshadv.transfer.spec`); torch-free, as the rendering child is."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["as_numpy", "normalize"]


def as_numpy(value: Any, dtype: Any = np.float32) -> np.ndarray:
    """Convert a tensor, list or array to a numpy array of ``dtype`` (detached, on the CPU)."""
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    return np.asarray(value, dtype=dtype)


def normalize(v: np.ndarray) -> np.ndarray:
    """``v`` divided by its length; raise ValueError for a zero vector."""
    norm = float(np.linalg.norm(v))
    if norm < 1e-12:
        raise ValueError("cannot normalise a zero vector (camera eye equals target, or up is parallel to the view)")
    return v / norm

