"""Lambertian lighting with directional lights and ambient light (NMR's model), differentiable in PyTorch.

``s = ambient + sum_j color_j * max(dot(d_j, n), 0)`` with ``d_j`` the unit direction FROM the surface TOWARD light j
and ``n`` the face normal (flipped toward the camera for two-sided rendering);
``face_color = clamp(reflectance * s, 0, 1)``.
Lights live in world space.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Union

import torch

from ._checks import as_float_tensor, batch_selector, require_instance
from ._ops import small_matmul
from .camera import Camera, _normalize
from .rasterize import _native

__all__ = ["Lights", "face_normals", "orient_normals", "shade"]

_EPS = 1e-12
_Vec = Union[Sequence[float], torch.Tensor]


@dataclass(frozen=True)
class Lights:
    """A batch of light sets: ``K`` directional lights plus an ambient term per view.

    Args:
        directions: (K,3) or (B,K,3) directions from the surface toward each light (normalised when shading).
        colors: (K,3) or (B,K,3) RGB intensity of each light.
        ambient: (3,) or (B,3) RGB ambient intensity.

    After construction all three fields are batched: (B,K,3), (B,K,3), (B,3); K may be 0 (ambient only).

    Raises:
        ValueError: bad shapes, incompatible batch sizes, non-finite values or zero directions.

    Example:
        >>> lights = Lights.single(direction=(0.0, 1.0, -1.0), color=(0.5, 0.5, 0.5), ambient=(0.5, 0.5, 0.5))
        >>> lights.directions.shape
        torch.Size([1, 1, 3])
    """

    directions: torch.Tensor
    colors: torch.Tensor
    ambient: torch.Tensor

    def __post_init__(self) -> None:
        dtype = next(
            (
                v.dtype
                for v in (self.directions, self.colors, self.ambient)
                if isinstance(v, torch.Tensor) and v.is_floating_point()
            ),
            torch.float32,
        )
        device = next(
            (v.device for v in (self.directions, self.colors, self.ambient) if isinstance(v, torch.Tensor)),
            None,
        )
        d = as_float_tensor(self.directions, "directions", dtype, device)
        c = as_float_tensor(self.colors, "colors", dtype, device)
        a = as_float_tensor(self.ambient, "ambient", dtype, device)
        for name, t in (("directions", d), ("colors", c)):
            if t.dim() not in (2, 3) or t.shape[-1] != 3:
                raise ValueError(f"{name} must have shape (K,3) or (B,K,3), got {tuple(t.shape)}")
        if a.dim() not in (1, 2) or a.shape[-1] != 3:
            raise ValueError(f"ambient must have shape (3,) or (B,3), got {tuple(a.shape)}")
        d = d if d.dim() == 3 else d.unsqueeze(0)
        c = c if c.dim() == 3 else c.unsqueeze(0)
        a = a if a.dim() == 2 else a.unsqueeze(0)
        if d.shape[1] != c.shape[1]:
            raise ValueError(
                f"directions and colors must hold the same number of lights, got {d.shape[1]} and {c.shape[1]}"
            )
        sizes = {d.shape[0], c.shape[0], a.shape[0]}
        sizes.discard(1)
        if len(sizes) > 1:
            raise ValueError(
                f"lights have incompatible batch sizes: directions {tuple(d.shape)}, "
                f"colors {tuple(c.shape)}, ambient {tuple(a.shape)}"
            )
        b = sizes.pop() if sizes else 1
        if b == 0:
            raise ValueError("lights must hold at least one light set (batch size 0)")
        # The native core's rule (the render binary refuses the same directions).
        if bool((d.detach().abs().amax(dim=-1) <= _native().MIN_LIGHT_DIRECTION).any()):
            raise ValueError("directions must be non-zero vectors")
        object.__setattr__(self, "directions", d.expand(b, -1, -1) if d.shape[0] != b else d)
        object.__setattr__(self, "colors", c.expand(b, -1, -1) if c.shape[0] != b else c)
        object.__setattr__(self, "ambient", a.expand(b, -1) if a.shape[0] != b else a)

    @classmethod
    def single(
        cls,
        direction: _Vec = (0.0, 0.0, -1.0),
        color: _Vec = (0.5, 0.5, 0.5),
        ambient: _Vec = (0.5, 0.5, 0.5),
    ) -> Lights:
        """One directional light plus ambient.

        Args:
            direction: (3,) or (B,3) direction from the surface toward the light.
            color: (3,) or (B,3) RGB intensity.
            ambient: (3,) or (B,3) RGB ambient intensity.
        """
        d = as_float_tensor(direction, "direction")
        c = as_float_tensor(color, "color", d.dtype, d.device)
        return cls(directions=d.unsqueeze(-2), colors=c.unsqueeze(-2), ambient=ambient)

    @classmethod
    def default(cls, camera: Camera | None = None) -> Lights:
        """NMR's default intensities: ambient 0.5 and one white directional light of 0.5 from the camera side.

        Args:
            camera: when given, the light of view ``b`` points from the target toward that view's eye (a head light,
                detached from the camera's autograd graph); otherwise it points to ``-Z``, toward the camera at
                azimuth 0.

        Returns:
            Lights of batch size ``len(camera)`` (or 1).

        Raises:
            TypeError: ``camera`` is neither a :class:`Camera` nor ``None``.
        """
        if camera is None:
            return cls.single()
        require_instance(camera, Camera, "camera")
        direction = (camera.eye() - camera.target()).detach()
        b = direction.shape[0]
        color = torch.full((b, 3), 0.5, dtype=direction.dtype, device=direction.device)
        return cls.single(direction=direction, color=color, ambient=color.clone())

    @property
    def batch_size(self) -> int:
        """Number of light sets B."""
        return int(self.ambient.shape[0])

    def __len__(self) -> int:
        return self.batch_size

    @property
    def num_lights(self) -> int:
        """Number of directional lights K."""
        return int(self.directions.shape[1])

    def to(self, device: str | torch.device | None = None, dtype: torch.dtype | None = None) -> Lights:
        """Move to ``device`` and/or cast to ``dtype``."""
        return Lights(
            self.directions.to(device=device, dtype=dtype),
            self.colors.to(device=device, dtype=dtype),
            self.ambient.to(device=device, dtype=dtype),
        )

    def detach(self) -> Lights:
        """A copy without autograd history."""
        return Lights(self.directions.detach(), self.colors.detach(), self.ambient.detach())

    def __getitem__(self, index: int | slice | torch.Tensor | Sequence[int]) -> Lights:
        """Select light sets; an integer keeps a batch of one.

        Raises:
            TypeError: ``index`` is not an int, slice, sequence of ints or integer/boolean tensor.
            IndexError: an index is out of range.
            ValueError: the selection is empty.
        """
        index = batch_selector(index, self.batch_size, "lights", self.ambient.device)
        return Lights(self.directions[index], self.colors[index], self.ambient[index])

    @staticmethod
    def cat(lights: Sequence[Lights]) -> Lights:
        """Concatenate light sets along the batch axis (all must have the same K)."""
        lights = list(lights)
        if not lights:
            raise ValueError("lights must be a non-empty sequence")
        if len({item.num_lights for item in lights}) != 1:
            raise ValueError("lights must all have the same number of directional lights to be concatenated")
        return Lights(
            torch.cat([item.directions for item in lights]),
            torch.cat([item.colors for item in lights]),
            torch.cat([item.ambient for item in lights]),
        )


def face_normals(verts_world: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Unit face normals ``normalize((v1 - v0) x (v2 - v0))``.

    Args:
        verts_world: (N,3) or (B,N,3) vertex positions.
        faces: (M,3) integer vertex indices.

    Returns:
        (B,M,3) unit normals (B = 1 for unbatched vertices); degenerate faces get a zero normal with zero gradient.
    """
    verts = verts_world if verts_world.dim() == 3 else verts_world.unsqueeze(0)
    tri = verts[:, faces.long()]  # (B,M,3,3)
    n = torch.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0], dim=-1)
    norm = n.norm(dim=-1, keepdim=True)
    return n / norm.clamp_min(_EPS)


