"""Exact BVH ray casting (the Rust core's oracle): picking and a cross-check of the rasterizer."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from .. import _validate
from ._checks import require_instance
from ._memory import check_memory, estimate_forward_bytes
from .camera import Camera
from .rasterize import _native, _to_numpy_f32, _to_numpy_i32, parse_image_size

__all__ = ["RayCastOutput", "raycast"]


@dataclass(frozen=True)
class RayCastOutput:
    """Output of :func:`raycast`.

    Attributes:
        face_index: (B,H,W) int64 face hit by the primary ray through each pixel centre, -1 for none.
        depth: (B,H,W) view-space depth of the hit, ``far`` for none.
    """

    face_index: torch.Tensor
    depth: torch.Tensor


def raycast(
    vertices: torch.Tensor,
    faces: torch.Tensor,
    camera: Camera,
    image_size: int | Sequence[int],
    cull_backfaces: bool = False,
    num_threads: int = 0,
) -> RayCastOutput:
    """Cast one ray per pixel centre through a BVH of the mesh (not differentiable).

    Gives the rasterizer's ``face_index``/``depth`` for the same camera except at exact ties and pixel centres within
    rounding of an edge; useful for picking and as an oracle.

    Args:
        vertices: (N,3) or (B,N,3) world-space positions.
        faces: (M,3) integer vertex indices.
        camera: cameras of batch 1 or B.
        image_size: ``int`` or ``(H, W)``.
        cull_backfaces: ignore faces whose normal faces away from the camera.
        num_threads: threads for the native code (0 = all).

    Returns:
        :class:`RayCastOutput` on the device of ``vertices``.

    Raises:
        TypeError: an argument of the wrong type (e.g. ``num_threads="1"`` or ``1.5``).
        ValueError: bad input (shapes, dtypes, indices, image size, thread count).
        MemoryError: the image would not fit in the memory left.
    """
    from .renderer import _check_mesh

    verts, faces = _check_mesh(vertices, faces)
    require_instance(camera, Camera, "camera")
    height, width = parse_image_size(image_size)
    num_threads = _validate.num_threads("num_threads", num_threads)
    cull_backfaces = _validate.boolean("cull_backfaces", cull_backfaces)
    check_memory(estimate_forward_bytes(len(camera), height, width, 0, verts.shape[-2], faces.shape[0]), "raycast")
    with torch.no_grad():
        verts_view = camera.world_to_view(verts)
    b = verts_view.shape[0]
    cam = camera if len(camera) == b else camera[[0] * b]
    f_np = _to_numpy_i32(faces)
    indices, depths = [], []
    for i in range(b):
        idx, depth = _native().raycast(
            _to_numpy_f32(verts_view[i : i + 1]),
            f_np,
            height,
            width,
            float(cam.viewing_angle[i]),
            float(cam.near[i]),
            float(cam.far[i]),
            bool(cam.orthographic),
            float(cam.ortho_scale[i]),
            bool(cull_backfaces),
            int(num_threads),
        )
        indices.append(torch.from_numpy(idx))
        depths.append(torch.from_numpy(depth))
    device = verts.device
    return RayCastOutput(face_index=torch.cat(indices).long().to(device), depth=torch.cat(depths).to(device))
