"""Held-out views of a scene attack: the scene seen from a few small, seeded changes it was never optimised on.

A detector that misses the table only from the one camera pixel-exactly has been fooled by a pattern of those
pixels. :func:`scene_held_out_views` derives ``count`` held-out views from a :class:`~meshadv.scenes.attack.SceneSetup`
and a seed:

* a rendered scene (no photo): the scene camera turned about its look-at point by a yaw of
  :data:`YAW_DEGREES` degrees (alternately to either side) and a pitch within ``+-`` :data:`PITCH_DEGREES`, and moved
  along its line of sight by a factor within ``1 +-`` :data:`DISTANCE_CHANGE`;
* an object inserted into a photo: the object's placement shifted on the photo by ``du, dv`` (fractions of the image
  width and height) within ``+-`` :data:`PLACEMENT_SHIFT` (the horizontal shift alternately to either side) and scaled
  by a factor within ``1 +-`` :data:`PLACEMENT_SCALE` about its centre. The photo stays where it is; the change is made
  by moving the camera the opposite way (the object shifted by ``t`` is the camera shifted by ``-t``; the object
  scaled by ``s`` about its centre ``c`` is the camera's eye and look-at point pulled towards ``c`` by ``1 / s``),
  which renders the same image under the photo's directional lights.

The same setup and seed give the same views. The lights are the scene's.

Example:
    >>> held = scene_held_out_views(setup, count=6, seed=0)          # doctest: +SKIP
    >>> len(held.views), held.kind, sorted(held.moves[0])            # doctest: +SKIP
    (6, 'camera', ['distance_scale', 'pitch_deg', 'yaw_deg'])
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Dict, List, Tuple

import torch

from meshadv import _validate
from meshadv.render import Camera, ViewSet

__all__ = ["SceneHeldOut", "scene_held_out_views", "DEFAULT_HELD_OUT_VIEWS", "YAW_DEGREES", "PITCH_DEGREES",
           "DISTANCE_CHANGE", "PLACEMENT_SHIFT", "PLACEMENT_SCALE"]

#: Held-out views of ``meshadv attack-scene`` by default.
DEFAULT_HELD_OUT_VIEWS = 6
#: ``(low, high)`` degrees of the yaw of a rendered scene's held-out camera about its look-at point.
YAW_DEGREES = (2.0, 5.0)
#: Largest pitch (degrees) of a rendered scene's held-out camera about its look-at point.
PITCH_DEGREES = 3.0
#: Largest relative change of a rendered scene's camera distance to its look-at point.
DISTANCE_CHANGE = 0.05
#: Largest shift of a photo object's placement, as a fraction of the image width (horizontal) and height (vertical).
PLACEMENT_SHIFT = 0.04
#: Largest relative change of a photo object's size.
PLACEMENT_SCALE = 0.1


@dataclass(frozen=True)
class SceneHeldOut:
    """The held-out views of a scene attack.

    Attributes:
        views: a ``ViewSet`` of the held-out look-at cameras under the scene's lights.
        kind: ``"camera"`` (a rendered scene: camera moves) or ``"placement"`` (a photo: object placements).
        moves: one JSON-able dict per view: ``yaw_deg``, ``pitch_deg``, ``distance_scale`` (camera) or ``shift_u``,
            ``shift_v``, ``scale`` (placement: fractions of the image width and height, and the size factor).
    """

    views: ViewSet
    kind: str
    moves: Tuple[Dict[str, float], ...]

    def to_record(self) -> Dict[str, Any]:
        """``{"kind", "moves", "views"}`` (the views as ``ViewSet.to_records``)."""
        return {"kind": self.kind, "moves": list(self.moves), "views": self.views.to_records()}


def _rotated(vector: torch.Tensor, axis: torch.Tensor, degrees: float) -> torch.Tensor:
    """``vector`` (3,) rotated by ``degrees`` about the unit ``axis`` (3,) (Rodrigues)."""
    theta = math.radians(degrees)
    return (vector * math.cos(theta) + torch.cross(axis, vector, dim=0) * math.sin(theta)
            + axis * torch.dot(axis, vector) * (1 - math.cos(theta)))


def _uniform(generator: torch.Generator, low: float, high: float) -> float:
    return low + (high - low) * float(torch.rand((), generator=generator, dtype=torch.float64))


def _camera_moves(setup: Any, count: int, generator: torch.Generator) -> Tuple[List[torch.Tensor],
                                                                                     List[torch.Tensor],
                                                                                     List[Dict[str, float]]]:
    cam = setup.camera
    eye, at = torch.tensor(cam.eye, dtype=torch.float64), torch.tensor(cam.at, dtype=torch.float64)
    up = torch.tensor(cam.up, dtype=torch.float64)
    axis = up / up.norm()
    eyes, moves = [], []
    for i in range(count):
        yaw = (-1.0 if i % 2 == 0 else 1.0) * _uniform(generator, *YAW_DEGREES)
        pitch = _uniform(generator, -PITCH_DEGREES, PITCH_DEGREES)
        scale = _uniform(generator, 1.0 - DISTANCE_CHANGE, 1.0 + DISTANCE_CHANGE)
        offset = _rotated(eye - at, axis, yaw)
        side = torch.cross(axis, offset, dim=0)
        offset = _rotated(offset, side / side.norm().clamp(min=1e-12), pitch)
        eyes.append(at + scale * offset)
        moves.append({"yaw_deg": yaw, "pitch_deg": pitch, "distance_scale": scale})
    return eyes, [at] * count, moves


def _object_centre(setup: Any) -> torch.Tensor:
    """World position of the centre of the attacked object's bounding box (float64 (3,))."""
    obj = setup.scene[setup.object_name]
    lo, hi = obj.mesh.bounds().double()
    centre = torch.cat([(lo + hi) / 2, torch.ones(1, dtype=torch.float64)])
    return (obj.transform.double() @ centre)[:3]


