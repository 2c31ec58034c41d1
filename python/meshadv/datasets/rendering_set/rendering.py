"""Rendering a set's meshes: one mesh loaded as the set frames it, its views rendered with the set's options, and
stored records rendered again exactly as they were built."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional

import numpy as np
import torch

from meshadv.datasets.rendering_set.mesh_paths import rendering_mesh_path
from meshadv.datasets.rendering_set.sampling import RenderingSetConfig, sampling_config
from meshadv.datasets.rendering_set.set_file import PathLike

if TYPE_CHECKING:
    from meshadv.mesh import Mesh
    from meshadv.render import ViewSet

__all__ = ["load_set_mesh", "record_views", "render_mesh_views", "render_records"]


def load_set_mesh(path: PathLike, config: RenderingSetConfig) -> tuple[Mesh, np.ndarray]:
    """Load mesh file ``path`` normalised into ``[-1, 1]`` (turned Y-up when ``config.z_up``) as the set uses it.

    Returns:
        The :class:`~meshadv.mesh.Mesh` and its ``(N, 3)`` vertices as float64 NumPy (for framing the views).
    """
    from meshadv.mesh import load_mesh, normalize_mesh

    mesh, _ = normalize_mesh(load_mesh(path), z_up=config.z_up)
    return mesh, mesh.vertices.detach().double().numpy()


def render_mesh_views(mesh: Mesh, view_set: ViewSet, config: RenderingSetConfig) -> torch.Tensor:
    """Render ``mesh`` (its face colours) from every view of ``view_set`` with the set's size, background and
    antialiasing, without gradients.

    Returns:
        ``(V, 3, S, S)`` images in ``[0, 1]``.
    """
    from meshadv.render import render

    with torch.no_grad():
        return render(
            mesh.vertices,
            mesh.faces,
            mesh.face_colors,
            view_set.camera,
            view_set.lights,
            image_size=config.image_size,
            background=config.background,
            antialias=config.antialias,
        ).image


def record_views(records: Sequence[Mapping[str, Any]]) -> ViewSet:
    """The :class:`meshadv.render.ViewSet` of rendering-set records (their ``"view"`` entries).

    Args:
        records: entries of ``doc["renderings"]`` (typically those of one mesh).
    """
    from meshadv.render import ViewSet

    return ViewSet.from_records([rec["view"] for rec in records])


def render_records(
    doc: Mapping[str, Any], records: Sequence[Mapping[str, Any]], mesh_root: Optional[PathLike] = None
) -> torch.Tensor:
    """Re-render rendering-set records exactly as the set was built (same mesh normalisation, views, options).

    Args:
        doc: the rendering-set document (for its sampling options).
        records: entries of ``doc["renderings"]``.
        mesh_root: folder of relative mesh paths (see :func:`~meshadv.datasets.rendering_set.rendering_mesh_path`).

    Returns:
        ``(len(records), 3, S, S)`` images in ``[0, 1]``.
    """
    if not records:
        raise ValueError("records must not be empty")
    config = sampling_config(doc)
    images: list[Optional[torch.Tensor]] = [None] * len(records)
    by_mesh: dict[Path, list[int]] = {}
    for i, rec in enumerate(records):
        by_mesh.setdefault(rendering_mesh_path(rec, mesh_root), []).append(i)
    for path, indices in by_mesh.items():
        mesh, _ = load_set_mesh(path, config)
        rendered = render_mesh_views(mesh, record_views([records[i] for i in indices]), config)
        for j, i in enumerate(indices):
            images[i] = rendered[j]
    return torch.stack([img for img in images if img is not None])
