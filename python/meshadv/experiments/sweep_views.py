"""The views a sweep attacks from: one-view records, the drawn rendering configurations and the multi-view sets.

Rendering configurations are drawn once from ``config_seed`` (so every mesh, victim and target sees the same
configurations): camera distance, azimuth and elevation uniform in their ranges, one directional light from the
camera side jittered by up to ``light_jitter`` degrees, light intensity and ambient uniform in their ranges. Each is a
one-view ``ViewSet`` record (``meshadv.render.ViewSet.from_records``). Meshes are normalised into ``[-1, 1]``, so
with a 30° field of view the camera must be about ``1 / tan(15°) + 1 ≈ 4.7`` away to keep the whole object in the
frame; the default distances (3.6 to 4.4) show it nearly whole and large.

A multi-view attack (Table 2) sees ``count`` views at random azimuths in its range and is evaluated on unseen views
drawn the same way; both come from one generator seeded by the attack seed, the count and the range, so every mesh,
victim and target of a cell gets the same views.
"""

from __future__ import annotations

import random
from typing import Any, Dict, List, Optional, Tuple

from meshadv.util.spherical import spherical_direction

__all__ = ["multiview_views", "rendering_configurations", "view_record"]


def view_record(distance: float, azimuth: float, elevation: float, *, viewing_angle: float = 30.0,
                light_azimuth: Optional[float] = None, light_elevation: Optional[float] = None,
                light_intensity: float = 0.6, ambient: float = 0.5) -> Dict[str, Any]:
    """One view as a ``ViewSet`` record: a spherical camera and one white directional light plus ambient.

    The light direction points from the surface toward the light (the contract's convention); by default the light
    sits at the camera.
    """
    la = azimuth if light_azimuth is None else light_azimuth
    le = elevation if light_elevation is None else light_elevation
    return {
        "distance": round(float(distance), 6),
        "azimuth": round(float(azimuth), 6),
        "elevation": round(float(elevation), 6),
        "tilt": 0.0,
        "viewing_angle": float(viewing_angle),
        "light_directions": [[round(v, 6) for v in spherical_direction(la, le)]],
        "light_colors": [[round(float(light_intensity), 6)] * 3],
        "ambient": [round(float(ambient), 6)] * 3,
    }


def rendering_configurations(render: Dict[str, Any]) -> List[Dict[str, Any]]:
    """Draw the ``render.configurations`` one-view records from ``render.config_seed`` (see module docstring)."""
    rng = random.Random(int(render["config_seed"]))
    out = []
    jitter = float(render["light_jitter"])
    for _ in range(int(render["configurations"])):
        az = rng.uniform(*render["azimuth"])
        el = rng.uniform(*render["elevation"])
        dist = rng.uniform(*render["distance"])
        out.append(view_record(dist, az, el, viewing_angle=float(render["viewing_angle"]),
                               light_azimuth=az + rng.uniform(-jitter, jitter),
                               light_elevation=min(89.0, max(-89.0, el + rng.uniform(-jitter, jitter))),
                               light_intensity=rng.uniform(*render["light_intensity"]),
                               ambient=rng.uniform(*render["ambient"])))
    return out


def multiview_views(multiview: Dict[str, Any], viewing_angle: float, seed: int, count: int,
                    azimuth_range: Tuple[float, float]) -> Tuple[List[Dict[str, Any]], List[Dict[str, Any]]]:
    """The ``count`` attacked views and the ``multiview.eval_views`` unseen views of one multi-view attack.

    Args:
        multiview: the sweep's ``[multiview]`` section (its ``distance``, ``elevation`` and ``eval_views``).
        viewing_angle: the camera's field of view in degrees.
        seed: the attack seed. count: the number of attacked views.
        azimuth_range: ``(low, high)`` degrees, as the file wrote them: they seed the generator as text, so ``45``
            and ``45.0`` draw different views.

    Returns:
        ``(views, unseen)`` as one-view records (:func:`view_record`), camera light, default intensities.
    """
    lo, hi = azimuth_range
    rng = random.Random(f"{seed}:{count}:{lo}:{hi}")
    views = [view_record(multiview["distance"], rng.uniform(lo, hi), multiview["elevation"],
                         viewing_angle=viewing_angle) for _ in range(int(count))]
    unseen = [view_record(multiview["distance"], rng.uniform(lo, hi), multiview["elevation"],
                          viewing_angle=viewing_angle) for _ in range(int(multiview["eval_views"]))]
    return views, unseen
