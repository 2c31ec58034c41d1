"""The one attack loop on a bare machine: stand-in classifier and detector, built-in meshes, no weights, no data.

Covers what the loop promises whatever the victim: batched targets behave as separate runs, Ctrl-C keeps the best
so far, the distortion budget stops a target, masks hold, the scene setup's static objects occlude, and a custom
update rule plugs in through ``method=``.
"""

from __future__ import annotations

from typing import Any, Sequence

import pytest
import torch
from stand_in_victims import DarkBlobDetector, PooledLinearClassifier

from meshadv.attacks import (
    Disappearance,
    ShapeAttack,
    TargetedMisclassification,
    TextureAttack,
    UpdateRule,
    evaluate,
    register_update_rule,
)
from meshadv.mesh import builtin_mesh
from meshadv.render import RenderSetup, StaticObject, ViewSet, native_available

pytestmark = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")

SETUP = RenderSetup(image_size=32)


def _views(n: int = 1) -> Any:
    return ViewSet.orbit([40.0 + 30.0 * i for i in range(n)], elevation=20.0, distance=2.6)


def test_batched_targets_equal_separate_runs() -> None:
    victim, mesh = PooledLinearClassifier(), builtin_mesh("sofa")
    attack = TextureAttack(steps=5, lr=0.05)
    crits = [TargetedMisclassification(728), TargetedMisclassification(247)]
    batched = attack(mesh, _views(), victim, crits, setup=SETUP)
    for t, crit in enumerate(crits):
        alone = attack(mesh, _views(), victim, crit, setup=SETUP)
        torch.testing.assert_close(batched.adversarial[t].face_colors, alone.mesh.face_colors, rtol=0, atol=1e-5)


def test_interrupt_keeps_the_best_so_far_and_budget_stops() -> None:
    victim, mesh = PooledLinearClassifier(), builtin_mesh("chair")

    def stop(info: Any) -> None:
        if info.total_step == 2:
            raise KeyboardInterrupt

    result = ShapeAttack(steps=50, lr=0.02)(mesh, _views(), victim, TargetedMisclassification(728), setup=SETUP,
                                            callback=stop)
    assert result.interrupted and result.steps == 2
    tiny = ShapeAttack(steps=50, lr=0.02, lambda_perceptual=0.0, max_distortion=1e-12)
    capped = tiny(mesh, _views(), victim, TargetedMisclassification(728), setup=SETUP)
    assert capped.steps < 50 and not bool(capped.succeeded[0])


def test_face_mask_and_vertex_mask_hold() -> None:
    victim, mesh = PooledLinearClassifier(), builtin_mesh("cube")
    faces = torch.zeros(mesh.num_faces, dtype=torch.bool)
    faces[::2] = True
    tex = TextureAttack(steps=5, lr=0.2, face_mask=faces)(mesh, _views(), victim, TargetedMisclassification(728),
                                                          setup=SETUP)
    changed = (tex.mesh.face_colors - mesh.face_colors).abs().amax(dim=1) > 0
    assert bool(changed[faces].any()) and not bool(changed[~faces].any())
    verts = torch.zeros(mesh.num_vertices, dtype=torch.bool)
    verts[::2] = True
    shp = ShapeAttack(steps=5, lr=0.05, vertex_mask=verts)(mesh, _views(), victim, TargetedMisclassification(728),
                                                           setup=SETUP)
    moved = (shp.mesh.vertices - mesh.vertices).abs().amax(dim=1) > 0
    assert bool(moved[verts].any()) and not bool(moved[~verts].any())
    assert tex.config["face_mask"]["indices"] == list(range(0, mesh.num_faces, 2))
    assert tex.config["image_size"] == [32, 32]
    with pytest.raises(ValueError, match="face_mask has 4 entries"):
        TextureAttack(face_mask=torch.ones(4, dtype=torch.bool))(mesh, _views(), victim, TargetedMisclassification(1),
                                                                 setup=SETUP)


def test_static_objects_occlude_the_attacked_mesh() -> None:
    """A white wall in front of a dark cube hides it from the dark-blob detector: nothing to attack."""
    cube = builtin_mesh("cube", color=(0.1, 0.1, 0.1))
    views = ViewSet.orbit([0.0], elevation=0.0, distance=4.0)
    wall = builtin_mesh("cube", color=(1.0, 1.0, 1.0))
    wall_verts = wall.vertices * torch.tensor([3.0, 3.0, 0.05]) + torch.tensor([0.0, 0.0, -2.0])
    hidden = RenderSetup(image_size=32, static=(StaticObject("wall", wall_verts, wall.faces, wall.face_colors),))
    crit = Disappearance("blob")
    visible = evaluate(cube, views, DarkBlobDetector(), crit, setup=SETUP)
    occluded = evaluate(cube, views, DarkBlobDetector(), crit, setup=hidden)
    assert not bool(visible.success.all()) and bool(occluded.success.all())


class _SignSGD(UpdateRule):
    """A custom rule for the test: one round, ``p -= lr * sign(grad)`` on the adversarial loss only."""

    def __init__(self, *, attack: Any, num_targets: int, lr: float = 0.01) -> None:
        self.lr, self.num_targets, self.calls = lr, num_targets, []

    @property
    def lambdas(self) -> torch.Tensor:
        return torch.zeros(self.num_targets)

    def start_round(self, params: torch.Tensor) -> None:
        self.params = params

    def objective(self, adv: torch.Tensor, perceptual: torch.Tensor, distance: torch.Tensor,
                  active: torch.Tensor) -> torch.Tensor:
        return adv.sum()

    def step(self, params: torch.Tensor, active: torch.Tensor, is_adversarial: torch.Tensor) -> None:
        self.calls.append((active.tolist(), is_adversarial.tolist()))
        with torch.no_grad():
            params -= self.lr * params.grad.sign()
        params.grad = None

    def end_round(self, successes: Sequence[bool]) -> None:
        self.calls.append(("end", list(successes)))


def test_a_registered_update_rule_drives_the_loop() -> None:
    made = []

    def factory(**kwargs: Any) -> UpdateRule:
        made.append(_SignSGD(**kwargs))
        return made[-1]

    register_update_rule("test_sign_sgd", factory)
    attack = TextureAttack(steps=3, method="test_sign_sgd", method_options={"lr": 0.1})
    assert attack.config()["method"] == "test_sign_sgd" and attack.config()["method_options"] == {"lr": 0.1}
    result = attack(builtin_mesh("sofa"), _views(), PooledLinearClassifier(), TargetedMisclassification(728),
                    setup=SETUP)
    rule = made[-1]
    assert [c[0] for c in rule.calls[:3]] == [[0], [0], [0]] and rule.calls[-1][0] == "end"
    assert result.steps == 3 and float((result.mesh.face_colors - builtin_mesh("sofa").face_colors).abs().max()) > 0
    with pytest.raises(ValueError, match="already registered"):
        register_update_rule("test_sign_sgd", factory)
