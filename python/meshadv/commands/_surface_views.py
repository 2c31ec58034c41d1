"""A mesh file's own surface (texture, vertex colours, normals) and shading for the commands: what ``meshadv render``
draws and ``meshadv attack`` attacks."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any, Optional

if TYPE_CHECKING:
    import torch

__all__ = ["SHADING_HELP", "SURFACE_SUFFIXES", "parse_shading", "render_file_surface", "surface_input"]

#: Files whose texture, vertex colours or normals the commands render as they are.
SURFACE_SUFFIXES = (".obj", ".glb", ".gltf", ".ply")

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


def _vertex_mean_colors(mesh: Any) -> torch.Tensor:
    """(N,3) each vertex's mean of its faces' colours (a vertex of no face: 0)."""
    import torch

    faces = mesh.faces.reshape(-1)
    total = torch.zeros(mesh.num_vertices, 3).index_add(0, faces, mesh.face_colors.repeat_interleave(3, 0))
    return total / torch.bincount(faces, minlength=mesh.num_vertices).clamp_min(1).unsqueeze(1)


def surface_input(loaded: Any, shading: Optional[str], *, keep_normals: bool = True) -> Any:
    """The ``MeshInput`` of a file drawn through its surface: its mesh the file's normalised
    :class:`~meshadv.mesh.surface_mesh.SurfaceMesh` (texture, UVs, vertex colours and normals as in the file, turned
    with the normalisation) under ``shading`` (default: what the file asks for), and its transform. A mesh with no
    texture and no vertex colours is drawn through its surface only for ``shading="smooth"``: the normalised per-face
    mesh with each vertex the mean of its faces' colours; else (and for built-in shapes) ``loaded`` comes back as it
    is, drawn per face and flat.

    Args:
        loaded: the command line's ``MeshInput``.
        shading: ``"flat"``, ``"smooth"`` or ``None`` (:func:`parse_shading`).
        keep_normals: keep the file's normals; ``False`` shades smooth with the area-weighted normals of the
            vertices (what an attack renders: a shape attack moves the vertices).

    Raises:
        MeshLoadError: the file's texture or attributes are unusable (the message names the file and field).
    """
    from meshadv.mesh.surface_mesh import SurfaceMesh, load_surface_mesh

    path = loaded.path
    surface = None
    if path is not None and path.suffix.lower() in SURFACE_SUFFIXES:
        surface = load_surface_mesh(path)
        if surface.texture is None and surface.vertex_colors is None:
            surface = None
    if surface is None:
        if shading != "smooth":
            return loaded
        mesh = loaded.mesh
        return replace(loaded, mesh=SurfaceMesh(mesh, vertex_colors=_vertex_mean_colors(mesh), shading="smooth"))
    surface, transform = surface.normalized(z_up=bool(loaded.z_up))
    if not keep_normals:
        surface = replace(surface, normals=None, normal_faces=None)
    return replace(loaded, mesh=replace(surface, shading=shading or surface.shading), transform=transform)


def render_file_surface(loaded: Any, view_set: Any, image_size: int, background: tuple,
                        shading: Optional[str]) -> Optional[torch.Tensor]:
    """(V,3,H,W) renders of ``loaded``'s file through its surface (:func:`surface_input`, the file's normals as
    given); None when it is drawn per face and flat (the per-face path renders it).

    Raises:
        MeshLoadError: the file's texture or attributes are unusable (the message names the file and field).
    """
    import torch

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
