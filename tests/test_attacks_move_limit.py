"""The largest-move projection: a cap's ``max_displacement`` is enforced inside the optimisation, for ddn and Adam
alike (every rendered step stays inside it), and the projection changes nothing inside the cap (stand-in victim)."""

from __future__ import annotations

from typing import Any, List, Tuple

import pytest
import torch
from torch import Tensor

from meshadv.attacks import ShapeAttack, TargetedMisclassification
from meshadv.attacks.move_limit import scale_factors, shorten_moves
from meshadv.mesh import builtin_mesh, vertex_edges
from meshadv.perceptibility.cap import CAP_SLACK
from meshadv.render import RenderSetup, ViewSet, native_available

needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")

#: ddn options for the 48-vertex builtin chair and the stand-in victim (as in tests/test_perceptibility_cap.py).
DDN_OPTIONS = {"step_size": 3e-2, "final_step_size": 3e-3, "init_budget": 1e-2, "gamma": 0.1}


class RecordingShapeAttack(ShapeAttack):
    """A shape attack that records the largest vertex move (over the bounding-box diagonal) of every mesh a step
    renders to differentiate (the calls with gradients on; the cap's checks and the final meshes run without)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.moves: List[float] = []

    def apply(self, params: Tensor, mesh: Any, edges: Tensor) -> Tuple[Tensor, Any]:
        verts, colors = super().apply(params, mesh, edges)
        if not torch.is_grad_enabled():
            return verts, colors
        diagonal = float((mesh.vertices.max(0).values - mesh.vertices.min(0).values).norm())
        self.moves.extend((verts.detach() - mesh.vertices).norm(dim=-1).amax(dim=-1).div(diagonal).tolist())
        return verts, colors


def _run(cap: Any, **kwargs: Any) -> Tuple[Any, RecordingShapeAttack]:
    from stand_in_victims import PooledLinearClassifier

    attack = RecordingShapeAttack(steps=30, perceptibility_cap=cap, **kwargs)
    targets = [TargetedMisclassification(728), TargetedMisclassification(247)]  # ranked 2nd and 3rd
    result = attack(builtin_mesh("chair"), ViewSet.orbit([40.0], elevation=20.0, distance=2.6),
                    PooledLinearClassifier(), targets, setup=RenderSetup(image_size=64))
    return result, attack


def test_shorten_moves_is_the_projection_onto_the_largest_move() -> None:
    flow = torch.tensor([[[3.0, 4.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 0.0]]])
    out = shorten_moves(flow, 1.0)
    # (3, 4, 0) has length 5: pulled back along itself to length 1; the others are inside and kept
    assert out[0, 0].tolist() == pytest.approx([0.6, 0.8, 0.0])
    assert torch.equal(out[0, 1:], flow[0, 1:])
    assert torch.equal(shorten_moves(flow, 5.0), flow)  # inside (on the boundary): unchanged
    assert scale_factors(flow, 1.0).tolist() == pytest.approx([0.2])
    assert scale_factors(flow, 10.0).tolist() == [1.0]
    with pytest.raises(ValueError, match="radius"):
        shorten_moves(flow, 0.0)
    with pytest.raises(ValueError, match="flow"):
        shorten_moves(torch.zeros(3, 2), 1.0)


@pytest.mark.parametrize("smoothing", [0, 3])
def test_limit_moves_is_a_no_op_inside_and_bounds_every_vertex_outside(smoothing: int) -> None:
    mesh = builtin_mesh("chair")
    edges = vertex_edges(mesh.faces).long()
    attack = ShapeAttack(smoothing=smoothing)
    gen = torch.Generator().manual_seed(0)
    params = 0.01 * torch.randn(2, mesh.num_vertices, 3, generator=gen)
    params[1] *= 30.0  # row 1 moves far, row 0 stays inside the radius
    reach = attack.displacement(params, edges).norm(dim=-1).amax(dim=1)
    radius = float(reach.mean())  # between the two rows' largest moves
    assert float(reach[0]) < radius < float(reach[1])
    inside_before = params[0].clone()
    assert attack.limit_moves(params, torch.tensor([0, 1]), edges, radius)
    assert torch.equal(params[0], inside_before)  # the row inside is left exactly as it was
    moves = attack.displacement(params, edges).norm(dim=-1)
    assert float(moves[1].max()) <= radius * (1 + 1e-6)
    assert float(moves[1].max()) > 0.99 * radius  # pulled to the limit, not further
    again = params.clone()
    assert not attack.limit_moves(params, torch.tensor([0, 1]), edges, radius)  # now inside: nothing to do
    assert torch.equal(params, again)


@needs_native
@pytest.mark.parametrize("method, kwargs", [
    ("ddn", {"method_options": DDN_OPTIONS}),
    ("adam", {"lr": 5e-2}),
    ("adam", {"lr": 5e-2, "smoothing": 4}),
])
def test_a_tiny_cap_never_lets_a_vertex_move_beyond_it(method: str, kwargs: Any) -> None:
    free, free_attack = _run(None, method=method, **kwargs)
    ceiling = 0.1 * max(free_attack.moves)  # a tenth of the farthest the free attack went
    assert max(free_attack.moves) > ceiling
    capped, attack = _run({"max_displacement": ceiling}, method=method, **kwargs)
    # every rendered step (the first one is the pristine mesh) and the kept results
    assert len(attack.moves) == 2 * 30
    assert max(attack.moves) <= ceiling * (1 + CAP_SLACK)
    assert max(attack.moves) > 0.5 * ceiling  # the steps go up to the limit: the optimiser works inside it
    for d in capped.distances:
        assert d["max_displacement"] <= ceiling * (1 + CAP_SLACK)
    assert bool(capped.inside_cap.all())


@needs_native
@pytest.mark.parametrize("method, kwargs", [("ddn", {"method_options": DDN_OPTIONS}), ("adam", {"lr": 5e-2})])
def test_a_cap_the_attack_stays_inside_changes_nothing(method: str, kwargs: Any) -> None:
    free, free_attack = _run(None, method=method, **kwargs)
    roomy, roomy_attack = _run({"max_displacement": 2.0 * max(free_attack.moves)}, method=method, **kwargs)
    assert roomy_attack.moves == free_attack.moves
    assert roomy.loss_history == free.loss_history
    for a, b in zip(free.adversarial, roomy.adversarial):
        assert torch.equal(a.vertices, b.vertices)
