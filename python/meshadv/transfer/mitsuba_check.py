"""Check the scene conversion (:func:`conversion_check`): Mitsuba's and meshadv's renders of the same mesh, camera
and lights agree.

With interreflection off (``max_depth = 2``: camera ray + one bounce toward the lights) and the lighting matched, the
two images of a *convex* shape agree away from silhouette edges up to Monte-Carlo noise of the ambient term (which
Mitsuba integrates over the hemisphere by sampling). Remaining, documented differences:

* Anti-aliasing: Mitsuba averages many sub-pixel samples; meshadv samples the pixel centre (``antialias = 1``), so
  edge pixels differ. They are excluded here (one pixel either side of the silhouette).
* Ambient occlusion: meshadv's ambient is unoccluded; Mitsuba's constant environment is shadowed by the object
  itself, darkening concave regions (none on a convex shape).
* Shadows and interreflection (``max_depth > 2``): only Mitsuba has them.
* Noise: the ambient term has Monte-Carlo variance ~ ``1/spp``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional

import numpy as np
import torch

from meshadv.mesh.surface_mesh import SurfaceMesh
from meshadv.render import Camera, Lights, ViewSet, render, render_surface
from meshadv.transfer.mitsuba_process import render_scenes
from meshadv.transfer.mitsuba_spec import MeshObject, MitsubaCamera, mask_spec, scene_spec

__all__ = ["ConversionCheck", "conversion_check", "head_light_record", "mask_iou"]


@dataclass(frozen=True)
class ConversionCheck:
    """Agreement of Mitsuba and meshadv renders.

    Attributes:
        mask_iou: IoU of the coverage masks (Mitsuba with one ray per pixel centre).
        mean_abs_difference: mean absolute RGB difference over interior pixels (away from edges).
        p95_abs_difference: 95th percentile of the per-pixel mean absolute difference over interior pixels.
        interior_pixels: number of interior pixels compared.
        variant: the Mitsuba variant used.
        meshadv_image: (H, W, 3) meshadv's render; mitsuba_image: (H, W, 3) Mitsuba's.
    """

    mask_iou: float
    mean_abs_difference: float
    p95_abs_difference: float
    interior_pixels: int
    variant: str
    meshadv_image: np.ndarray
    mitsuba_image: np.ndarray

    def summary(self) -> dict[str, Any]:
        """The numbers as a JSON-able dict."""
        return {
            "mask_iou": self.mask_iou,
            "mean_abs_difference": self.mean_abs_difference,
            "p95_abs_difference": self.p95_abs_difference,
            "interior_pixels": self.interior_pixels,
            "variant": self.variant,
        }


def _erode(mask: np.ndarray) -> np.ndarray:
    """Binary erosion by one pixel (4-neighbourhood); the border counts as outside."""
    m = np.pad(mask, 1, constant_values=False)
    return m[1:-1, 1:-1] & m[:-2, 1:-1] & m[2:, 1:-1] & m[1:-1, :-2] & m[1:-1, 2:]


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """IoU of two masks thresholded at 0.5.

    Raises:
        ValueError: the shapes differ.
    """
    a, b = np.asarray(a) > 0.5, np.asarray(b) > 0.5
    if a.shape != b.shape:
        raise ValueError(f"masks must have the same shape, got {a.shape} and {b.shape}")
    union = (a | b).sum()
    return float((a & b).sum() / union) if union else 1.0


def conversion_check(
    mesh: Any,
    record: dict[str, Any],
    *,
    image_size: int = 96,
    spp: int = 256,
    variant: Optional[str] = None,
    timeout: float = 600.0,
    shading: Optional[str] = None,
) -> ConversionCheck:
    """Render ``mesh`` with meshadv and with Mitsuba (direct light only) under one view record and compare.

    Args:
        mesh: a ``meshadv.mesh.Mesh`` (per-face colours, flat), or a ``meshadv.mesh.SurfaceMesh`` (its texture as a
            bitmap with its UVs, or its vertex colours, and for smooth shading the same vertex normals, in both
            renderers).
        record: a ``ViewSet.to_records()`` record (camera and lights).
        image_size: square image side.
        spp: Mitsuba samples per pixel for the shaded image.
        variant: Mitsuba variant.
        timeout: seconds for the Mitsuba call.
        shading: for a ``SurfaceMesh``, ``"flat"`` or ``"smooth"`` (default: what the mesh asks for).

    Returns:
        The :class:`ConversionCheck`.
    """
    views = ViewSet.from_records([record])
    with torch.no_grad():
        if isinstance(mesh, SurfaceMesh):
            if mesh.texture is None and mesh.vertex_colors is None:
                raise ValueError("mesh: a SurfaceMesh is compared with its texture or vertex colours; this one has "
                                 "neither")
            shading = shading or mesh.shading
            ours = render_surface(
                mesh.mesh.vertices, mesh.mesh.faces, views.camera, views.lights, image_size, texture=mesh.texture,
                uvs=mesh.uvs, uv_faces=mesh.uv_faces, vertex_colors=mesh.vertex_colors, normals=mesh.normals,
                normal_faces=mesh.normal_faces, shading=shading, background=(1.0, 1.0, 1.0),
            )
            obj = MeshObject.from_surface(mesh, shading)
        else:
            ours = render(mesh.vertices, mesh.faces, mesh.face_colors, views.camera, views.lights, image_size,
                          background=(1.0, 1.0, 1.0))
            obj = MeshObject.from_mesh(mesh)
    ours_img = ours.image[0].permute(1, 2, 0).numpy()
    ours_mask = ours.alpha[0, 0].numpy() > 0.5
    shaded = scene_spec(obj, record, lights=record, image_size=image_size, spp=spp, max_depth=2,
                        background=(1.0, 1.0, 1.0))
    mask = mask_spec(obj, MitsubaCamera.from_record(record), image_size, spp=1)
    theirs, theirs_mask = render_scenes([shaded, mask], variant=variant, timeout=timeout)
    both = _erode(ours_mask) & _erode(theirs_mask.alpha > 0.5) & _erode(theirs.alpha > 0.999)
    diff = np.abs(ours_img - theirs.image).mean(axis=-1)[both]
    return ConversionCheck(
        mask_iou=mask_iou(ours_mask, theirs_mask.alpha),
        mean_abs_difference=float(diff.mean()) if diff.size else float("nan"),
        p95_abs_difference=float(np.percentile(diff, 95)) if diff.size else float("nan"),
        interior_pixels=int(both.sum()),
        variant=theirs.variant,
        meshadv_image=ours_img,
        mitsuba_image=theirs.image,
    )


def head_light_record(distance: float, azimuth: float, elevation: float, light: float, ambient: float,
                      viewing_angle: float = 30.0) -> dict[str, Any]:
    """A one-view record (``ViewSet.to_records()``) of a spherical camera with a head light (toward the camera,
    slightly offset) of intensity ``light`` and an ambient light ``ambient``."""
    camera = Camera.spherical(distance, azimuth, elevation, viewing_angle=viewing_angle)
    direction = (camera.eye() - camera.target()).detach()
    lights = Lights(direction.unsqueeze(1) + 0.3, [[light] * 3], [ambient] * 3)
    return ViewSet(camera, lights).to_records()[0]
