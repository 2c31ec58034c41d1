"""meshadv.render: differentiable mesh rendering (PyTorch camera and shading, Rust rasterizer; one native op for
the whole flat render of float32 CPU meshes, :mod:`meshadv.render.flat`).

Public API: :class:`Camera`, :class:`Lights`, :class:`ViewSet`, :func:`render`, :func:`render_silhouette`,
:class:`RenderOutput`, :func:`rasterize`, :class:`RasterOutput`, :func:`face_normals`, :func:`shade`, the names of
the vertex gradients (:data:`VISIBILITY_GRADIENTS`), and :func:`render_surface` (textures, vertex colours, smooth
shading; docs/TEXTURES.md) with :func:`vertex_normals`.
"""

from .camera import Camera
from .lighting import Lights, face_normals, orient_normals, shade
from .rasterize import RasterOutput, native_available, rasterize
from .raycast import RayCastOutput, raycast
from .renderer import RenderOutput, render, render_silhouette
from .setup import RenderSetup, StaticObject, render_views
from .surface import render_surface, vertex_normals
from .views import ViewSet
from .visibility import VISIBILITY_GRADIENTS

__all__ = [
    "Camera",
    "Lights",
    "RasterOutput",
    "RayCastOutput",
    "RenderOutput",
    "RenderSetup",
    "StaticObject",
    "VISIBILITY_GRADIENTS",
    "ViewSet",
    "face_normals",
    "native_available",
    "orient_normals",
    "rasterize",
    "raycast",
    "render",
    "render_silhouette",
    "render_surface",
    "render_views",
    "shade",
    "vertex_normals",
]
