"""Normalisation as in the paper: centre at the origin and scale into ``[-1, 1]``, optionally Z-up to Y-up.

The transform is kept (:class:`NormalizeTransform`) so adversarial vertices can be mapped back to the original
file's coordinates.

Z-up to Y-up is the rotation of -90 degrees about +X, ``(x, y, z) -> (x, z, -y)`` (the Blender-to-glTF
convention). For PASCAL3D+ models this means a PASCAL3D+ viewpoint ``(azimuth a, elevation e)`` (camera at
``d (cos e sin a, -cos e cos a, sin e)`` in the CAD frame) is seen by the renderer's spherical camera at
``azimuth = 180 - a`` and the same elevation (see :func:`pascal3d_azimuth_to_renderer`). The rotation keeps the
geometry's handedness; note that NMR-convention images are the horizontal mirror of a right-handed camera's view
(docs/ARCHITECTURE.md, "Handedness").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Union

import numpy as np
import torch

from meshadv import _validate
from meshadv.mesh.structure import Mesh

ArrayLike = Union[torch.Tensor, np.ndarray]

#: Rotation taking a Z-up model into the renderer's Y-up world: ``(x, y, z) -> (x, z, -y)``.
#: Largest accepted ``extent`` of :func:`normalize_mesh`; float32 vertices (max 3.4e38) stay far from overflow.
_MAX_EXTENT = 1e30
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def pascal3d_azimuth_to_renderer(azimuth: float) -> float:
    """Map a PASCAL3D+ annotation azimuth (degrees) to the renderer's azimuth for a mesh loaded with ``z_up=True``.

    Args:
        azimuth: PASCAL3D+ azimuth in degrees.

    Returns:
        The renderer azimuth in degrees, in ``[0, 360)``.
    """
    return float((180.0 - azimuth) % 360.0)


@dataclass(frozen=True)
class NormalizeTransform:
    """The similarity ``v_norm = scale * R (v - center)`` applied by :func:`normalize_mesh`.

    Attributes:
        center: ``(3,)`` float64, the bounding-box centre in original coordinates.
        scale: the uniform scale factor (positive).
        rotation: ``(3, 3)`` float64 rotation ``R`` (identity unless ``z_up``).
    """

    center: np.ndarray
    scale: float
    rotation: np.ndarray

    def _apply(
        self,
        points: ArrayLike,
        matrix: np.ndarray,
        shift_before: "np.ndarray | None",
        factor: float,
        shift_after: "np.ndarray | None",
    ) -> ArrayLike:
        if isinstance(points, torch.Tensor):
            p = points
            kw = {"dtype": p.dtype, "device": p.device}
            if shift_before is not None:
                p = p - torch.as_tensor(shift_before, **kw)
            p = (p @ torch.as_tensor(matrix.T, **kw)) * factor
            if shift_after is not None:
                p = p + torch.as_tensor(shift_after, **kw)
            return p
        arr = np.asarray(points)
        out = arr.astype(np.float64)
        if shift_before is not None:
            out = out - shift_before
        out = (out @ matrix.T) * factor
        if shift_after is not None:
            out = out + shift_after
        return out.astype(arr.dtype if np.issubdtype(arr.dtype, np.floating) else np.float64)

    def from_original(self, points: ArrayLike) -> ArrayLike:
        """Map points from the original coordinates to the normalised ones.

        Args:
            points: tensor or array of shape ``(..., 3)``; tensors keep autograd, dtype and device.
        """
        return self._apply(points, self.rotation, self.center, self.scale, None)

    def to_original(self, points: ArrayLike) -> ArrayLike:
        """Map points from normalised coordinates back to the original file's coordinates.

        Args:
            points: tensor or array of shape ``(..., 3)``; tensors keep autograd, dtype and device.
        """
        return self._apply(points, self.rotation.T, None, 1.0 / self.scale, self.center)

    def displacement_to_original(self, vectors: ArrayLike) -> ArrayLike:
        """Map displacement vectors (e.g. adversarial perturbations) to original coordinates (no translation)."""
        return self._apply(vectors, self.rotation.T, None, 1.0 / self.scale, None)

    def matrix(self) -> np.ndarray:
        """The ``(4, 4)`` homogeneous matrix of :meth:`from_original`."""
        m = np.eye(4)
        m[:3, :3] = self.scale * self.rotation
        m[:3, 3] = -self.scale * (self.rotation @ self.center)
        return m

    def to_dict(self) -> dict:
        """A JSON-able dict (inverse: :meth:`from_dict`)."""
        return {"center": self.center.tolist(), "scale": float(self.scale), "rotation": self.rotation.tolist()}

    @classmethod
    def from_dict(cls, data: dict) -> "NormalizeTransform":
        """Rebuild a transform written by :meth:`to_dict`.

        Raises:
            ValueError: missing keys or wrong shapes.
        """
        try:
            center = np.asarray(data["center"], dtype=np.float64)
            rotation = np.asarray(data["rotation"], dtype=np.float64)
            scale = float(data["scale"])
        except (KeyError, TypeError) as exc:
            raise ValueError(f"data must have center, scale and rotation, got {data!r}") from exc
        if center.shape != (3,) or rotation.shape != (3, 3) or not scale > 0:
            raise ValueError("data has wrong shapes: center (3,), rotation (3, 3), scale > 0 expected")
        return cls(center=center, scale=scale, rotation=rotation)


def normalize_mesh(mesh: Mesh, *, z_up: bool = False, extent: float = 1.0) -> "tuple[Mesh, NormalizeTransform]":
    """Centre the bounding box at the origin and scale the mesh uniformly into ``[-extent, extent]``.

    The largest half-extent becomes exactly ``extent`` (the paper's ``[-1, 1]``). With ``z_up`` the model is
    first rotated from Z-up (PASCAL3D+) into the renderer's Y-up world.

    Args:
        mesh: the mesh; gradients are not tracked through the normalisation.
        z_up: the mesh is Z-up; rotate it to Y-up.
        extent: half-size of the target cube.

    Returns:
        ``(normalised mesh, transform)``; ``transform.to_original`` maps vertices back.

    Raises:
        TypeError: ``mesh`` is not a :class:`Mesh`, ``extent`` not a real number or ``z_up`` not a bool.
        ValueError: ``extent`` is not positive and finite or exceeds ``1e30`` (float32 vertices would overflow),
            or the mesh is empty or a single point (no extent to scale).

    Example:
        >>> unit, tf = normalize_mesh(builtin_mesh("cube"))  # doctest: +SKIP
        >>> torch.allclose(tf.to_original(unit.vertices), cube.vertices, atol=1e-6)  # doctest: +SKIP
    """
    if not isinstance(mesh, Mesh):
        raise TypeError(f"mesh must be a Mesh, got {type(mesh).__name__}")
    extent = _validate.positive_float("extent", extent, high=_MAX_EXTENT)
    z_up = _validate.boolean("z_up", z_up)
    if mesh.num_vertices == 0:
        raise ValueError("mesh has no vertices; an empty mesh cannot be normalised")
    verts = mesh.vertices.detach().double().cpu().numpy()
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    center = (lo + hi) / 2.0
    rotation = Z_UP_TO_Y_UP.copy() if z_up else np.eye(3)
    half = float(np.abs(verts - center).max())
    if not half > 0:
        raise ValueError("mesh has zero extent (all vertices coincide); it cannot be normalised")
    transform = NormalizeTransform(center=center, scale=extent / half, rotation=rotation)
    new_verts = transform.from_original(verts)
    new_vertices = torch.as_tensor(new_verts, dtype=torch.float32).to(mesh.device)
    return mesh.detach().with_vertices(new_vertices), transform
