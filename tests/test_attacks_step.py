"""One step of the attack loop (meshadv.attacks.loop.attack_step): the update rule's ``edge_gradient`` weights the
rasterization part of the shape gradient, and its ``visibility_gradient`` chooses it."""

from __future__ import annotations

from typing import Any, List

import pytest
import torch

from meshadv.render import RenderSetup, native_available

needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")


def _views(num: int) -> Any:
    from meshadv.render import ViewSet

    return ViewSet.orbit([40.0 + 35.0 * i for i in range(num)], elevation=20.0, distance=2.6)


class _SumRule:
    """A rule whose objective uses every term, so that the perceptual and distance terms must backprop too; its
    renders weight the rasterization gradient ``visibility_gradient`` by ``edge_gradient``."""

    def __init__(self, weights: torch.Tensor, edge_gradient: float = 1.0, visibility_gradient: str = "nmr") -> None:
        self.weights = weights
        self.edge_gradient = edge_gradient
        self.visibility_gradient = visibility_gradient

    def objective(self, adv: torch.Tensor, perc: torch.Tensor, dist: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        return (adv + self.weights[idx] * perc + 0.5 * self.weights[idx] * dist).sum()


def _call(mesh: Any, views: Any, victim: Any, size: int = 48) -> Any:
    from meshadv.attacks.loop import AttackCall
    from meshadv.mesh.adjacency import vertex_edges

    return AttackCall(mesh, views.detach(), victim, RenderSetup(image_size=size, antialias=2),
                      vertex_edges(mesh.faces).long())


def _step_grads(attack: Any, call: Any, criteria: List[Any], params: torch.Tensor, idx: torch.Tensor,
                edge_gradient: float = 1.0, visibility_gradient: str = "nmr") -> Any:
    from meshadv.attacks.loop import attack_step

    rule = _SumRule(torch.tensor([0.3, 2.0, 0.7, 1.5]), edge_gradient, visibility_gradient)
    p = params.detach().clone().requires_grad_(True)
    bound = [c.bind(call.victim) for c in criteria]
    out = attack_step(attack, p[idx], idx, bound, call, call.views, rule)
    return p.grad, out


@needs_native
def test_the_rules_edge_gradient_weights_the_rasterization_part_of_every_step() -> None:
    """A rule's ``edge_gradient`` reaches the step's renders: the shape gradient is the shading part plus ``w``
    times the rasterization part (linear in ``w``)."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import ShapeAttack, TargetedMisclassification
    from meshadv.mesh import builtin_mesh

    mesh = builtin_mesh("chair")
    attack = ShapeAttack()
    call = _call(mesh, _views(2), PooledLinearClassifier())
    params = 0.02 * torch.randn(attack.initial_params(mesh, 2).shape, generator=torch.Generator().manual_seed(2))
    idx = torch.tensor([0, 1])
    criteria = [TargetedMisclassification(c) for c in (728, 247)]
    serial = {w: _step_grads(attack, call, criteria, params, idx, w)[0] for w in (0.0, 0.25, 1.0)}
    assert float((serial[1.0] - serial[0.0]).abs().max()) > 0.1 * float(serial[1.0].abs().max())
    torch.testing.assert_close(serial[0.25], 0.75 * serial[0.0] + 0.25 * serial[1.0],
                               rtol=1e-4, atol=1e-5 * float(serial[1.0].abs().max()))


@needs_native
def test_the_rules_visibility_gradient_reaches_the_renders_of_every_step() -> None:
    """A rule's ``visibility_gradient`` reaches the step's renders: the local one changes the shape gradient, and
    with no rasterization part (``edge_gradient`` 0) both give the same (shading) gradient."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import ShapeAttack, TargetedMisclassification
    from meshadv.mesh import builtin_mesh

    mesh = builtin_mesh("chair")
    attack = ShapeAttack()
    call = _call(mesh, _views(2), PooledLinearClassifier())
    params = 0.02 * torch.randn(attack.initial_params(mesh, 2).shape, generator=torch.Generator().manual_seed(2))
    idx = torch.tensor([0, 1])
    criteria = [TargetedMisclassification(c) for c in (728, 247)]
    nmr = _step_grads(attack, call, criteria, params, idx)[0]
    local = _step_grads(attack, call, criteria, params, idx, visibility_gradient="local")[0]
    assert float((nmr - local).abs().max()) > 1e-3 * float(nmr.abs().max())
    shading = [_step_grads(attack, call, criteria, params, idx, 0.0, v)[0] for v in ("nmr", "local")]
    torch.testing.assert_close(shading[0], shading[1])
