"""The paper's two black-box transfer setups, built from the shared data.

* :func:`outdoor_classifier_setup`: an object (the paper: an aeroplane) flying in an outdoor-like world lit by
  a procedural sky environment and a sun (a directional light), seen by a hidden camera.
* :func:`indoor_detector_setup`: the indoor desk scene (``scenes/indoor/scene.xml``: desk, chair, the Stanford Bunny
  on the desk, floor, walls, an area light and a dim environment); the bunny is the attacked object.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from meshadv import _validate
from meshadv.transfer._arrays import as_numpy
from meshadv.transfer.environment import outdoor_environment
from meshadv.transfer.hidden import HiddenScene
from meshadv.transfer.spec import MitsubaLights
from meshadv.util.spherical import spherical_direction

#: The hidden camera of the outdoor setup (degrees; distance in object units): slightly below a flying airliner,
#: against the sky (EfficientNet-Lite0 says "airliner" with p = 0.8 for PASCAL3D+ aeroplane/01 here).
OUTDOOR_CAMERA = {"distance": 3.2, "azimuth": 120.0, "elevation": -5.0}

#: The hidden camera of the indoor setup: close to the scene file's own view, looking at the origin.
INDOOR_CAMERA = {"distance": 3.4, "azimuth": 145.0, "elevation": 24.0}


def _sun(elevation: float, azimuth: float, strength: float) -> MitsubaLights:
    """One white directional light of colour ``strength`` from (``azimuth``, ``elevation``) degrees, no ambient."""
    direction = spherical_direction(azimuth, elevation)
    return MitsubaLights(np.array([direction]), np.full((1, 3), strength), np.zeros(3))


def outdoor_classifier_setup(
    mesh: Any,
    *,
    camera: Optional[dict[str, float]] = None,
    image_size: int = 224,
    spp: int = 64,
    sun_elevation: float = 50.0,
    sun_azimuth: float = 160.0,
    sun_strength: float = 0.6,
    sky_scale: float = 0.7,
    ground: bool = False,
) -> HiddenScene:
    """An outdoor-like hidden world for a classifier: sky environment light, a sun and optionally a ground plane.

    Args:
        mesh: the object (normalised into [-1, 1], Y up); the ground is placed just below it.
        camera: hidden camera (keys distance, azimuth, elevation); default :data:`OUTDOOR_CAMERA`.
        image_size: square image side.
        spp: Mitsuba samples per pixel.
        sun_elevation: degrees.
        sun_azimuth: degrees (meshadv's azimuth convention).
        sun_strength: the sun's colour in meshadv units (a white face facing it gets this much).
        sky_scale: multiplier of the sky's radiance.
        ground: put a ground plane just below the object (False: the object flies; the environment's lower half
            stands for the distant ground).

    Returns:
        The :class:`~meshadv.transfer.hidden.HiddenScene`.
    """
    verts = as_numpy(mesh.vertices)
    ground_y = float(verts[:, 1].min()) - 0.02
    env = outdoor_environment(height=64, sun_strength=0.0)
    return HiddenScene(
        camera=dict(camera or OUTDOOR_CAMERA),
        viewing_angle=30.0,
        lights=_sun(sun_elevation, sun_azimuth, sun_strength),
        environment=env,
        environment_scale=sky_scale,
        ground=(ground_y, (0.35, 0.33, 0.3)) if ground else None,
        image_size=(image_size, image_size),
        spp=spp,
        max_depth=6,
    )


@dataclass(frozen=True)
class IndoorSetup:
    """The indoor detector setup.

    Attributes:
        objects: desk, chair and bunny meshes in world space (what the attacker knows), in that order.
        object_index: the attacked object (the bunny, 2).
        hidden: the hidden world (the scene file with the bunny replaced by the attacker's object).
        background_exclude: base-scene shapes that are the known objects (dropped for the background render).
    """

    objects: tuple[Any, ...]
    object_index: int
    hidden: HiddenScene
    background_exclude: tuple[str, ...]


def indoor_detector_setup(
    scene_dir: Optional[Path] = None,
    *,
    camera: Optional[dict[str, float]] = None,
    image_size: int = 256,
    spp: int = 64,
    object_scale: float = 1.0,
) -> IndoorSetup:
    """The paper's indoor detection setup from ``scenes/indoor`` in the shared data.

    The known objects come from the one model of the indoor scene, :func:`meshadv.scenes.indoor.load_indoor_scene`
    (the desk, chair and bunny of ``scene.xml`` in world coordinates with their colours).

    Args:
        scene_dir: folder with ``scene.xml`` and ``meshes/`` (default: the shared data's ``scenes/indoor``).
        camera: hidden spherical camera; default :data:`INDOOR_CAMERA`.
        image_size: square image side.
        spp: Mitsuba samples per pixel.
        object_scale: scale of the attacked object (the bunny, 0.25 m tall in the scene file) about the centre of
            its base, so that it stays on the desk; > 0. The hidden world holds the scaled object too.

    Returns:
        The :class:`IndoorSetup`.

    Raises:
        FileNotFoundError: the scene is missing.
        TypeError: ``object_scale`` is not a number.
        ValueError: ``object_scale`` is not a positive finite number.
    """
    from meshadv.data import require_shared_data
    from meshadv.mesh import Mesh
    from meshadv.scenes.indoor import load_indoor_scene

    _validate.positive_float("object_scale", object_scale)
    root = Path(scene_dir) if scene_dir is not None else require_shared_data("scenes/indoor")
    xml = root / "scene.xml"
    if not xml.is_file():
        raise FileNotFoundError(f"scene_dir {root} has no scene.xml")
    scene = load_indoor_scene(root).scene
    objects = tuple(
        Mesh(scene[name].world_vertices().detach(), scene[name].mesh.faces, scene[name].mesh.face_colors)
        for name in ("desk", "chair", "bunny")
    )
    if object_scale != 1.0:
        objects = objects[:2] + (scale_on_base(objects[2], object_scale),)
    hidden = HiddenScene(
        camera=dict(camera or INDOOR_CAMERA),
        viewing_angle=45.0,
        lights=None,
        base_scene=str(xml),
        base_exclude=("bunny",),
        image_size=(image_size, image_size),
        spp=spp,
        max_depth=5,
    )
    return IndoorSetup(objects, 2, hidden, ("desk", "chair", "bunny"))


def scale_on_base(mesh: Any, scale: float) -> Any:
    """``mesh`` scaled by ``scale`` about the centre of the bottom of its bounding box (Y up): it keeps standing
    where it stood.

    Raises:
        TypeError: ``scale`` is not a number.
        ValueError: ``scale`` is not a positive finite number.
    """
    _validate.positive_float("scale", scale)
    lo, hi = mesh.bounds()
    pivot = (lo + hi) / 2
    pivot[1] = lo[1]
    return mesh.with_vertices((mesh.vertices - pivot) * scale + pivot)


def default_aeroplane() -> Any:
    """The first PASCAL3D+ aeroplane of the shared data (``pascal3d/aeroplane/01.ply``), normalised into [-1, 1]
    with Y up.

    Raises:
        FileNotFoundError: the shared data has no aeroplane.
    """
    from meshadv.data import require_shared_data
    from meshadv.mesh import load_mesh, normalize_mesh

    path = require_shared_data("pascal3d/aeroplane/01.ply")
    mesh, _ = normalize_mesh(load_mesh(path, default_color=(0.75, 0.75, 0.78)), z_up=True)
    return mesh


__all__ = [
    "INDOOR_CAMERA",
    "OUTDOOR_CAMERA",
    "IndoorSetup",
    "default_aeroplane",
    "indoor_detector_setup",
    "outdoor_classifier_setup",
    "scale_on_base",
]
