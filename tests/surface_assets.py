"""Generated textured and vertex-coloured meshes (no downloads) for the surface attack, export and transfer tests."""

from __future__ import annotations

import torch

from meshadv.mesh import builtin_mesh
from meshadv.mesh.structure import Mesh
from meshadv.mesh.surface_mesh import SurfaceMesh


def box_textured(name: str = "sphere", side: int = 16, seed: int = 0) -> SurfaceMesh:
    """The built-in mesh ``name`` with one UV per face corner (a box projection along each face's dominant normal
    axis, over [0.05, 0.95]) and a random 8-bit ``side x side`` texture (8-bit exact: a PNG round trip is exact)."""
    base = builtin_mesh(name)
    verts, faces = base.vertices, base.faces
    corners = verts[faces]  # (M,3,3)
    normal = torch.linalg.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]).abs().argmax(dim=1)
    keep = torch.tensor([[1, 2], [0, 2], [0, 1]])[normal]  # (M,2): the two axes across the face
    uv = torch.gather(corners, 2, keep[:, None, :].expand(-1, 3, -1))
    uv = 0.05 + 0.9 * (uv - uv.min()) / (uv.max() - uv.min())
    g = torch.Generator().manual_seed(seed)
    texture = torch.randint(0, 256, (side, side, 3), generator=g).float() / 255.0
    uvs = uv.reshape(-1, 2).contiguous()
    uv_faces = torch.arange(uvs.shape[0]).reshape(-1, 3)
    surface = SurfaceMesh(Mesh(verts, faces, torch.full((faces.shape[0], 3), 0.5)), uvs, uv_faces, texture)
    return surface.with_texture(texture)


def vertex_coloured(name: str = "sphere") -> SurfaceMesh:
    """The built-in mesh ``name`` with smooth 8-bit vertex colours that vary over the surface (a colour per axis of
    the position) and per-face colours their mean per face."""
    base = builtin_mesh(name)
    v = base.vertices
    rgb = ((0.5 + 0.45 * v / v.abs().max()) * 255).round() / 255
    return SurfaceMesh(Mesh(v, base.faces, rgb[base.faces].mean(dim=1)), vertex_colors=rgb)
