"""Sets of views (one camera and one light set per view) used by attacks and experiments."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from ._checks import require_instance
from .camera import Camera, TensorLike
from .lighting import Lights

__all__ = ["ViewSet", "frame_distance"]

_SPHERICAL_KEYS = ("distance", "azimuth", "elevation")
_LOOK_AT_KEYS = ("eye", "at", "up")


@dataclass(frozen=True)
class ViewSet:
    """``B`` views of a scene: a camera batch and a light batch of the same size.

    Args:
        camera: cameras of batch B.
        lights: lights of batch B or 1 (broadcast to B).

    Raises:
        ValueError: the batch sizes differ (and lights is not of batch 1).

    Example:
        >>> views = ViewSet.orbit([0.0, 90.0, 180.0], elevation=20.0, distance=2.7)
        >>> len(views), len(views[1:])
        (3, 2)
    """

    camera: Camera
    lights: Lights

    def __post_init__(self) -> None:
        require_instance(self.camera, Camera, "camera")
        require_instance(self.lights, Lights, "lights")
        b, bl = len(self.camera), len(self.lights)
        if bl != b:
            if bl != 1:
                raise ValueError(f"lights batch size {bl} does not match the camera batch size {b}")
            lights = self.lights
            object.__setattr__(
                self,
                "lights",
                Lights(
                    lights.directions.expand(b, -1, -1),
                    lights.colors.expand(b, -1, -1),
                    lights.ambient.expand(b, -1),
                ),
            )

    def __len__(self) -> int:
        return len(self.camera)

    @staticmethod
    def require(views: Any, name: str = "views") -> ViewSet:
        """``views`` itself when it is a :class:`ViewSet` (an argument's check, naming it ``name``; a ViewSet always
        holds at least one view: its camera rejects an empty batch).

        Raises:
            TypeError: ``views`` is not a ViewSet.
        """
        if not isinstance(views, ViewSet):
            raise TypeError(f"{name} must be a meshadv.render.ViewSet (e.g. ViewSet.orbit(...)), "
                            f"got {type(views).__name__}")
        return views

    def __getitem__(self, index: int | slice | torch.Tensor | Sequence[int]) -> ViewSet:
        """Select views; an integer gives a ViewSet of one view."""
        return ViewSet(self.camera[index], self.lights[index])

    @staticmethod
    def cat(views: Sequence[ViewSet]) -> ViewSet:
        """Concatenate view sets (same camera kind and number of lights)."""
        views = list(views)
        if not views:
            raise ValueError("views must be a non-empty sequence")
        return ViewSet(Camera.cat([v.camera for v in views]), Lights.cat([v.lights for v in views]))

    def to(self, device: str | torch.device | None = None, dtype: torch.dtype | None = None) -> ViewSet:
        """Move to ``device`` and/or cast to ``dtype``."""
        return ViewSet(self.camera.to(device, dtype), self.lights.to(device, dtype))

    def detach(self) -> ViewSet:
        """A copy without autograd history."""
        return ViewSet(self.camera.detach(), self.lights.detach())

    @classmethod
    def orbit(
        cls,
        azimuths: TensorLike,
        elevation: TensorLike = 0.0,
        distance: TensorLike = 2.732,
        tilt: TensorLike = 0.0,
        viewing_angle: TensorLike = 30.0,
        lights: Lights | None = None,
        near: TensorLike = 0.1,
        far: TensorLike = 100.0,
    ) -> ViewSet:
        """Views on a circle of azimuths around the origin.

        Args:
            azimuths: (B,) azimuths in degrees.
            elevation: scalar or (B,) elevation in degrees.
            distance: scalar or (B,) camera distance (2.732 is NMR's default).
            tilt: scalar or (B,) roll in degrees.
            viewing_angle: scalar or (B,) field of view in degrees.
            lights: lights of batch 1 or B; default ``Lights.default(camera)`` (a head light per view).
            near: near clipping depth.
            far: far clipping depth.

        Returns:
            A ViewSet of B views.
        """
        az = azimuths if isinstance(azimuths, torch.Tensor) else torch.as_tensor(azimuths, dtype=torch.float32)
        camera = Camera.spherical(distance, az.reshape(-1), elevation, tilt, viewing_angle, near, far)
        return cls(camera, lights if lights is not None else Lights.default(camera))

    def jitter(
        self,
        generator: torch.Generator,
        *,
        azimuth: float = 0.0,
        elevation: float = 0.0,
        distance: float = 0.0,
        tilt: float = 0.0,
        light_direction: float = 0.0,
        light_intensity: float = 0.0,
    ) -> ViewSet:
        """Randomly perturbed copy of the views (for expectation-over-transformation attacks).

        Angles get uniform noise in ``[-x, x]`` degrees, distance a relative factor ``1 + U[-x, x]``; light directions
        get Gaussian noise of standard deviation ``light_direction`` (relative to their length) and light colours and
        ambient a factor ``1 + U[-x, x]``. Only spherical cameras can be jittered in angle.

        Args:
            generator: torch random generator (CPU), for reproducibility.
            azimuth: maximum azimuth offset (degrees).
            elevation: maximum elevation offset (degrees).
            distance: maximum relative change of distance.
            tilt: maximum tilt offset (degrees).
            light_direction: relative standard deviation of the light direction noise.
            light_intensity: maximum relative change of light colours and ambient.

        Returns:
            A new ViewSet (the original is unchanged); the noise is detached, parameters keep their autograd history.

        Raises:
            ValueError: negative magnitudes, or angle jitter on a look-at camera.
        """
        mags = {
            "azimuth": azimuth,
            "elevation": elevation,
            "distance": distance,
            "tilt": tilt,
            "light_direction": light_direction,
            "light_intensity": light_intensity,
        }
        for name, value in mags.items():
            if not value >= 0:
                raise ValueError(f"{name} jitter must be >= 0, got {value}")
        cam, lights, b = self.camera, self.lights, len(self)

        def uniform(shape: Sequence[int], mag: float) -> torch.Tensor:
            noise = (torch.rand(*shape, generator=generator) * 2 - 1) * mag
            return noise.to(dtype=cam.dtype, device=cam.device)

        # the noise is drawn in this order (tilt, distance, azimuth, elevation): keyword arguments run left to right
        if cam.is_spherical:
            new_cam = replace(
                cam,
                tilt=cam.tilt + uniform((b,), tilt),
                distance=cam.distance * (1 + uniform((b,), distance)),
                azimuth=cam.azimuth + uniform((b,), azimuth),
                elevation=cam.elevation + uniform((b,), elevation),
            )
        else:
            if azimuth or elevation or distance:
                raise ValueError("azimuth/elevation/distance jitter needs a spherical camera")
            new_cam = replace(cam, tilt=cam.tilt + uniform((b,), tilt))
        dirs = lights.directions
        if light_direction > 0:
            noise = torch.randn(*dirs.shape, generator=generator).to(dirs.dtype) * light_direction
            dirs = dirs + noise.to(dirs.device) * dirs.detach().norm(dim=-1, keepdim=True)
        k = lights.num_lights
        color_scale = 1 + uniform((b, k, 1), light_intensity).to(lights.colors.dtype)
        amb_scale = 1 + uniform((b, 1), light_intensity).to(lights.ambient.dtype)
        return ViewSet(new_cam, Lights(dirs, lights.colors * color_scale, lights.ambient * amb_scale))

    def to_records(self) -> list[dict[str, Any]]:
        """One JSON-able dict per view.

        Keys: ``distance, azimuth, elevation, tilt, viewing_angle, light_directions (K x 3), light_colors (K x 3),
        ambient (3)`` for spherical cameras; look-at cameras store ``eye, at, up`` instead of the three spherical keys.
        All records also carry ``near``, ``far``, ``orthographic`` and ``ortho_scale``.
        """
        cam, lights = self.camera.detach(), self.lights.detach()
        records = []
        for i in range(len(self)):
            rec: dict[str, Any] = {}
            if cam.is_spherical:
                rec.update(
                    distance=float(cam.distance[i]),
                    azimuth=float(cam.azimuth[i]),
                    elevation=float(cam.elevation[i]),
                )
            else:
                rec.update(eye=cam.eye_position[i].tolist(), at=cam.at[i].tolist(), up=cam.up[i].tolist())
            rec.update(
                tilt=float(cam.tilt[i]),
                viewing_angle=float(cam.viewing_angle[i]),
                near=float(cam.near[i]),
                far=float(cam.far[i]),
                orthographic=bool(cam.orthographic),
                ortho_scale=float(cam.ortho_scale[i]),
                light_directions=lights.directions[i].tolist(),
                light_colors=lights.colors[i].tolist(),
                ambient=lights.ambient[i].tolist(),
            )
            records.append(rec)
        return records

    @classmethod
    def from_records(cls, records: Sequence[dict[str, Any]]) -> ViewSet:
        """Rebuild a ViewSet from :meth:`to_records` output (float32 tensors).

        Raises:
            ValueError: empty input, missing keys, or a mix of spherical and look-at records.
        """
        records = list(records)
        if not records:
            raise ValueError("records must be a non-empty sequence")
        views = []
        for i, rec in enumerate(records):
            missing = [k for k in ("light_directions", "light_colors", "ambient") if k not in rec]
            if missing:
                raise ValueError(f"records[{i}] is missing keys {missing}")
            common = {
                "tilt": rec.get("tilt", 0.0),
                "viewing_angle": rec.get("viewing_angle", 30.0),
                "near": rec.get("near", 0.1),
                "far": rec.get("far", 100.0),
                "orthographic": bool(rec.get("orthographic", False)),
                "ortho_scale": rec.get("ortho_scale", 1.0),
            }
            if all(k in rec for k in _SPHERICAL_KEYS):
                camera = Camera.spherical(rec["distance"], rec["azimuth"], rec["elevation"], **common)
            elif all(k in rec for k in _LOOK_AT_KEYS):
                camera = Camera.look_at(rec["eye"], rec["at"], rec["up"], **common)
            else:
                raise ValueError(f"records[{i}] needs either {_SPHERICAL_KEYS} or {_LOOK_AT_KEYS}")
            dirs = torch.as_tensor(rec["light_directions"], dtype=torch.float32).reshape(-1, 3)
            cols = torch.as_tensor(rec["light_colors"], dtype=torch.float32).reshape(-1, 3)
            views.append(cls(camera, Lights(dirs, cols, torch.as_tensor(rec["ambient"], dtype=torch.float32))))
        return cls.cat(views)


def frame_distance(vertices: np.ndarray, to_eye: np.ndarray, fill: float, viewing_angle: float) -> float:
    """Camera distance at which the mesh's widest projected half-extent is exactly ``fill`` of the half view.

    With the NMR look-at basis ``(x, y, z)`` of a camera on the unit direction ``to_eye`` (up = +Y), a vertex with view
    coordinates ``(a, b, c)`` relative to the origin projects to ``a / ((d + c) tan(fov / 2))``, so the distance is
    ``max_i(max(|a_i|, |b_i|) / (fill tan(fov / 2)) - c_i)`` (exact for the perspective camera).

    Args:
        vertices: ``(N, 3)`` world-space vertices (object centred at the origin).
        to_eye: unit vector from the origin toward the camera.
        fill: wanted half-extent in NDC, in ``(0, 1]``.
        viewing_angle: field of view in degrees.
    """
    z_axis = -to_eye
    up = np.array([0.0, 1.0, 0.0])
    x_axis = np.cross(up, z_axis)
    if np.linalg.norm(x_axis) < 1e-9:  # looking straight down or up: any horizontal x works
        x_axis = np.array([1.0, 0.0, 0.0])
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(z_axis, x_axis)
    a, b, c = vertices @ x_axis, vertices @ y_axis, vertices @ z_axis
    tan_half = math.tan(math.radians(viewing_angle) / 2.0)
    distance = float(np.max(np.maximum(np.abs(a), np.abs(b)) / (fill * tan_half) - c))
    return max(distance, float(np.max(-c)) + 0.5)  # keep every vertex well beyond the near plane
