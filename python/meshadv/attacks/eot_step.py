"""The step and the success check of an EOT attack (:mod:`meshadv.attacks.eot`), in the calling thread.

:func:`eot_step` is :func:`meshadv.attacks.step.serial_step` on one step's draw: the active targets are rendered from
the draw's views with the draw's setup, the draw's blur and noise are applied to the renders, and the victim sees the
result; the perceptual term of the family is computed on the renders before blur and noise. :func:`check_margins`
scores parameters on fresh views without gradients (the success check that decides which parameters are kept).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, List

import torch
from torch import Tensor

from meshadv.attacks.criteria import Criterion
from meshadv.attacks.eot import StepDraw
from meshadv.attacks.outputs import slice_output
from meshadv.attacks.step import AttackCall, StepTerms, adversarial_terms
from meshadv.render.views import ViewSet

if TYPE_CHECKING:
    from meshadv.attacks.base import MeshAttack
    from meshadv.attacks.update import UpdateRule

__all__ = ["eot_step", "check_margins"]


def eot_step(attack: "MeshAttack", p: Tensor, idx: Tensor, criteria: List[Criterion], call: AttackCall,
             draw: StepDraw, rule: "UpdateRule") -> StepTerms:
    """One EOT step: forward on ``draw``, the update rule's objective, ``backward()`` into the parameters' ``.grad``.

    Args:
        attack: the attack.
        p: ``(K, ...)`` the active targets' rows of the parameters (still in their graph).
        idx: int64 ``(K,)`` the active targets.
        criteria: the ``K`` bound criteria.
        call: the attack call (its mesh, victim and edges; its views and setup are replaced by the draw's).
        draw: the step's transformations.
        rule: the update rule, whose ``objective`` is differentiated.

    Returns:
        The step's :class:`~meshadv.attacks.step.StepTerms` (margins ``(K, samples)`` on the transformed images).
    """
    num_v = len(draw.views)
    verts, colors = attack._apply(p, call.mesh, call.edges)
    images, alpha = draw.setup.render(verts, call.mesh.faces, colors, draw.views, rule.edge_gradient)
    output = call.victim(draw.transform(images))
    adv, margins = adversarial_terms(attack, output, criteria, num_v)
    perc, dist = attack._terms(p, call.mesh, call.edges, images, alpha, num_v)
    rule.objective(adv, perc, dist, idx).backward()
    return StepTerms(adv, perc, dist, output, margins)


def check_margins(attack: "MeshAttack", p: Tensor, criteria: List[Criterion], call: AttackCall,
                  views: ViewSet) -> Tensor:
    """Criterion margins ``(K, V)`` of parameters ``p (K, ...)`` rendered from ``views`` with the call's own setup
    (no gradient, no blur or noise): target ``k`` against ``criteria[k]``."""
    num_v = len(views)
    with torch.no_grad():
        verts, colors = attack._apply(p.detach(), call.mesh, call.edges)
        images, _ = call.setup.render(verts, call.mesh.faces, colors, views)
        output: Any = call.victim(images)
        return torch.stack([c.margin(slice_output(output, a * num_v, (a + 1) * num_v)).detach()
                            for a, c in enumerate(criteria)])
