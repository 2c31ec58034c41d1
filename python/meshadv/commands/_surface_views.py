"""Renders of a mesh file's own surface (texture, vertex colours, smooth normals) for the commands."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import torch

__all__ = ["SURFACE_SUFFIXES", "render_file_surface"]

#: Files whose texture, vertex colours or normals the commands render as they are.
SURFACE_SUFFIXES = (".obj", ".glb", ".gltf", ".ply")


def render_file_surface(
    path: Optional[Path], z_up: bool, view_set: Any, image_size: int, background: tuple, shading: Optional[str]
) -> Optional[torch.Tensor]:
    """(V,3,H,W) renders of the file at ``path`` with its texture or vertex colours under ``shading`` (default: what
    the file asks for), normalised as the commands normalise meshes; None when the file has neither (the per-face
    path renders it) and no ``shading="smooth"`` was asked for.

    Raises:
        MeshLoadError: the file's texture or attributes are unusable (the message names the file and field).
    """
    from meshadv.mesh import normalize_mesh
    from meshadv.mesh.surface_mesh import load_surface_mesh
    from meshadv.render import render_surface

    if path is None or path.suffix.lower() not in SURFACE_SUFFIXES:
        return None
    surface = load_surface_mesh(path)
    if surface.texture is None and surface.vertex_colors is None and shading != "smooth":
        return None
    mesh, _ = normalize_mesh(surface.mesh, z_up=z_up)
    colors = surface.vertex_colors
    if surface.texture is None and colors is None:
        # Smooth shading of per-face colours: each vertex the mean of its faces' colours.
        faces = mesh.faces.reshape(-1)
        total = torch.zeros(mesh.num_vertices, 3).index_add(0, faces, mesh.face_colors.repeat_interleave(3, 0))
        colors = total / torch.bincount(faces, minlength=mesh.num_vertices).clamp_min(1).unsqueeze(1)
    # File normals are not rotated with the mesh: smooth shading uses the normals of the normalised vertices.
    with torch.no_grad():
        out = render_surface(
            mesh.vertices, mesh.faces, view_set.camera, view_set.lights, image_size, texture=surface.texture,
            uvs=surface.uvs, uv_faces=surface.uv_faces, vertex_colors=colors,
            shading=shading or surface.shading, background=background,
        )
    return out.image
