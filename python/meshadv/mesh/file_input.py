"""A mesh file as ``meshadv render``, ``meshadv attack`` and sweep jobs draw and attack it: normalised into
``[-1, 1]``, its texture, vertex colours and normals as the file has them (a
:class:`~meshadv.mesh.surface_mesh.SurfaceMesh`) under a shading, and resampled uniformly for a shape attack.

One loader for the commands and the sweep jobs, so that a sweep's job attacks a file as ``meshadv attack`` does.

Example:
    >>> loaded = attack_input(read_file_input(Path("ball.obj"), z_up=False), "shape", None, 0)  # doctest: +SKIP
    >>> type(loaded.mesh).__name__  # doctest: +SKIP
    'SurfaceMesh'
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Optional

import torch

from meshadv.mesh.io import DEFAULT_MAX_FACES, load_mesh
from meshadv.mesh.normalize import normalize_mesh

__all__ = ["SURFACE_SUFFIXES", "MeshInput", "attack_input", "read_file_input", "resampled_input", "surface_input"]

#: Files whose texture, vertex colours or normals are drawn as they are.
SURFACE_SUFFIXES = (".obj", ".glb", ".gltf", ".ply")

#: Where the notes of :func:`resampled_input` and :func:`attack_input` go (a command prints them).
Say = Callable[[str], None]


def _silent(_: str) -> None:
    return None


@dataclass(frozen=True)
class MeshInput:
    """A mesh to draw or attack, normalised into ``[-1, 1]``.

    Attributes:
        mesh: the normalised, Y-up mesh (a ``Mesh``, or a ``SurfaceMesh`` once drawn through its surface).
        label: how it was named (the command line's argument, a file path).
        path: the resolved input file, ``None`` for built-ins.
        transform: the ``NormalizeTransform`` from the input file's frame (``None`` for built-ins).
        z_up: whether the file was taken as Z-up.
    """

    mesh: Any
    label: str
    path: Optional[Path]
    transform: Any
    z_up: bool


def read_file_input(path: Path, *, z_up: bool, max_faces: int = DEFAULT_MAX_FACES, label: Optional[str] = None
                    ) -> MeshInput:
    """The per-face mesh of a file, normalised (:func:`~meshadv.mesh.normalize.normalize_mesh`), as a
    :class:`MeshInput`; :func:`surface_input` or :func:`attack_input` then draw it through its surface.

    Args:
        path: the mesh file. z_up: the file is Z-up (rotated to Y-up). max_faces: refuse larger meshes.
        label: how to name it (default: the path).

    Raises:
        MeshLoadError: an unreadable or too large file (the message names it).
    """
    mesh, transform = normalize_mesh(load_mesh(path, max_faces=max_faces), z_up=z_up)
    return MeshInput(mesh, str(path) if label is None else label, Path(path).resolve(), transform, z_up)


def _vertex_mean_colors(mesh: Any) -> torch.Tensor:
    """(N,3) each vertex's mean of its faces' colours (a vertex of no face: 0)."""
    faces = mesh.faces.reshape(-1)
    total = torch.zeros(mesh.num_vertices, 3).index_add(0, faces, mesh.face_colors.repeat_interleave(3, 0))
    return total / torch.bincount(faces, minlength=mesh.num_vertices).clamp_min(1).unsqueeze(1)


def surface_input(loaded: MeshInput, shading: Optional[str], *, keep_normals: bool = True) -> MeshInput:
    """``loaded`` drawn through its file's surface: its mesh the file's normalised
    :class:`~meshadv.mesh.surface_mesh.SurfaceMesh` (texture, UVs, vertex colours and normals as in the file, turned
    with the normalisation) under ``shading`` (default: what the file asks for), and its transform. A mesh with no
    texture and no vertex colours is drawn through its surface only for ``shading="smooth"``: the normalised per-face
    mesh with each vertex the mean of its faces' colours; else (and for built-in shapes) ``loaded`` comes back as it
    is, drawn per face and flat.

    Args:
        loaded: the per-face input (:func:`read_file_input`).
        shading: ``"flat"``, ``"smooth"`` or ``None`` (what the file asks for).
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


def resampled_input(loaded: MeshInput, faces: int, say: Say = _silent, hint: str = "") -> MeshInput:
    """``loaded`` with its mesh resampled uniformly with MeshLab to about ``faces`` faces, saying the face counts
    (``hint`` appended: e.g. a command's way back to the mesh as loaded): a
    per-face mesh by :func:`meshadv.mesh.resample.resample_mesh_with_info`, a textured or vertex-coloured one by
    :func:`meshadv.mesh.surface_resample.resample_surface_mesh` (its texture carried onto a new atlas, its vertex
    colours onto the new vertices); unchanged for ``faces == 0`` and for built-in shapes (no file).

    Raises:
        MeshProcessingError: MeshLab failed on the mesh (the message says so).
    """
    if faces == 0 or loaded.path is None:
        return loaded
    from meshadv.mesh.surface_mesh import SurfaceMesh

    carried = ""
    if isinstance(loaded.mesh, SurfaceMesh):
        from meshadv.mesh.surface_resample import resample_surface_mesh

        dense, info = resample_surface_mesh(loaded.mesh, target_faces=faces)
        carried = "; " + " and ".join(
            ([f"texture carried onto a {dense.texture.shape[1]}x{dense.texture.shape[0]} atlas"]
             if dense.texture is not None else []) + (["vertex colours carried"] if dense.vertex_colors is not None
                                                      else []))
    else:
        from meshadv.mesh.resample import resample_mesh_with_info

        dense, info = resample_mesh_with_info(loaded.mesh, target_faces=faces)
    say(f"resampled uniformly with MeshLab ({info.method}): {info.input_faces} -> {info.output_faces} faces"
        f"{carried}{hint}")
    return replace(loaded, mesh=dense)


def attack_input(loaded: MeshInput, perturbation: str, shading: Optional[str], resample: int,
                 say: Say = _silent, hint: str = "") -> MeshInput:
    """The input an attack of ``perturbation`` works on, resampled (:func:`resampled_input`) and under ``shading``
    (default: what the file asks for): for ``shape`` and ``texture-map`` a file's texture or vertex colours drawn as
    the file has them (a :class:`~meshadv.mesh.surface_mesh.SurfaceMesh`; ``texture-map`` attacks it as loaded, its
    texels in the file's UV layout being the perturbation), else the per-face mesh, drawn smooth with each vertex the
    mean of its faces' colours for ``shading="smooth"``. Smooth shading uses the area-weighted normals of the
    attacked vertices (the file's normals do not follow a shape perturbation). ``texture`` (per-face colours) takes
    the per-face mesh, drawn flat: ``shading`` does not apply to it.

    Args:
        loaded: the per-face input (:func:`read_file_input`). perturbation: ``shape``, ``texture`` or
            ``texture-map``. shading: ``"flat"``, ``"smooth"`` or ``None``. resample: faces to resample to (0:
            as loaded). say: where the resampling notes go. hint: appended to the resampling note.

    Raises:
        ValueError: ``texture-map`` of a mesh without a UV texture image.
        MeshLoadError: the file's texture or attributes are unusable (the message names the file and field).
        MeshProcessingError: MeshLab failed on the mesh.
    """
    from meshadv.mesh.surface_mesh import SurfaceMesh

    if perturbation == "texture":
        return resampled_input(loaded, resample, say, hint)
    surface = surface_input(loaded, None if shading == "smooth" else shading, keep_normals=False)
    if isinstance(surface.mesh, SurfaceMesh):
        surface = replace(surface, mesh=replace(surface.mesh, shading=shading or surface.mesh.shading))
        if perturbation == "texture-map":
            if resample:
                say("texture-map: the textured file is attacked as loaded (its texels, in the file's UV layout, "
                    "are the perturbation; resampling would re-encode them)")
            return surface
        return resampled_input(surface, resample, say, hint)
    if perturbation == "texture-map":
        raise ValueError(f"texture-map needs a UV texture image: {loaded.label} has none (an OBJ needs a map_Kd in "
                         "its MTL, a GLB a base-colour texture)")
    return surface_input(resampled_input(loaded, resample, say, hint), shading)
