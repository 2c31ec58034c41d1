"""A mesh file's own surface (texture, vertex colours, normals) and shading for the commands: what ``meshadv render``
draws and ``meshadv attack`` attacks (the loader itself, shared with sweep jobs: :mod:`meshadv.mesh.file_input`)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Optional

if TYPE_CHECKING:
    import torch

__all__ = ["SHADING_HELP", "parse_shading", "render_file_surface"]

#: The help text of ``--shading`` (``meshadv render`` and ``meshadv attack``).
SHADING_HELP = ("flat or smooth (default: what the file asks for: smooth when it has vertex normals, else flat); "
                "textures and vertex colours are drawn as the file has them, and smooth shading of a file with "
                "neither draws each vertex the mean of its faces' colours")


def parse_shading(value: Optional[str], option: str = "--shading") -> Optional[str]:
    """``value`` of a ``--shading`` option: ``"flat"``, ``"smooth"`` or ``None`` (what the file asks for).

    Raises:
        ValueError: another value (the message names ``option``).
    """
    if value not in (None, "flat", "smooth"):
        raise ValueError(f"{option} must be flat or smooth, got {value!r}")
    return value


def render_file_surface(loaded: Any, view_set: Any, image_size: int, background: tuple,
                        shading: Optional[str]) -> Optional[torch.Tensor]:
    """(V,3,H,W) renders of ``loaded``'s file through its surface (:func:`~meshadv.mesh.file_input.surface_input`, the
    file's normals as given); None when it is drawn per face and flat (the per-face path renders it).

    Raises:
        MeshLoadError: the file's texture or attributes are unusable (the message names the file and field).
    """
    import torch

    from meshadv.mesh.file_input import surface_input
    from meshadv.mesh.surface_mesh import SurfaceMesh
    from meshadv.render import render_surface

    surface = surface_input(loaded, shading).mesh
    if not isinstance(surface, SurfaceMesh):
        return None
    with torch.no_grad():
        out = render_surface(
            surface.vertices, surface.faces, view_set.camera, view_set.lights, image_size, texture=surface.texture,
            uvs=surface.uvs, uv_faces=surface.uv_faces, vertex_colors=surface.vertex_colors, normals=surface.normals,
            normal_faces=surface.normal_faces, shading=surface.shading, background=background,
        )
    return out.image