def orient_normals(
    normals: torch.Tensor, verts_world: torch.Tensor, faces: torch.Tensor, camera: Camera
) -> torch.Tensor:
    """Flip normals that face away from the camera (two-sided rendering).

    Perspective: a normal is flipped when ``dot(n, eye - p) < 0`` with ``p`` a point of the face (its first vertex:
    ``n`` is orthogonal to the face's plane, so every point of the face, e.g. the centroid, gives the same sign).
    Orthographic: when ``dot(n, view_dir) > 0``. The flip sign is piecewise constant, so it carries no gradient.

    Args:
        normals: (B,M,3) face normals.
        verts_world: (N,3) or (B,N,3) vertices.
        faces: (M,3) vertex indices.
        camera: cameras of batch B (or 1).

    Returns:
        (B,M,3) normals facing the camera.
    """
    verts = verts_world if verts_world.dim() == 3 else verts_world.unsqueeze(0)
    with torch.no_grad():
        if camera.orthographic:
            toward = -camera.view_direction().to(normals.dtype).unsqueeze(1)  # (Bc,1,3)
        else:
            corner = verts[:, faces[:, 0].long()]  # (Bv,M,3)
            toward = camera.eye().to(normals.dtype).unsqueeze(1) - corner
        facing = (normals * toward).sum(-1, keepdim=True)
    sign = torch.where(facing < 0, -torch.ones_like(facing), torch.ones_like(facing))
    return normals * sign


