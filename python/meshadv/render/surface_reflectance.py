"""A batch of UV-textured or vertex-coloured reflectances for :meth:`RenderSetup.render`: what an attack on a texture
image, or on a textured, vertex-coloured or smooth-shaded mesh, renders.

:class:`SurfaceReflectance` stands where the per-face colours stand in a batched render: ``K`` texture images on one
UV layout and/or vertex colours, flat or smooth shaded, drawn through :func:`~meshadv.render.render_surface` with
exact gradients to the texels. :func:`stacked_reflectance` builds the reflectance of a list of meshes sharing one
topology: their stacked face colours, or a :class:`SurfaceReflectance` when they carry a texture or vertex colours;
:func:`reflectance_of` that of one mesh (a shape perturbation of a textured mesh renders its texture).

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
    """``K`` texture images on one UV layout and/or shared vertex colours, the reflectance of ``K`` versions of a mesh.

    Attributes:
        texture: ``(K, Ht, Wt, 3)`` RGB in ``[0, 1]`` (row 0 at the top; may carry gradients), or None (vertex
            colours alone, one reflectance shared by every version).
        uvs: ``(T, 2)`` texture coordinates (origin bottom-left), None without a texture.
        uv_faces: ``(M, 3)`` rows of ``uvs`` at each face corner, None without a texture.
        vertex_colors: optional ``(N, 3)`` per-vertex reflectance, multiplied with the texture when there is one.
        shading: ``"flat"`` or ``"smooth"`` (smooth uses the area-weighted normals of the rendered vertices).
        wrap: texel indices outside the image, ``"repeat"`` or ``"clamp"``.

    Raises:
        ValueError: neither a texture nor vertex colours, a texture without its UVs, or a texture not
            ``(K, Ht, Wt, 3)``.
    """

    texture: Optional[Tensor]
    uvs: Optional[Tensor]
    uv_faces: Optional[Tensor]
    vertex_colors: Optional[Tensor] = None
    shading: str = "flat"
    wrap: str = "repeat"

    def __post_init__(self) -> None:
        if self.texture is None:
            if self.vertex_colors is None:
                raise ValueError("a SurfaceReflectance needs a texture or vertex_colors")
            return
        if self.texture.dim() != 4 or self.texture.shape[-1] != 3:
            raise ValueError(f"texture must have shape (K,Ht,Wt,3), got {tuple(self.texture.shape)}")
        if self.uvs is None or self.uv_faces is None:
            raise ValueError("a texture needs its uvs and uv_faces")

    def __len__(self) -> int:
        return 1 if self.texture is None else int(self.texture.shape[0])

    def repeat_views(self, num_views: int, num_meshes: int = 1) -> SurfaceReflectance:
        """The reflectance of a mesh-major batch of ``num_meshes * num_views`` renders: texture ``k`` repeated per
        view, or one shared texture (``K = 1``) for every mesh.

        Raises:
            ValueError: ``K`` is neither 1 nor ``num_meshes``.
        """
        if self.texture is None:
            return self  # one shared reflectance: render_surface broadcasts it over the batch
        if len(self) == 1:
            texture = self.texture.expand(num_meshes * num_views, -1, -1, -1)
        elif len(self) == num_meshes:
            texture = self.texture.repeat_interleave(num_views, dim=0) if num_views > 1 else self.texture
        else:
            raise ValueError(f"texture holds {len(self)} images for {num_meshes} meshes (give 1 or {num_meshes})")
        return SurfaceReflectance(texture, self.uvs, self.uv_faces, self.vertex_colors, self.shading, self.wrap)


def _is_surface(mesh: Any) -> bool:
    """Whether ``mesh`` is drawn by ``render_surface``: it carries a texture or vertex colours (a
    :class:`~meshadv.mesh.surface_mesh.SurfaceMesh`)."""
    return getattr(mesh, "texture", None) is not None or getattr(mesh, "vertex_colors", None) is not None


def reflectance_of(mesh: Any) -> Union[Tensor, SurfaceReflectance]:
    """What a render of ``mesh`` draws: its UV texture and/or vertex colours as a one-version
    :class:`SurfaceReflectance` under its shading when it carries them (a
    :class:`~meshadv.mesh.surface_mesh.SurfaceMesh`), else its ``(M, 3)`` face colours."""
    if not _is_surface(mesh):
        return mesh.face_colors
    texture = None if mesh.texture is None else mesh.texture.unsqueeze(0)
    return SurfaceReflectance(texture, mesh.uvs, mesh.uv_faces, mesh.vertex_colors, mesh.shading)


def stacked_reflectance(meshes: Sequence[Any]) -> Union[Tensor, SurfaceReflectance]:
    """The reflectance of meshes sharing one topology: ``(K, M, 3)`` face colours, or a :class:`SurfaceReflectance`
    of their ``(Ht, Wt, 3)`` textures and the first one's vertex colours and shading when they carry a texture or
    vertex colours (a :class:`~meshadv.mesh.surface_mesh.SurfaceMesh`).

    Raises:
        ValueError: some meshes carry a texture (or vertex colours) and others do not, or their textures differ in
            size.
    """
    first = meshes[0]
    if any(_is_surface(m) != _is_surface(first) for m in meshes):
        raise ValueError("meshes must all carry a texture or vertex colours, or all none")
    if not _is_surface(first):
        return torch.stack([m.face_colors for m in meshes])
    if first.texture is None:
        if any(m.texture is not None for m in meshes):
            raise ValueError("meshes must all carry a texture or none")
        return SurfaceReflectance(None, None, None, first.vertex_colors, first.shading)
    textures = [m.texture for m in meshes]
    if any(t is None or t.shape != textures[0].shape for t in textures):
        raise ValueError("meshes must all carry a texture of one size")
    return SurfaceReflectance(torch.stack(textures), first.uvs, first.uv_faces, first.vertex_colors,
                              first.shading)
