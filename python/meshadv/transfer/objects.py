"""Scenes of several known objects merged into one mesh: the merge, where one object lies in it, what hides it.

Used by the black-box pipeline against a detector (:func:`~meshadv.transfer.blackbox.blackbox_detector`), where the
attacker knows several objects of the scene and changes one of them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Sequence

import torch

if TYPE_CHECKING:
    from meshadv.render import ViewSet

__all__ = ["merge_meshes", "object_range", "occlusion_mask"]


def merge_meshes(meshes: Sequence[Any]) -> Any:
    """One ``meshadv.mesh.Mesh`` holding all ``meshes``, in order (faces re-indexed).

    Args:
        meshes: meshes with ``vertices`` (N_i, 3), ``faces`` (M_i, 3) and ``face_colors`` (M_i, 3).

    Returns:
        The merged mesh (float32 vertices and colours, int64 faces); mesh ``i``'s rows are
        :func:`object_range` ``(meshes, i, ...)``.
    """
    from meshadv.mesh import Mesh

    verts, faces, colors, offset = [], [], [], 0
    for m in meshes:
        verts.append(torch.as_tensor(m.vertices, dtype=torch.float32))
        faces.append(torch.as_tensor(m.faces, dtype=torch.int64) + offset)
        colors.append(torch.as_tensor(m.face_colors, dtype=torch.float32))
        offset += int(m.vertices.shape[0])
    return Mesh(torch.cat(verts), torch.cat(faces), torch.cat(colors))


def object_range(objects: Sequence[Any], index: int, part: str = "faces") -> tuple[int, int]:
    """``(start, stop)``: the rows of object ``index``'s ``part`` (``"faces"`` or ``"vertices"``) in
    :func:`merge_meshes` of ``objects``.

    Example:
        >>> object_range([cube, sphere], 1, "vertices")  # (8, 8 + sphere's vertex count)  # doctest: +SKIP
    """
    start = sum(int(getattr(o, part).shape[0]) for o in objects[:index])
    return start, start + int(getattr(objects[index], part).shape[0])


def occlusion_mask(objects: Sequence[Any], index: int, views: ViewSet, image_size: Any) -> torch.Tensor:
    """Pixels where object ``index`` alone would be drawn but another of ``objects`` is in front of it.

    Args:
        objects: ``meshadv.mesh.Mesh`` objects in world space.
        index: the object of interest.
        views: a one-view ``ViewSet`` (the estimated view).
        image_size: int or (H, W).

    Returns:
        (H, W) float32, 1 where the object is occluded.

    Raises:
        ValueError: ``index`` out of range.
    """
    from meshadv.render import render

    if not 0 <= index < len(objects):
        raise ValueError(f"index {index} out of range for {len(objects)} objects")
    merged = merge_meshes(objects)
    start, stop = object_range(objects, index)
    obj = objects[index]
    with torch.no_grad():
        scene = render(merged.vertices, merged.faces, merged.face_colors, views.camera, views.lights,
                       image_size).face_index[0]
        alone = render(obj.vertices, obj.faces, obj.face_colors, views.camera, views.lights, image_size).face_index[0]
    visible = (scene >= start) & (scene < stop)
    return ((alone >= 0) & ~visible).float()
