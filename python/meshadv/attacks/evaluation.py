"""Scoring meshes against criteria from scratch: the measurement every attack result reports.

:func:`evaluate` renders meshes (no gradients, no jitter) and scores each against its criterion; the attack loop
measures its final meshes with it, never with the optimiser's last images.

Example:
    >>> from meshadv.attacks import TargetedMisclassification, evaluate
    >>> scored = evaluate(mesh, views, victim, TargetedMisclassification("bicycle"))   # doctest: +SKIP
    >>> scored.success.shape                                                            # doctest: +SKIP
    torch.Size([1, 4])
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional, Sequence, Union

import torch
from torch import Tensor

from meshadv.attacks.criteria import Criterion, as_criteria
from meshadv.attacks.outputs import slice_output
from meshadv.render.setup import RenderSetup
from meshadv.render.surface_reflectance import stacked_reflectance

__all__ = ["Evaluation", "evaluate"]


@dataclass(frozen=True)
class Evaluation:
    """Meshes re-rendered from scratch and scored against criteria (:func:`evaluate`).

    Attributes:
        margins: ``(T, V)`` criterion margins (``> 0``: adversarial).
        scores: ``(T, V)`` criterion scores.
        images: ``(K, V, 3, H, W)`` the renders (``K`` meshes).
        top1: ``(K, V)`` top-1 classes for a classifier, else ``None``.
    """

    margins: Tensor
    scores: Tensor
    images: Tensor
    top1: Optional[Tensor]

    @property
    def success(self) -> Tensor:
        """``(T, V)`` bool: ``margins > 0``."""
        return self.margins > 0


def evaluate(meshes: Union[Any, Sequence[Any]], views: Any, victim: Any,
             criterion: Union[Criterion, Sequence[Criterion]], *, setup: Optional[RenderSetup] = None) -> Evaluation:
    """Render ``meshes`` from ``views`` with ``setup`` (no gradients) and score them against each criterion.

    One mesh is scored against every criterion; ``T`` meshes are scored one-to-one against ``T`` criteria.

    Args:
        meshes: a ``Mesh`` or a sequence of meshes sharing one topology.
        views: a ``ViewSet`` of ``V`` views.
        victim: the victim.
        criterion: a criterion (bound or not) or a sequence of them.
        setup: the render setup (default ``RenderSetup()``).

    Returns:
        An :class:`Evaluation`.

    Raises:
        ValueError: no mesh or no criterion, or several meshes but a different number of criteria.
    """
    meshes = [meshes] if hasattr(meshes, "vertices") else list(meshes)
    if not meshes or not all(hasattr(m, "vertices") for m in meshes):
        raise ValueError("meshes must be a Mesh or a non-empty sequence of meshes")
    criteria = as_criteria(criterion)
    shared = len(meshes) == 1
    if not shared and len(meshes) != len(criteria):
        raise ValueError(f"meshes ({len(meshes)}) must be one mesh or one per criterion ({len(criteria)})")
    criteria = [c.bind(victim) for c in criteria]  # binding is idempotent
    setup = setup or RenderSetup()
    num_v = len(views)
    verts = torch.stack([m.vertices for m in meshes])
    colors = stacked_reflectance(meshes)
    with torch.no_grad():
        images, _ = setup.render(verts, meshes[0].faces, colors, views)
        output = victim(images)
        parts = [slice_output(output, 0, num_v) if shared else slice_output(output, t * num_v, (t + 1) * num_v)
                 for t in range(len(criteria))]
        margins = torch.stack([c.margin(o) for c, o in zip(criteria, parts)])
        scores = torch.stack([c.score(o) for c, o in zip(criteria, parts)])
        top1 = output.argmax(dim=1).view(len(meshes), num_v) if isinstance(output, Tensor) else None
    return Evaluation(margins, scores, images.view(len(meshes), num_v, *images.shape[1:]), top1)
