"""Views a person would also look from: between and away from the views an attack optimised.

:func:`held_out_views` derives them from the attack's views alone (so every result of the same views is judged on
the same ones): the azimuths half-way between neighbouring attack views, views :data:`AWAY_AZIMUTH` degrees beyond
both ends of their azimuth range, and views :data:`AWAY_ELEVATION` degrees above and below their mean elevation at
their mean azimuth. Spherical cameras get a head light per view (``Lights.default``); look-at cameras (scenes) are
turned about their ``up`` axis around the point they look at and keep the first view's lights.

Example:
    >>> from meshadv.render import ViewSet
    >>> held = held_out_views(ViewSet.orbit([150.0, 180.0, 210.0], elevation=30.0))
    >>> [round(float(a)) for a in held.camera.azimuth]
    [165, 195, 120, 240, 180, 180]
    >>> [round(float(e)) for e in held.camera.elevation]
    [30, 30, 30, 30, 50, 10]
"""

from __future__ import annotations

import math

import torch

from meshadv.render import Camera, Lights, ViewSet

__all__ = ["held_out_views", "AWAY_AZIMUTH", "AWAY_ELEVATION"]

#: Degrees beyond either end of the attack views' azimuth range.
AWAY_AZIMUTH = 30.0
#: Degrees above and below the attack views' mean elevation.
AWAY_ELEVATION = 20.0
#: Highest elevation of a held-out view (degrees).
_MAX_ELEVATION = 80.0


def _spherical(views: ViewSet) -> ViewSet:
    cam = views.camera.detach()
    assert cam.azimuth is not None and cam.elevation is not None and cam.distance is not None
    azimuths = torch.sort(cam.azimuth.double()).values
    lo, hi = float(azimuths[0]), float(azimuths[-1])
    centre_az = (lo + hi) / 2.0
    elevation = float(cam.elevation.double().mean())
    between = [(float(a) + float(b)) / 2.0 for a, b in zip(azimuths[:-1], azimuths[1:]) if float(b) - float(a) > 1e-6]
    az = between + [lo - AWAY_AZIMUTH, hi + AWAY_AZIMUTH, centre_az, centre_az]
    up = min(elevation + AWAY_ELEVATION, _MAX_ELEVATION)
    down = max(elevation - AWAY_ELEVATION, -_MAX_ELEVATION)
    el = [elevation] * (len(between) + 2) + [up, down]
    camera = Camera.spherical(float(cam.distance.double().mean()), torch.tensor(az, dtype=torch.float32),
                              torch.tensor(el, dtype=torch.float32), viewing_angle=float(cam.viewing_angle[0]),
                              near=float(cam.near[0]), far=float(cam.far[0]), orthographic=cam.orthographic,
                              ortho_scale=float(cam.ortho_scale[0]))
    return ViewSet(camera, Lights.default(camera))


def _rotated(vector: torch.Tensor, axis: torch.Tensor, degrees: float) -> torch.Tensor:
    """``vector`` (3,) rotated by ``degrees`` about the unit ``axis`` (3,) (Rodrigues)."""
    theta = math.radians(degrees)
    return (vector * math.cos(theta) + torch.cross(axis, vector, dim=0) * math.sin(theta)
            + axis * torch.dot(axis, vector) * (1 - math.cos(theta)))


def _look_at(views: ViewSet) -> ViewSet:
    cam = views.camera.detach()
    assert cam.eye_position is not None and cam.at is not None and cam.up is not None
    eye, at, up = cam.eye_position[0].double(), cam.at[0].double(), cam.up[0].double()
    axis = up / up.norm()
    offset = eye - at
    side = torch.cross(axis, offset, dim=0)
    side = side / side.norm().clamp(min=1e-12)
    eyes = [at + _rotated(offset, axis, s * AWAY_AZIMUTH) for s in (-1.0, 1.0)]
    eyes += [at + _rotated(offset, side, s * AWAY_ELEVATION) for s in (1.0, -1.0)]
    camera = Camera.look_at(torch.stack(eyes).float(), at.float(), up.float(),
                            viewing_angle=float(cam.viewing_angle[0]), near=float(cam.near[0]), far=float(cam.far[0]),
                            orthographic=cam.orthographic, ortho_scale=float(cam.ortho_scale[0]))
    return ViewSet(camera, views.lights.detach()[0])


def held_out_views(views: ViewSet) -> ViewSet:
    """The held-out views of an attack optimised on ``views`` (see the module docstring).

    Args:
        views: the attack's views (spherical or look-at cameras).

    Returns:
        A ``ViewSet``: for spherical cameras ``V' + 4`` views (``V'`` the gaps between distinct attack azimuths), for
        look-at cameras 4 (the first view turned left, right, up and down).

    Raises:
        TypeError: ``views`` is not a ViewSet.
    """
    views = ViewSet.require(views)
    return _spherical(views) if views.camera.is_spherical else _look_at(views)
