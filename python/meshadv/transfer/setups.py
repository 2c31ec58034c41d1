"""The hidden "real world" of a black-box experiment, what Mitsuba renders unknown to the attacker, and the two
black-box setups built from the shared data.

* :class:`HiddenScene`: plain numpy values (no torch, no Mitsuba); the Mitsuba scene of an object placed in it
  (:meth:`HiddenScene.spec`) and of the world without it (:meth:`HiddenScene.background_spec`).
* :func:`outdoor_classifier_setup`: an object (by default an aeroplane) flying in an outdoor-like world lit by a
  procedural sky and a sun (a directional light), seen by a hidden camera.
* :func:`indoor_detector_setup`: the indoor desk scene (``scenes/indoor/scene.xml``: desk, chair, the Stanford
  Bunny on the desk, floor, walls, an area light and a dim environment); the bunny is the attacked object.
* Scenes of several known objects merged into one mesh (:func:`merge_meshes`), where one object lies in it
  (:func:`object_range`) and what hides it (:func:`occlusion_mask`).
* :func:`base_scene_file`: a Mitsuba scene file to place a mesh in, by name or path.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Optional, Sequence

import numpy as np
import torch

from meshadv import _validate
from meshadv.data import require_shared_data
from meshadv.mesh import Mesh, load_mesh, normalize_mesh
from meshadv.render import render
from meshadv.scenes.indoor import load_indoor_scene
from meshadv.transfer.mitsuba_scene import outdoor_environment
from meshadv.transfer.mitsuba_spec import (
    MeshObject,
    MitsubaCamera,
    MitsubaLights,
    SceneSpec,
    as_mesh_object,
    as_numpy,
)
from meshadv.util.spherical import spherical_direction

if TYPE_CHECKING:
    from meshadv.render import ViewSet

__all__ = [
    "INDOOR_CAMERA", "NAMED_SCENES", "OUTDOOR_CAMERA", "HiddenScene", "IndoorSetup", "base_scene_file",
    "default_aeroplane", "indoor_detector_setup", "merge_meshes", "object_range", "occlusion_mask",
    "outdoor_classifier_setup", "scale_on_base",
]


#: The hidden camera of the outdoor setup (degrees; distance in object units): slightly below a flying airliner,
#: against the sky (EfficientNet-Lite0 says "airliner" with p = 0.8 for PASCAL3D+ aeroplane/01 here).
OUTDOOR_CAMERA = {"distance": 3.2, "azimuth": 120.0, "elevation": -5.0}

#: The hidden camera of the indoor setup: close to the scene file's own view, looking at the origin.
INDOOR_CAMERA = {"distance": 3.4, "azimuth": 145.0, "elevation": 24.0}


@dataclass(frozen=True)
class HiddenScene:
    """The hidden "real world" of a black-box experiment: what Mitsuba renders, unknown to the attacker.

    Attributes:
        camera: the true spherical camera (distance, azimuth, elevation in degrees).
        viewing_angle: field of view (assumed known to the attacker).
        lights: true directional lights + ambient (or None).
        environment: optional lat-long environment map (e.g.
            :func:`~meshadv.transfer.mitsuba_scene.outdoor_environment`).
        environment_scale: multiplier of ``environment``.
        ground: optional ground plane (height, colour).
        base_scene: optional Mitsuba scene file the object is placed in.
        base_exclude: shapes of the base scene to drop (the object it replaces).
        image_size: (H, W).
        spp: samples per pixel; max_depth: path depth.
        extra_objects: other meshes of the world (beside the object and the base scene).

    Raises:
        TypeError: ``camera`` is not a dict, one of its values (``distance``, ``azimuth``, ``elevation``, ``tilt``)
            is not a real number (a string, ``None``, a bool), an extra object is not a
            :class:`~meshadv.transfer.mitsuba_spec.MeshObject`, or a setting has the wrong type (checked by building the
            world's :class:`~meshadv.transfer.mitsuba_spec.SceneSpec`).
        ValueError: ``camera`` lacks one of ``distance``, ``azimuth``, ``elevation`` or has a value that is not
            finite; a bad ``viewing_angle``, ``image_size``, ``spp`` or ``max_depth``.
        FileNotFoundError: ``base_scene`` does not exist.
    """

    camera: dict[str, float]
    viewing_angle: float = 30.0
    lights: Optional[MitsubaLights] = None
    environment: Optional[np.ndarray] = None
    environment_scale: float = 1.0
    ground: Optional[tuple[float, tuple[float, float, float]]] = None
    base_scene: Optional[str] = None
    base_exclude: tuple[str, ...] = ()
    image_size: tuple[int, int] = (224, 224)
    spp: int = 64
    max_depth: int = 8
    extra_objects: tuple[MeshObject, ...] = field(default=())

    def __post_init__(self) -> None:
        if not isinstance(self.camera, Mapping):
            raise TypeError(f"camera must be a dict with distance, azimuth, elevation, "
                            f"got {type(self.camera).__name__}")
        missing = [k for k in ("distance", "azimuth", "elevation") if k not in self.camera]
        if missing:
            raise ValueError(f"camera must have the keys distance, azimuth, elevation; missing {missing}")
        for key in ("distance", "azimuth", "elevation", "tilt"):
            if key in self.camera:
                _validate.finite_float(f"camera[{key!r}]", self.camera[key])
        for i, obj in enumerate(self.extra_objects):
            if not isinstance(obj, MeshObject):
                raise TypeError(f"extra_objects[{i}] must be a MeshObject, got {type(obj).__name__}")
        self._scene((), self.base_exclude, 0)  # checks the rest now (image size, spp, depth, lights, base scene, ...)

    def mitsuba_camera(self) -> MitsubaCamera:
        """The true camera for Mitsuba."""
        c = self.camera
        return MitsubaCamera.spherical(c["distance"], c["azimuth"], c["elevation"], c.get("tilt", 0.0),
                                       self.viewing_angle)

    def spec(self, mesh: Any, *, seed: int = 0) -> SceneSpec:
        """The Mitsuba scene of ``mesh`` in this hidden world (the object first, then any extra objects)."""
        return self._scene((as_mesh_object(mesh),) + tuple(self.extra_objects), self.base_exclude, seed)

    def background_spec(self, exclude: Sequence[str] = (), *, seed: int = 0) -> SceneSpec:
        """The Mitsuba scene of this world without the attacker's objects: no object, no extra object, and the
        base-scene shapes ``exclude`` dropped as well as :attr:`base_exclude`.

        Rendered, it stands for a photo of the background taken without the object.
        """
        return self._scene((), tuple(self.base_exclude) + tuple(exclude), seed)

    def _scene(self, objects: tuple[MeshObject, ...], base_exclude: Sequence[str], seed: int) -> SceneSpec:
        """The scene of ``objects`` in this world (its camera, lights, environment, ground and base scene)."""
        return SceneSpec(
            objects=objects,
            camera=self.mitsuba_camera(),
            lights=self.lights,
            image_size=self.image_size,
            spp=self.spp,
            max_depth=self.max_depth,
            background=None,
            base_scene=self.base_scene,
            base_exclude=base_exclude,
            environment=self.environment,
            environment_scale=self.environment_scale,
            ground=self.ground,
            seed=seed,
        )


def merge_meshes(meshes: Sequence[Any]) -> Any:
    """One ``meshadv.mesh.Mesh`` holding all ``meshes``, in order (faces re-indexed).

    Args:
        meshes: meshes with ``vertices`` (N_i, 3), ``faces`` (M_i, 3) and ``face_colors`` (M_i, 3).

    Returns:
        The merged mesh (float32 vertices and colours, int64 faces); mesh ``i``'s rows are
        :func:`object_range` ``(meshes, i, ...)``.
    """
    verts, faces, colors, offset = [], [], [], 0
    for m in meshes:
        verts.append(torch.as_tensor(m.vertices, dtype=torch.float32))
        faces.append(torch.as_tensor(m.faces, dtype=torch.int64) + offset)
        colors.append(torch.as_tensor(m.face_colors, dtype=torch.float32))
        offset += int(m.vertices.shape[0])
    return Mesh(torch.cat(verts), torch.cat(faces), torch.cat(colors))


def object_range(objects: Sequence[Any], index: int, part: str = "faces") -> tuple[int, int]:
    """``(start, stop)``: the rows of object ``index``'s ``part`` (``"faces"`` or ``"vertices"``) in
    :func:`merge_meshes` of ``objects``.

    Example:
        >>> object_range([cube, sphere], 1, "vertices")  # (8, 8 + sphere's vertex count)  # doctest: +SKIP
    """
    start = sum(int(getattr(o, part).shape[0]) for o in objects[:index])
    return start, start + int(getattr(objects[index], part).shape[0])


def occlusion_mask(objects: Sequence[Any], index: int, views: ViewSet, image_size: Any) -> torch.Tensor:
    """Pixels where object ``index`` alone would be drawn but another of ``objects`` is in front of it.

    Args:
        objects: ``meshadv.mesh.Mesh`` objects in world space.
        index: the object of interest.
        views: a one-view ``ViewSet`` (the estimated view).
        image_size: int or (H, W).

    Returns:
        (H, W) float32, 1 where the object is occluded.

    Raises:
        ValueError: ``index`` out of range.
    """
    if not 0 <= index < len(objects):
        raise ValueError(f"index {index} out of range for {len(objects)} objects")
    merged = merge_meshes(objects)
    start, stop = object_range(objects, index)
    obj = objects[index]
    with torch.no_grad():
        scene = render(merged.vertices, merged.faces, merged.face_colors, views.camera, views.lights,
                       image_size).face_index[0]
        alone = render(obj.vertices, obj.faces, obj.face_colors, views.camera, views.lights, image_size).face_index[0]
    visible = (scene >= start) & (scene < stop)
    return ((alone >= 0) & ~visible).float()


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
        The :class:`~meshadv.transfer.setups.HiddenScene`.
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
    path = require_shared_data("pascal3d/aeroplane/01.ply")
    mesh, _ = normalize_mesh(load_mesh(path, default_color=(0.75, 0.75, 0.78)), z_up=True)
    return mesh


#: The shared scene files :func:`base_scene_file` knows by name.
NAMED_SCENES = {"indoor": "scenes/indoor/scene.xml", "living-room": "scenes/living-room/scene_mi3.xml"}


def base_scene_file(scene: str) -> Optional[str]:
    """The Mitsuba scene file to place a mesh in: ``None`` for ``"none"``, the shared scene of a name of
    :data:`NAMED_SCENES`, else ``scene`` itself when it is a file.

    Raises:
        ValueError: ``scene`` is neither a known name nor a file.
        FileNotFoundError: the shared data are missing.
    """
    if scene == "none":
        return None
    if scene in NAMED_SCENES:
        return str(require_shared_data(NAMED_SCENES[scene]))
    if not Path(scene).is_file():
        raise ValueError(f"scene {scene} is not none, {', '.join(NAMED_SCENES)} or a scene file")
    return scene