def shade(
    verts_world: torch.Tensor,
    faces: torch.Tensor,
    face_colors: torch.Tensor,
    lights: Lights,
    camera: Camera | None = None,
    two_sided: bool = True,
) -> torch.Tensor:
    """Lambert-shaded face colours.

    Args:
        verts_world: (N,3) or (B,N,3) vertex positions.
        faces: (M,3) vertex indices.
        face_colors: (M,3) or (B,M,3) reflectance.
        lights: lights of batch B (or 1).
        camera: needed when ``two_sided`` (normals are flipped toward it).
        two_sided: flip normals toward the camera before shading (NMR ``fill_back``).

    Returns:
        (B,M,3) ``clamp(face_colors * (ambient + sum_j c_j max(dot(d_j, n), 0)), 0, 1)``.

    Raises:
        ValueError: ``two_sided`` without a camera, or shapes that do not broadcast.
    """
    normals = face_normals(verts_world, faces)
    if two_sided:
        if camera is None:
            raise ValueError("camera is required when two_sided=True (normals are flipped toward it)")
        normals = orient_normals(normals, verts_world, faces, camera)
    dtype = normals.dtype
    dirs = lights.directions.to(dtype)
    dirs = _normalize(dirs)
    b = max(normals.shape[0], dirs.shape[0])
    if normals.shape[0] not in (1, b) or dirs.shape[0] not in (1, b):
        raise ValueError(
            f"lights batch size {dirs.shape[0]} does not match the vertex/camera batch size {normals.shape[0]}"
        )
    cos = small_matmul(normals, dirs.transpose(1, 2)).clamp_min(0)  # (B,M,K)
    intensity = lights.ambient.to(dtype).unsqueeze(1).expand(b, 1, 3)
    if lights.num_lights > 0:
        intensity = intensity + small_matmul(cos, lights.colors.to(dtype))
    colors = face_colors if face_colors.dim() == 3 else face_colors.unsqueeze(0)
    return (colors.to(dtype) * intensity).clamp(0.0, 1.0)
