"""A pinhole camera in meshadv's conventions, ready for Mitsuba (:class:`MitsubaCamera`): built from meshadv's
spherical or look-at cameras and view records, with NMR's view axes and projection. Plain numpy, no torch."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from meshadv import _validate
from meshadv.transfer._arrays import as_numpy, normalize
from meshadv.util.spherical import spherical_direction

if TYPE_CHECKING:
    from meshadv.render import Camera

__all__ = ["MitsubaCamera"]


@dataclass(frozen=True)
class MitsubaCamera:
    """A pinhole camera in meshadv's conventions, ready for Mitsuba.

    Attributes:
        eye: camera position (3,) in world space.
        target: the point looked at (3,).
        up: up vector (3,), before orthogonalisation (tilt already applied).
        viewing_angle: full horizontal field of view in degrees (NMR ``viewing_angle``).
        near: near clip distance.
        far: far clip distance.
    """

    eye: tuple[float, float, float]
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    viewing_angle: float = 30.0
    near: float = 0.1
    far: float = 100.0

    def __post_init__(self) -> None:
        for name in ("eye", "target", "up"):
            value = getattr(self, name)
            if isinstance(value, (str, bytes)) or len(value) != 3:
                raise ValueError(f"{name} must be 3 numbers, got {value!r}")
            for i, v in enumerate(value):
                _validate.finite_float(f"{name}[{i}]", v)
        for name in ("viewing_angle", "near", "far"):
            _validate.finite_float(name, getattr(self, name))
        if not 0.0 < self.viewing_angle < 180.0:
            raise ValueError(f"viewing_angle must be in (0, 180) degrees, got {self.viewing_angle}")
        if not 0.0 < self.near < self.far:
            raise ValueError(f"need 0 < near < far, got near={self.near}, far={self.far}")

    @classmethod
    def spherical(
        cls,
        distance: float,
        azimuth: float,
        elevation: float,
        tilt: float = 0.0,
        viewing_angle: float = 30.0,
        near: float = 0.1,
        far: float = 100.0,
    ) -> "MitsubaCamera":
        """A camera on a sphere around the origin, exactly as ``meshadv.render.Camera.spherical``.

        Args:
            distance: distance from the origin (> 0).
            azimuth: degrees; ``eye = d * (cos(el) sin(az), sin(el), -cos(el) cos(az))``.
            elevation: degrees.
            tilt: degrees; rotates the up vector about the viewing axis, counter-clockwise in the image.
            viewing_angle: full field of view in degrees.
            near: near clip distance.
            far: far clip distance.

        Raises:
            ValueError: ``distance`` is not positive.
        """
        if not distance > 0:
            raise ValueError(f"distance must be positive, got {distance}")
        eye = distance * np.array(spherical_direction(azimuth, elevation))
        up = _tilted_up(eye, np.zeros(3), np.array([0.0, 1.0, 0.0]), tilt)
        return cls(tuple(eye.tolist()), (0.0, 0.0, 0.0), tuple(up.tolist()), viewing_angle, near, far)

    @classmethod
    def from_camera(cls, camera: Camera, index: int = 0) -> "MitsubaCamera":
        """Build from view ``index`` of a ``meshadv.render.Camera`` (spherical or look-at, tilt applied).

        Raises:
            ValueError: the camera is orthographic or ``index`` is out of range.
        """
        if getattr(camera, "orthographic", False):
            raise ValueError("camera: orthographic cameras are not supported by the Mitsuba conversion")
        if not 0 <= index < len(camera):
            raise ValueError(f"index {index} out of range for a camera batch of {len(camera)}")
        eye = as_numpy(camera.eye()[index], np.float64)
        target = as_numpy(camera.target()[index], np.float64)
        up = as_numpy(camera.rotation()[index, 1], np.float64)
        return cls(
            tuple(eye.tolist()),
            tuple(target.tolist()),
            tuple(up.tolist()),
            float(camera.viewing_angle[index]),
            float(camera.near[index]),
            float(camera.far[index]),
        )

    @classmethod
    def from_record(cls, record: Mapping[str, Any]) -> "MitsubaCamera":
        """Build from a ``ViewSet.to_records()`` record.

        Spherical records have keys distance, azimuth, elevation; look-at records have eye, at, up; both may have
        tilt, viewing_angle, near, far.

        Raises:
            ValueError: required keys are missing, or the record is orthographic.
        """
        if record.get("orthographic", False):
            raise ValueError("record: orthographic cameras are not supported by the Mitsuba conversion")
        if all(k in record for k in ("eye", "at", "up")):
            eye, at = as_numpy(record["eye"], np.float64), as_numpy(record["at"], np.float64)
            up = _tilted_up(eye, at, as_numpy(record["up"], np.float64), float(record.get("tilt", 0.0)))
            return cls(tuple(eye.tolist()), tuple(at.tolist()), tuple(up.tolist()), *_lens(record))
        missing = [k for k in ("distance", "azimuth", "elevation") if k not in record]
        if missing:
            raise ValueError(f"record is missing camera keys {missing} (or eye, at, up)")
        return cls.spherical(float(record["distance"]), float(record["azimuth"]), float(record["elevation"]),
                             float(record.get("tilt", 0.0)), *_lens(record))

    def view_axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """NMR's view axes ``(x, y, z)``: x is image right, y image up, z the viewing direction."""
        eye, target, up = (np.asarray(v, dtype=np.float64) for v in (self.eye, self.target, self.up))
        z = normalize(target - eye)
        x = normalize(np.cross(up, z))
        y = normalize(np.cross(z, x))
        return x, y, z

    def project(self, points_world: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
        """Project world points to pixel coordinates ``(column, row)`` (floats, pixel centres at ``k + 0.5``).

        Args:
            points_world: (P, 3) points.
            image_size: (H, W).

        Returns:
            (P, 2) array of (column, row) positions.
        """
        x, y, z = self.view_axes()
        rel = np.asarray(points_world, dtype=np.float64) - np.asarray(self.eye)
        view = np.stack([rel @ x, rel @ y, rel @ z], axis=-1)
        width = math.tan(math.radians(self.viewing_angle) / 2)
        x_ndc = view[:, 0] / (view[:, 2] * width)
        y_ndc = view[:, 1] / (view[:, 2] * width)
        h, w = image_size
        return np.stack([(x_ndc + 1) * w / 2, (1 - y_ndc) * h / 2], axis=-1)


def _lens(record: Mapping[str, Any]) -> tuple[float, float, float]:
    """``viewing_angle``, ``near`` and ``far`` of a view record (defaults 30 degrees, 0.1, 100)."""
    return float(record.get("viewing_angle", 30.0)), float(record.get("near", 0.1)), float(record.get("far", 100.0))


def _tilted_up(eye: np.ndarray, target: np.ndarray, up: np.ndarray, tilt: float) -> np.ndarray:
    """Rotate ``up`` about the viewing axis by ``tilt`` degrees, counter-clockwise in the image."""
    if tilt == 0.0:
        return up.astype(np.float64)
    z = normalize(target - eye)
    x = normalize(np.cross(up, z))
    y = np.cross(z, x)
    t = math.radians(tilt)
    # Image up (0, 1) rotated counter-clockwise by t is (-sin t, cos t) in image (right, up) coordinates.
    return math.cos(t) * y - math.sin(t) * x
