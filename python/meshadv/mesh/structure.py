"""The in-memory triangle mesh used everywhere in meshadv.

Faces are stored as int64 (not the int32 of the file formats and of the native rasterizer) because PyTorch
indexing (``vertices[faces]``, ``index_add_``) wants int64; :attr:`Mesh.faces_int32` gives the rasterizer's type.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Union

import numpy as np
import torch

Device = Union[str, torch.device]


def bbox_diagonal(vertices: torch.Tensor) -> torch.Tensor:
    """Length of the axis-aligned bounding-box diagonal of ``(N, 3)`` vertices: a scalar tensor of their dtype.

    Raises:
        ValueError: ``vertices`` is not ``(N, 3)`` with ``N > 0``.

    Example:
        >>> float(bbox_diagonal(torch.tensor([[0.0, 0, 0], [3, 4, 0]])))
        5.0
    """
    if vertices.dim() != 2 or vertices.shape[1] != 3 or vertices.shape[0] == 0:
        raise ValueError(f"vertices must have shape (N, 3) with N > 0, got {tuple(vertices.shape)}")
    return (vertices.max(dim=0).values - vertices.min(dim=0).values).norm()


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh with one RGB reflectance per face.

    Equality is identity (tensors have no single truth value); compare fields with ``torch.equal``.

    Attributes:
        vertices: float32 tensor of vertex positions.
        faces: int64 tensor of vertex indices, one row per triangle, each in ``[0, N)``.
        face_colors: float32 tensor of per-face RGB reflectance, nominally in ``[0, 1]`` (not enforced so
            that attacks may carry unclamped parameters; :func:`meshadv.mesh.save_mesh` clamps the 8-bit
            copy it writes).

    Shape:
        vertices: ``(N, 3)``; faces: ``(M, 3)``; face_colors: ``(M, 3)``.

    Raises:
        ValueError: a field has the wrong shape, dtype or device, a vertex is NaN or infinite, or a face index is
            out of range.

    Example:
        >>> m = Mesh.from_numpy(np.eye(3), np.array([[0, 1, 2]]))
        >>> m.num_vertices, m.num_faces
        (3, 1)
    """

    vertices: torch.Tensor
    faces: torch.Tensor
    face_colors: torch.Tensor

    def __post_init__(self) -> None:
        v, f, c = self.vertices, self.faces, self.face_colors
        for name, t in (("vertices", v), ("faces", f), ("face_colors", c)):
            if not isinstance(t, torch.Tensor):
                raise ValueError(f"{name} must be a torch.Tensor, got {type(t).__name__}")
        if v.dim() != 2 or v.shape[1] != 3 or v.dtype != torch.float32:
            raise ValueError(f"vertices must be float32 (N, 3), got {v.dtype} {tuple(v.shape)}")
        if f.dim() != 2 or f.shape[1] != 3 or f.dtype != torch.int64:
            raise ValueError(f"faces must be int64 (M, 3), got {f.dtype} {tuple(f.shape)}")
        if c.dim() != 2 or c.shape[1] != 3 or c.dtype != torch.float32:
            raise ValueError(f"face_colors must be float32 (M, 3), got {c.dtype} {tuple(c.shape)}")
        if c.shape[0] != f.shape[0]:
            raise ValueError(f"face_colors has {c.shape[0]} rows but there are {f.shape[0]} faces")
        if not (v.device == f.device == c.device):
            raise ValueError(
                f"vertices, faces and face_colors must be on one device, got {v.device}, {f.device}, {c.device}"
            )
        finite = torch.isfinite(v.detach()).all(dim=1)
        if not bool(finite.all()):
            first = int(torch.nonzero(~finite)[0, 0])
            raise ValueError(
                f"vertices must be finite: {int((~finite).sum())} vertices hold NaN or infinite coordinates "
                f"(the first is vertex {first})"
            )
        if f.numel() > 0:
            lo, hi = int(f.min()), int(f.max())
            if lo < 0 or hi >= v.shape[0]:
                raise ValueError(
                    f"faces index out of range: indices span [{lo}, {hi}] but there are {v.shape[0]} vertices"
                )

    @classmethod
    def from_numpy(
        cls,
        vertices: np.ndarray,
        faces: np.ndarray,
        face_colors: "np.ndarray | None" = None,
        *,
        default_color: "tuple[float, float, float]" = (0.7, 0.7, 0.7),
    ) -> "Mesh":
        """Build a mesh from array-likes, converting dtypes.

        Args:
            vertices: ``(N, 3)`` positions.
            faces: ``(M, 3)`` integer vertex indices.
            face_colors: ``(M, 3)`` RGB in ``[0, 1]``; ``None`` paints every face ``default_color``.
            default_color: colour used when ``face_colors`` is ``None``.

        Returns:
            A CPU :class:`Mesh`.

        Raises:
            ValueError: shapes do not match or an index is out of range.
        """
        v = torch.as_tensor(np.ascontiguousarray(vertices, dtype=np.float32))
        f = torch.as_tensor(np.ascontiguousarray(faces, dtype=np.int64))
        if f.dim() == 1 and f.numel() == 0:
            f = f.reshape(0, 3)
        if face_colors is None:
            if len(default_color) != 3:
                raise ValueError(f"default_color must have 3 components, got {default_color!r}")
            c = torch.tensor(default_color, dtype=torch.float32).expand(f.shape[0], 3).contiguous()
        else:
            c = torch.as_tensor(np.ascontiguousarray(face_colors, dtype=np.float32))
        return cls(v, f, c)

    @property
    def num_vertices(self) -> int:
        """Number of vertices ``N``."""
        return int(self.vertices.shape[0])

    @property
    def num_faces(self) -> int:
        """Number of triangles ``M``."""
        return int(self.faces.shape[0])

    @property
    def device(self) -> torch.device:
        """The device holding the tensors."""
        return self.vertices.device

    @property
    def faces_int32(self) -> torch.Tensor:
        """The faces as a contiguous int32 ``(M, 3)`` tensor, the native rasterizer's index type."""
        return self.faces.to(torch.int32).contiguous()

    def to(self, device: Device) -> "Mesh":
        """Return a copy on ``device`` (the same object if already there)."""
        device = torch.device(device)
        if self.vertices.device == device:
            return self
        return Mesh(self.vertices.to(device), self.faces.to(device), self.face_colors.to(device))

    def with_vertices(self, vertices: torch.Tensor) -> "Mesh":
        """Return a mesh sharing faces and colours with new vertex positions (autograd is kept).

        Args:
            vertices: float32 ``(N, 3)`` tensor, same ``N`` as this mesh.

        Raises:
            ValueError: wrong shape or dtype.
        """
        return self._with_same_shape("vertices", vertices)

    def with_face_colors(self, face_colors: torch.Tensor) -> "Mesh":
        """Return a mesh sharing vertices and faces with new per-face colours (autograd is kept).

        Args:
            face_colors: float32 ``(M, 3)`` tensor, same ``M`` as this mesh.

        Raises:
            ValueError: wrong shape or dtype.
        """
        return self._with_same_shape("face_colors", face_colors)

    def _with_same_shape(self, name: str, value: torch.Tensor) -> "Mesh":
        """This mesh with the tensor field ``name`` replaced by ``value``, which must have the field's shape."""
        expected = tuple(getattr(self, name).shape)
        if not isinstance(value, torch.Tensor) or tuple(value.shape) != expected:
            shape = tuple(value.shape) if isinstance(value, torch.Tensor) else type(value).__name__
            raise ValueError(f"{name} must be a tensor of shape {expected}, got {shape}")
        return dataclasses.replace(self, **{name: value})

    def detach(self) -> "Mesh":
        """Return a copy whose tensors are detached from any autograd graph."""
        return Mesh(self.vertices.detach(), self.faces.detach(), self.face_colors.detach())

    def bounds(self) -> torch.Tensor:
        """Axis-aligned bounding box as a ``(2, 3)`` tensor ``[min, max]``.

        Raises:
            ValueError: the mesh has no vertices.
        """
        if self.num_vertices == 0:
            raise ValueError("bounds of a mesh without vertices are undefined")
        v = self.vertices.detach()
        return torch.stack([v.min(dim=0).values, v.max(dim=0).values])

    def bbox_diagonal(self) -> float:
        """Length of the diagonal of the axis-aligned bounding box (in double precision, as a float).

        Raises:
            ValueError: the mesh has no vertices.
        """
        if self.num_vertices == 0:
            raise ValueError("bounds of a mesh without vertices are undefined")
        return float(bbox_diagonal(self.vertices.detach().double()))

    def face_areas(self) -> torch.Tensor:
        """Area of every face, float32 ``(M,)`` (differentiable in the vertices)."""
        tri = self.vertices[self.faces]
        return 0.5 * torch.linalg.norm(torch.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], dim=1), dim=1)

    def numpy(self) -> "tuple[np.ndarray, np.ndarray, np.ndarray]":
        """Return detached CPU copies ``(vertices float32, faces int64, face_colors float32)``."""
        return (
            self.vertices.detach().cpu().numpy().copy(),
            self.faces.detach().cpu().numpy().copy(),
            self.face_colors.detach().cpu().numpy().copy(),
        )

    def __repr__(self) -> str:
        return f"Mesh(num_vertices={self.num_vertices}, num_faces={self.num_faces}, device={self.device})"
