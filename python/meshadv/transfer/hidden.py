"""The hidden "real world" of a black-box experiment: what Mitsuba renders, unknown to the attacker.

Plain numpy values (no torch, no Mitsuba): :class:`HiddenScene` gives the Mitsuba scene of an object placed in it
(:meth:`HiddenScene.spec`) and of the world without it (:meth:`HiddenScene.background_spec`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Optional, Sequence

import numpy as np

from meshadv import _validate
from meshadv.transfer.spec import MeshObject, MitsubaCamera, MitsubaLights, SceneSpec, as_mesh_object

__all__ = ["HiddenScene"]


@dataclass(frozen=True)
class HiddenScene:
    """The hidden "real world" of a black-box experiment: what Mitsuba renders, unknown to the attacker.

    Attributes:
        camera: the true spherical camera (distance, azimuth, elevation in degrees).
        viewing_angle: field of view (assumed known to the attacker).
        lights: true directional lights + ambient (or None).
        environment: optional lat-long environment map (e.g.
            :func:`~meshadv.transfer.environment.outdoor_environment`).
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
            :class:`~meshadv.transfer.spec.MeshObject`, or a setting has the wrong type (checked by building the
            world's :class:`~meshadv.transfer.spec.SceneSpec`).
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
