"""Every perceptibility measure of an attack's adversarial meshes: surface measures and SSIM on held-out views.

:func:`perceptibility_measures` gives, per adversarial mesh, the surface measures of
:mod:`meshadv.perceptibility.geometry` and the SSIM (:func:`~meshadv.perceptibility.images.render_ssim`) between the
benign and the adversarial renders on the held-out views of :func:`~meshadv.perceptibility.held_out.held_out_views`
(``ssim_held_out_mean``, ``ssim_held_out_min``, and ``dssim_held_out_max = (1 - ssim_held_out_min) / 2``, a
distance for tables), rendered with the attack's own setup.

Example:
    >>> from meshadv.mesh import builtin_mesh
    >>> from meshadv.render import RenderSetup, ViewSet
    >>> mesh = builtin_mesh("chair")
    >>> m = perceptibility_measures(mesh, [mesh], ViewSet.orbit([0.0]), RenderSetup(image_size=32))[0]
    >>> m["max_displacement"], m["ssim_held_out_min"]
    (0.0, 1.0)
"""

from __future__ import annotations

from typing import Any, Dict, List, Sequence

import torch

from meshadv.perceptibility.geometry import SURFACE_MEASURES, surface_measures
from meshadv.perceptibility.images import render_ssim
from meshadv.perceptibility.held_out import held_out_views
from meshadv.render.setup import RenderSetup
from meshadv.render.surface_reflectance import reflectance_of, stacked_reflectance

__all__ = ["perceptibility_measures", "MEASURE_DESCRIPTIONS"]

#: One line per measure, for tables and reports.
MEASURE_DESCRIPTIONS = {
    **SURFACE_MEASURES,
    "ssim_held_out_mean": "mean SSIM of benign vs adversarial renders on held-out views (1 = identical)",
    "ssim_held_out_min": "lowest SSIM of benign vs adversarial renders on held-out views",
    "dssim_held_out_max": "structural dissimilarity (1 - SSIM) / 2 of the least similar held-out view (0 = same)",
}


def perceptibility_measures(mesh: Any, adversarial: Sequence[Any], views: Any, setup: RenderSetup
                            ) -> List[Dict[str, float]]:
    """The measures of :data:`MEASURE_DESCRIPTIONS` for each adversarial version of ``mesh``.

    Args:
        mesh: the pristine ``Mesh``.
        adversarial: adversarial meshes of the same topology.
        views: the attack's ``ViewSet`` (the held-out views are derived from it).
        setup: the attack's render setup.

    Returns:
        One dict of floats per adversarial mesh.

    Raises:
        ValueError: no adversarial mesh, or one of another topology.
    """
    adversarial = list(adversarial)
    if not adversarial:
        raise ValueError("adversarial must hold at least one mesh")
    for i, m in enumerate(adversarial):
        if m.vertices.shape != mesh.vertices.shape or m.faces.shape != mesh.faces.shape:
            raise ValueError(f"adversarial[{i}] has another topology than mesh")
    held = held_out_views(views)
    faces = mesh.faces.long()
    with torch.no_grad():
        # textured meshes render their texture images, others their face colours
        benign, benign_alpha = setup.render(mesh.vertices.detach()[None], faces, reflectance_of(mesh), held)
        verts = torch.stack([m.vertices.detach() for m in adversarial])
        images, alpha = setup.render(verts, faces, stacked_reflectance(adversarial), held)
    num = len(held)
    out = []
    for k, m in enumerate(adversarial):
        record = surface_measures(m.vertices.detach(), m.face_colors.detach(), mesh.vertices.detach(),
                                  mesh.face_colors.detach(), faces)
        ssim = render_ssim(benign, images[k * num:(k + 1) * num], benign_alpha, alpha[k * num:(k + 1) * num])
        record.update(ssim_held_out_mean=float(ssim.mean()), ssim_held_out_min=float(ssim.min()),
                      dssim_held_out_max=(1.0 - float(ssim.min())) / 2.0)
        out.append(record)
    return out
