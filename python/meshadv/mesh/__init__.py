"""The mesh layer: load, clean, normalise, resample, save, adjacency and curvature of triangle meshes.

See docs/ARCHITECTURE.md ("Meshes") for the contract. The main entry points are :func:`load_mesh`,
:func:`normalize_mesh`, :func:`resample_mesh`, :func:`save_mesh`, :func:`vertex_edges`, :func:`mean_curvature`,
:func:`builtin_mesh`, :func:`default_mesh` and :class:`Pascal3DCatalog`.
"""

from meshadv.mesh.adjacency import (
    boundary_vertex_mask,
    face_adjacency,
    is_watertight,
    uniform_laplacian,
    vertex_degrees,
    vertex_edges,
    vertex_neighbors,
)
from meshadv.mesh.catalog import PASCAL3D_CLASSES, Pascal3DCatalog
from meshadv.mesh.curvature import mean_curvature
from meshadv.mesh.errors import MeshLoadError, MeshProcessingError
from meshadv.mesh.io import DEFAULT_MAX_FACES, LoadReport, load_mesh, load_mesh_with_report, save_mesh
from meshadv.mesh.normalize import NormalizeTransform, normalize_mesh, pascal3d_azimuth_to_renderer
from meshadv.mesh.resample import ResampleInfo, default_cache_dir, resample_mesh, resample_mesh_with_info
from meshadv.mesh.shapes import BUILTIN_SHAPES, builtin_mesh, class_mesh, default_mesh
from meshadv.mesh.structure import Mesh, bbox_diagonal

__all__ = [
    "BUILTIN_SHAPES",
    "DEFAULT_MAX_FACES",
    "PASCAL3D_CLASSES",
    "LoadReport",
    "Mesh",
    "MeshLoadError",
    "MeshProcessingError",
    "NormalizeTransform",
    "Pascal3DCatalog",
    "ResampleInfo",
    "bbox_diagonal",
    "boundary_vertex_mask",
    "builtin_mesh",
    "class_mesh",
    "default_cache_dir",
    "default_mesh",
    "face_adjacency",
    "is_watertight",
    "load_mesh",
    "load_mesh_with_report",
    "mean_curvature",
    "normalize_mesh",
    "pascal3d_azimuth_to_renderer",
    "resample_mesh",
    "resample_mesh_with_info",
    "save_mesh",
    "uniform_laplacian",
    "vertex_degrees",
    "vertex_edges",
    "vertex_neighbors",
]
