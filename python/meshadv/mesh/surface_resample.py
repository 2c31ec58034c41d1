"""Uniform MeshLab resampling of a textured or vertex-coloured mesh that keeps its look.

The geometry is resampled as a plain mesh (:func:`~meshadv.mesh.resample.resample_mesh_with_info`, cached); then, in
the isolated MeshLab worker, the texture is carried onto the new faces (a trivial per-triangle atlas of
``texture_side`` squared texels filled with the source texture's colour at the closest source point; MeshLab looks
up the nearest texel, so a smaller texture is first magnified bilinearly, as meshadv samples it) and the vertex
colours likewise (the source colour at the closest point). Normals from the file are not carried (smooth shading then
uses the area-weighted normals of the new vertices); the shading the file asked for is kept.

Measured on generated textured meshes (benchmarks/surface_resample.py, docs/TEXTURES.md): the transferred texture
renders within a few hundredths of the original's colours, several times closer than the texture's colour per new
vertex or per new face.

Example:
    >>> dense, info = resample_surface_mesh(load_surface_mesh("textured.obj"), target_faces=4000)  # doctest: +SKIP
    >>> dense.texture.shape  # doctest: +SKIP
    torch.Size([1024, 1024, 3])
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from meshadv import _validate
from meshadv.mesh.resample import DEFAULT_TIMEOUT, ResampleInfo, resample_mesh_with_info, run_isolated
from meshadv.mesh.surface_mesh import SurfaceMesh, load_surface_mesh, save_surface_mesh

__all__ = ["DEFAULT_TEXTURE_SIDE", "resample_surface_mesh"]

#: Side in texels of the texture atlas of a resampled textured mesh.
DEFAULT_TEXTURE_SIDE = 1024


def _magnified(texture: torch.Tensor, side: int) -> torch.Tensor:
    """``texture`` (Ht,Wt,3) magnified bilinearly (texel centres as docs/TEXTURES.md) by the integer factor that
    brings its larger side to at least ``side``; as it is when it is that large already."""
    factor = math.ceil(side / max(texture.shape[:2]))
    if factor <= 1:
        return texture
    image = texture.detach().float().permute(2, 0, 1).unsqueeze(0)
    size = (texture.shape[0] * factor, texture.shape[1] * factor)
    return F.interpolate(image, size=size, mode="bilinear", align_corners=False)[0].permute(1, 2, 0).contiguous()


def resample_surface_mesh(
    surface: SurfaceMesh,
    *,
    target_faces: int,
    texture_side: int = DEFAULT_TEXTURE_SIDE,
    timeout: float = DEFAULT_TIMEOUT,
) -> tuple[SurfaceMesh, ResampleInfo]:
    """Resample ``surface`` uniformly with MeshLab to about ``target_faces`` faces, carrying its texture and vertex
    colours onto the new surface.

    Args:
        surface: a mesh with a texture and/or vertex colours.
        target_faces: wanted face count (about 20 %).
        texture_side: side of the new texture atlas in texels (a textured surface only).
        timeout: seconds allowed per MeshLab run.

    Returns:
        ``(resampled surface, info)``: the welded new geometry with its per-face colours (the texture's mean per
        face), a ``texture_side`` squared texture, UVs and/or vertex colours, and the shading of ``surface``.

    Raises:
        TypeError: ``surface`` is not a SurfaceMesh, or an argument of the wrong type.
        ValueError: ``surface`` has neither texture nor vertex colours, or an argument out of range.
        MeshProcessingError: MeshLab failed, crashed or timed out.
    """
    if not isinstance(surface, SurfaceMesh):
        raise TypeError(f"surface must be a SurfaceMesh, got {type(surface).__name__}")
    texture, colors = surface.texture is not None, surface.vertex_colors is not None
    if not (texture or colors):
        raise ValueError("surface has neither texture nor vertex colours: resample its mesh with resample_mesh")
    _validate.integer("texture_side", texture_side, low=8, high=16384)
    dense, info = resample_mesh_with_info(surface.mesh, target_faces=target_faces, timeout=timeout)
    with tempfile.TemporaryDirectory(prefix="meshadv-surface-resample-") as tmp:
        folder = Path(tmp)
        source = replace(surface, normals=None, normal_faces=None)
        if texture:  # MeshLab looks up the nearest texel: hand it a bilinear magnification to look up in
            source = replace(source, texture=_magnified(surface.texture, texture_side))
        save_surface_mesh(source, folder / "source.obj")
        np.savez(folder / "target.npz", vertices=dense.vertices.double().cpu().numpy(),
                 faces=dense.faces.cpu().numpy().astype(np.int32))
        run_isolated({"op": "surface_transfer", "source": str(folder / "source.obj"),
                      "input": str(folder / "target.npz"), "output": str(folder / "resampled.obj"),
                      "texture": texture, "colors": colors, "texture_side": int(texture_side),
                      "texture_name": "resampled_texture.png"}, timeout=timeout)
        result = load_surface_mesh(folder / "resampled.obj")
    result = replace(result, shading=surface.shading, normals=None, normal_faces=None)
    return result, replace(info, output_faces=result.num_faces)
