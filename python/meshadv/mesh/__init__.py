"""The mesh layer: load, clean, normalise, resample, save, adjacency and curvature of triangle meshes.

See docs/ARCHITECTURE.md ("Meshes") for the contract. The main entry points are :func:`load_mesh`,
:func:`normalize_mesh`, :func:`resample_mesh`, :func:`save_mesh`, :func:`vertex_edges`, :func:`mean_curvature`,
:func:`builtin_mesh`, :func:`default_mesh` and :class:`Pascal3DCatalog`.
"""

from meshadv.mesh.errors import MeshLoadError, MeshProcessingError
from meshadv.mesh.io import DEFAULT_MAX_FACES, LoadReport, load_mesh, load_mesh_with_report, save_mesh
from meshadv.mesh.structure import Mesh

__all__ = [
    "DEFAULT_MAX_FACES",
    "LoadReport",
    "Mesh",
    "MeshLoadError",
    "MeshProcessingError",
    "load_mesh",
    "load_mesh_with_report",
    "save_mesh",
]
