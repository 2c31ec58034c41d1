"""A procedural outdoor environment map (sky, sun, ground) for Mitsuba's ``envmap`` emitter."""

from __future__ import annotations

import math

import numpy as np

from meshadv import _validate
from meshadv.util.spherical import spherical_direction

__all__ = ["outdoor_environment"]


def outdoor_environment(
    height: int = 64,
    sun_elevation: float = 45.0,
    sun_azimuth: float = 30.0,
    sun_strength: float = 40.0,
    sky: tuple[float, float, float] = (0.45, 0.6, 0.9),
    horizon: tuple[float, float, float] = (0.9, 0.9, 0.85),
    ground: tuple[float, float, float] = (0.3, 0.27, 0.22),
) -> np.ndarray:
    """A simple procedural outdoor lat-long environment map (sky gradient, small sun, dark ground).

    Args:
        height: map height in pixels (width is twice that).
        sun_elevation: sun elevation in degrees.
        sun_azimuth: sun azimuth in degrees (meshadv's azimuth convention for a direction).
        sun_strength: radiance of the sun disc relative to the sky.
        sky: zenith colour.
        horizon: horizon colour.
        ground: colour below the horizon.

    Returns:
        (height, 2 * height, 3) float32 radiance, Mitsuba's lat-long layout (+Y up).

    Raises:
        TypeError: ``height`` is not an int.
        ValueError: ``height`` < 4.
    """
    _validate.integer("height", height, low=4)
    w = 2 * height
    theta = (np.arange(height) + 0.5) / height * math.pi  # 0 at +Y
    phi = (np.arange(w) + 0.5) / w * 2 * math.pi
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    # Mitsuba's envmap: direction = (sin(theta) sin(phi), cos(theta), -sin(theta) cos(phi)).
    dirs = np.stack([np.sin(th) * np.sin(ph), np.cos(th), -np.sin(th) * np.cos(ph)], axis=-1)
    up = np.clip(dirs[..., 1], -1, 1)
    t = np.clip(up, 0, 1)[..., None] ** 0.5
    env = (1 - t) * np.asarray(horizon) + t * np.asarray(sky)
    env = np.where(up[..., None] < 0, np.asarray(ground), env)
    sun = np.array(spherical_direction(sun_azimuth, sun_elevation))
    cos_angle = dirs @ sun
    env = env + sun_strength * (cos_angle > math.cos(math.radians(4.0)))[..., None]
    return env.astype(np.float32)