def _placement_moves(setup: Any, count: int, generator: torch.Generator) -> Tuple[List[torch.Tensor],
                                                                                        List[torch.Tensor],
                                                                                        List[Dict[str, float]]]:
    cam = setup.camera
    eye, at = torch.tensor(cam.eye, dtype=torch.float64), torch.tensor(cam.at, dtype=torch.float64)
    centre = _object_centre(setup)
    forward = (at - eye) / (at - eye).norm()
    right, true_up = cam.image_axes()
    depth = float(torch.dot(centre - eye, forward))
    pixel = 2.0 * depth * math.tan(math.radians(cam.fov) / 2.0) / cam.width  # world units per pixel at the object
    eyes, ats, moves = [], [], []
    for i in range(count):
        du = (-1.0 if i % 2 == 0 else 1.0) * _uniform(generator, 0.25 * PLACEMENT_SHIFT, PLACEMENT_SHIFT)
        dv = _uniform(generator, -PLACEMENT_SHIFT, PLACEMENT_SHIFT)
        scale = _uniform(generator, 1.0 - PLACEMENT_SCALE, 1.0 + PLACEMENT_SCALE)
        shift = (du * cam.width * pixel) * right - (dv * cam.height * pixel) * true_up  # v grows downwards
        eyes.append(centre + (eye - centre - shift) / scale)
        ats.append(centre + (at - centre - shift) / scale)
        moves.append({"shift_u": du, "shift_v": dv, "scale": scale})
    return eyes, ats, moves


def scene_held_out_views(setup: Any, count: int = DEFAULT_HELD_OUT_VIEWS, seed: int = 0) -> SceneHeldOut:
    """The held-out views of a scene attack on ``setup`` (see the module docstring).

    Args:
        setup: the attacked scene, a :class:`~meshadv.scenes.attack.SceneSetup` (a photo setup gets placement
            changes, any other camera moves).
        count: number of held-out views (at least 1).
        seed: seed of the draws (the same seed, the same views).

    Returns:
        A :class:`SceneHeldOut`.

    Raises:
        TypeError: ``setup`` is not a SceneSetup, or ``count`` / ``seed`` is not an integer.
        ValueError: ``count < 1`` or a negative ``seed``.
    """
    if not all(hasattr(setup, name) for name in ("scene", "object_name", "camera", "lights", "photo")):
        raise TypeError(f"setup must be a SceneSetup, got {type(setup).__name__}")
    count = _validate.positive_int("count", count)
    seed = _validate.seed("seed", seed)
    generator = torch.Generator().manual_seed(seed)
    kind = "camera" if setup.photo is None else "placement"
    eyes, ats, moves = (_camera_moves if kind == "camera" else _placement_moves)(setup, count, generator)
    cam = setup.camera
    camera = Camera.look_at(torch.stack(eyes).float(), torch.stack(ats).float(),
                            torch.tensor(cam.up, dtype=torch.float32), viewing_angle=cam.fov, near=cam.near,
                            far=cam.far)
    rounded = tuple({k: round(v, 6) for k, v in m.items()} for m in moves)
    return SceneHeldOut(ViewSet(camera, setup.lights), kind, rounded)
