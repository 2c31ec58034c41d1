"""The unit direction of the NMR spherical camera convention, in one place.

``direction(az, el) = (cos(el) sin(az), sin(el), -cos(el) cos(az))`` (angles in degrees, Y up): the eye of a
spherical camera at distance ``d`` is ``d * direction``, and the same formula places lights and suns. Works on
Python floats (returns a tuple), NumPy arrays and torch tensors (differentiable; the last axis holds x, y, z).

Example:
    >>> [round(c, 6) for c in spherical_direction(0.0, 0.0)]
    [0.0, 0.0, -1.0]
    >>> [round(c, 6) + 0.0 for c in spherical_direction(90.0, 0.0)]
    [1.0, 0.0, 0.0]
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["spherical_direction"]


def spherical_direction(azimuth: Any, elevation: Any, *, degrees: bool = True) -> Any:
    """``(cos(el) sin(az), sin(el), -cos(el) cos(az))`` for floats, NumPy arrays or torch tensors.

    Args:
        azimuth: angle(s) about +Y, 0 = looking from -Z.
        elevation: angle(s) above the XZ plane.
        degrees: angles in degrees (else radians).

    Returns:
        A tuple of 3 floats for scalar inputs, else an array / tensor of shape ``(..., 3)``.
    """
    if hasattr(azimuth, "detach") or hasattr(elevation, "detach"):
        import torch

        az = torch.as_tensor(azimuth)
        el = torch.as_tensor(elevation, dtype=az.dtype if az.is_floating_point() else None)
        if degrees:
            az, el = torch.deg2rad(az), torch.deg2rad(el)
        return torch.stack([torch.cos(el) * torch.sin(az), torch.sin(el), -torch.cos(el) * torch.cos(az)], dim=-1)
    if hasattr(azimuth, "shape") or hasattr(elevation, "shape"):
        import numpy as np

        az, el = np.asarray(azimuth, dtype=float), np.asarray(elevation, dtype=float)
        if degrees:
            az, el = np.radians(az), np.radians(el)
        return np.stack([np.cos(el) * np.sin(az), np.sin(el), -np.cos(el) * np.cos(az)], axis=-1)
    az, el = (math.radians(azimuth), math.radians(elevation)) if degrees else (azimuth, elevation)
    return (math.cos(el) * math.sin(az), math.sin(el), -math.cos(el) * math.cos(az))
