"""A batch of UV-textured reflectances for :meth:`RenderSetup.render`: what an attack on a texture image renders.

:class:`SurfaceReflectance` stands where the per-face colours stand in a batched render: ``K`` texture images on one
UV layout (and optional vertex colours), drawn through :func:`~meshadv.render.render_surface` with exact gradients to
the texels. :func:`stacked_reflectance` builds the reflectance of a list of meshes sharing one topology: their stacked
face colours, or a :class:`SurfaceReflectance` of their textures when they carry one; :func:`reflectance_of` that of
one mesh (a shape perturbation of a textured mesh renders its texture).

Example:
    >>> refl = SurfaceReflectance(torch.rand(2, 8, 8, 3), uvs, uv_faces)         # doctest: +SKIP
    >>> images, alpha = RenderSetup(image_size=64).render(verts, faces, refl, views)   # doctest: +SKIP
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional, Sequence, Union

import torch
from torch import Tensor

__all__ = ["SurfaceReflectance", "reflectance_of", "stacked_reflectance"]


@dataclass(frozen=True)
class SurfaceReflectance:
    """``K`` texture images on one UV layout, the reflectance of ``K`` versions of a mesh.

    Attributes:
        texture: ``(K, Ht, Wt, 3)`` RGB in ``[0, 1]`` (row 0 at the top; may carry gradients).
        uvs: ``(T, 2)`` texture coordinates (origin bottom-left).
        uv_faces: ``(M, 3)`` rows of ``uvs`` at each face corner.
        vertex_colors: optional ``(N, 3)`` per-vertex reflectance multiplied with the texture.
        shading: ``"flat"`` or ``"smooth"`` (smooth uses the normals of the rendered vertices).
        wrap: texel indices outside the image, ``"repeat"`` or ``"clamp"``.
    """

    texture: Tensor
    uvs: Tensor
    uv_faces: Tensor
    vertex_colors: Optional[Tensor] = None
    shading: str = "flat"
    wrap: str = "repeat"

    def __post_init__(self) -> None:
        if self.texture.dim() != 4 or self.texture.shape[-1] != 3:
            raise ValueError(f"texture must have shape (K,Ht,Wt,3), got {tuple(self.texture.shape)}")

    def __len__(self) -> int:
        return int(self.texture.shape[0])

    def repeat_views(self, num_views: int, num_meshes: int = 1) -> SurfaceReflectance:
        """The reflectance of a mesh-major batch of ``num_meshes * num_views`` renders: texture ``k`` repeated per
        view, or one shared texture (``K = 1``) for every mesh.

        Raises:
            ValueError: ``K`` is neither 1 nor ``num_meshes``.
        """
        if len(self) == 1:
            texture = self.texture.expand(num_meshes * num_views, -1, -1, -1)
        elif len(self) == num_meshes:
            texture = self.texture.repeat_interleave(num_views, dim=0) if num_views > 1 else self.texture
        else:
            raise ValueError(f"texture holds {len(self)} images for {num_meshes} meshes (give 1 or {num_meshes})")
        return SurfaceReflectance(texture, self.uvs, self.uv_faces, self.vertex_colors, self.shading, self.wrap)


def reflectance_of(mesh: Any) -> Union[Tensor, SurfaceReflectance]:
    """What a render of ``mesh`` draws: its UV texture as a one-image :class:`SurfaceReflectance` when it carries one
    (a :class:`~meshadv.mesh.surface_mesh.SurfaceMesh`), else its ``(M, 3)`` face colours."""
    if getattr(mesh, "texture", None) is None:
        return mesh.face_colors
    return SurfaceReflectance(mesh.texture.unsqueeze(0), mesh.uvs, mesh.uv_faces, mesh.vertex_colors, mesh.shading)


def stacked_reflectance(meshes: Sequence[Any]) -> Union[Tensor, SurfaceReflectance]:
    """The reflectance of meshes sharing one topology: ``(K, M, 3)`` face colours, or a :class:`SurfaceReflectance`
    of their ``(Ht, Wt, 3)`` textures when the first one carries a texture (a
    :class:`~meshadv.mesh.surface_mesh.SurfaceMesh`).

    Raises:
        ValueError: some meshes carry a texture and others do not, or their textures differ in size.
    """
    first = meshes[0]
    if getattr(first, "texture", None) is None:
        if any(getattr(m, "texture", None) is not None for m in meshes):
            raise ValueError("meshes must all carry a texture or none")
        return torch.stack([m.face_colors for m in meshes])
    textures = [m.texture for m in meshes]
    if any(t is None or t.shape != textures[0].shape for t in textures):
        raise ValueError("meshes must all carry a texture of one size")
    return SurfaceReflectance(torch.stack(textures), first.uvs, first.uv_faces, first.vertex_colors,
                              first.shading)
