"""Loss terms, distances, criteria and the lambda search of meshadv.attacks (no renderer needed)."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from meshadv.attacks import losses
from meshadv.mesh import vertex_edges
from meshadv.attacks.criteria import (
    Disappearance,
    Misclassification,
    TargetedMisclassification,
    resolve_imagenet_classes,
)
from meshadv.attacks.distances import color_rmse, displacement_stats, laplacian_pair_mean, mesh_distances
from meshadv.attacks.search import LambdaSearch

# Two triangles sharing the edge (0, 2): neighbours N(0)={1,2,3}, N(1)={0,2}, N(2)={0,1,3}, N(3)={0,2}.
QUAD_FACES = torch.tensor([[0, 1, 2], [0, 2, 3]])
QUAD_NEIGHBOURS = {0: [1, 2, 3], 1: [0, 2], 2: [0, 1, 3], 3: [0, 2]}


def _hand_laplacian(dv: torch.Tensor) -> float:
    """The paper's double sum written out with explicit neighbour lists."""
    return sum(float((dv[i] - dv[q]).pow(2).sum()) for i, nbrs in QUAD_NEIGHBOURS.items() for q in nbrs)


def test_vertex_edges_of_quad() -> None:
    edges = vertex_edges(QUAD_FACES)
    assert sorted(map(tuple, edges.tolist())) == [(0, 1), (0, 2), (0, 3), (1, 2), (2, 3)]


def test_laplacian_zero_for_rigid_translation() -> None:
    gen = torch.Generator().manual_seed(0)
    shift = torch.randn(3, generator=gen)
    dv = shift.expand(4, 3)
    assert float(losses.laplacian_flow_loss(dv, vertex_edges(QUAD_FACES))) == pytest.approx(0.0, abs=1e-10)
    # but not for a non-rigid flow
    dv2 = dv.clone()
    dv2[1] += 0.1
    assert float(losses.laplacian_flow_loss(dv2, vertex_edges(QUAD_FACES))) > 1e-4


def test_laplacian_matches_hand_computation() -> None:
    dv = torch.zeros(4, 3)
    dv[0, 0] = 1.0
    # vertex 0 has 3 neighbours (3 terms of 1) and is a neighbour of 1, 2, 3 (3 more terms of 1)
    assert float(losses.laplacian_flow_loss(dv, vertex_edges(QUAD_FACES))) == pytest.approx(6.0)
    gen = torch.Generator().manual_seed(1)
    dv = torch.randn(4, 3, generator=gen)
    assert float(losses.laplacian_flow_loss(dv, vertex_edges(QUAD_FACES))) == pytest.approx(_hand_laplacian(dv),
                                                                                           rel=1e-5)


def test_laplacian_batched_and_gradcheck() -> None:
    gen = torch.Generator().manual_seed(2)
    dv = torch.randn(3, 4, 3, generator=gen, dtype=torch.float64, requires_grad=True)
    edges = vertex_edges(QUAD_FACES)
    batched = losses.laplacian_flow_loss(dv, edges).detach()
    assert batched.shape == (3,)
    for b in range(3):
        assert float(batched[b]) == pytest.approx(float(losses.laplacian_flow_loss(dv[b].detach(), edges)))
    assert torch.autograd.gradcheck(lambda x: losses.laplacian_flow_loss(x, edges), (dv,))


def test_laplacian_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="displacement"):
        losses.laplacian_flow_loss(torch.zeros(4, 2), vertex_edges(QUAD_FACES))
    with pytest.raises(ValueError, match="edges"):
        losses.laplacian_flow_loss(torch.zeros(4, 3), torch.tensor([[0, 9]]))


def test_image_smoothness_hand_and_gradcheck() -> None:
    img = torch.zeros(1, 1, 2, 2)
    img[0, 0, 0, 0] = 1.0
    # pixel (0,0) differs from its 2 neighbours; each pair counted from both ends -> 4
    assert float(losses.image_smoothness_loss(img)) == pytest.approx(4.0)
    assert float(losses.image_smoothness_loss(torch.full((2, 3, 5, 5), 0.3))[1]) == 0.0
    mask = torch.zeros(1, 1, 2, 2)
    assert float(losses.image_smoothness_loss(img, mask)) == 0.0
    gen = torch.Generator().manual_seed(3)
    x = torch.rand(2, 3, 4, 5, generator=gen, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(losses.image_smoothness_loss, (x,))


def test_targeted_ce_single_and_grouped() -> None:
    gen = torch.Generator().manual_seed(4)
    logits = torch.randn(5, 10, generator=gen)
    target = torch.tensor([3] * 5)
    assert torch.allclose(losses.targeted_cross_entropy(logits, 3), F.cross_entropy(logits, target, reduction="none"),
                          atol=1e-6)
    group = [2, 5, 7]
    expected = -torch.log(torch.softmax(logits, 1)[:, group].sum(1))
    assert torch.allclose(losses.targeted_cross_entropy(logits, group), expected, atol=1e-5)
    assert torch.allclose(losses.untargeted_cross_entropy(logits, group), -expected, atol=1e-5)


def test_cw_margins_and_kappa() -> None:
    logits = torch.tensor([[1.0, 4.0, 2.0], [5.0, 0.0, 1.0]])
    # target 1: row 0 leads by 2 -> clamped at -kappa; row 1 trails by 5
    out = losses.cw_targeted_margin(logits, 1, kappa=0.5)
    assert out.tolist() == pytest.approx([-0.5, 5.0])
    out = losses.cw_targeted_margin(logits, 1, kappa=10.0)
    assert out.tolist() == pytest.approx([-2.0, 5.0])
    un = losses.cw_untargeted_margin(logits, 0, kappa=1.0)
    assert un.tolist() == pytest.approx([-1.0, 4.0])
    with pytest.raises(ValueError, match="kappa"):
        losses.cw_targeted_margin(logits, 1, kappa=-1.0)


def test_cw_gradient_matches_finite_differences() -> None:
    gen = torch.Generator().manual_seed(5)
    logits = torch.randn(3, 6, generator=gen, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda z: losses.cw_targeted_margin(z, [1, 4], kappa=100.0), (logits,))
    assert torch.autograd.gradcheck(lambda z: losses.targeted_cross_entropy(z, [1, 4]), (logits,))


def test_disappearance_loss_is_max_of_hidden_classes() -> None:
    scores = torch.zeros(2, 4, 3)
    scores[0, 1, 2] = 0.9
    scores[0, 3, 0] = 0.4
    scores[1, 2, 1] = 0.7
    assert losses.disappearance_loss(scores).tolist() == pytest.approx([0.9, 0.7])
    assert losses.disappearance_loss(scores, 0).tolist() == pytest.approx([0.4, 0.0])
    assert losses.disappearance_loss(scores, [0, 1]).tolist() == pytest.approx([0.4, 0.7])
    with pytest.raises(ValueError, match="classes"):
        losses.disappearance_loss(scores, 5)


def test_distances_by_hand() -> None:
    colors = torch.zeros(2, 3)
    adv = torch.tensor([[0.3, 0.0, 0.4], [0.0, 0.0, 0.0]])
    # sqrt((0.25 + 0) / 2)
    assert float(color_rmse(adv, colors)) == pytest.approx(math.sqrt(0.125))
    verts = torch.tensor([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [0.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    dv = torch.zeros(4, 3)
    dv[1, 0] = 1.0
    stats = displacement_stats(dv, verts)
    assert float(stats["max_displacement"]) == pytest.approx(1.0 / 5.0)
    assert float(stats["mean_displacement"]) == pytest.approx(0.25 / 5.0)
    d = mesh_distances(verts, torch.zeros(2, 3), verts + dv, adv, vertex_edges(QUAD_FACES))
    assert d["laplacian_sum"] == pytest.approx(_hand_laplacian(dv))
    num_edges = vertex_edges(QUAD_FACES).shape[0]
    assert d["num_edges"] == num_edges == 5
    assert d["laplacian_pair_mean"] == pytest.approx(_hand_laplacian(dv) / (2 * num_edges))
    assert float(laplacian_pair_mean(dv, vertex_edges(QUAD_FACES))) == pytest.approx(d["laplacian_pair_mean"])
    assert d["color_rmse_per_channel"] == pytest.approx(math.sqrt(0.125 / 3))
    assert d["color_rmse"] == pytest.approx(math.sqrt(0.125))


def test_lambda_search_bisects() -> None:
    search = LambdaSearch(1.0, num_targets=2)
    search.update([True, False])
    assert search.lambdas.tolist() == pytest.approx([10.0, 0.1])
    search.update([False, True])
    assert search.lambdas.tolist() == pytest.approx([5.5, 0.55])
    assert search.largest_success == pytest.approx([1.0, 0.1])
    with pytest.raises(ValueError, match="success"):
        search.update([True])
    with pytest.raises(ValueError, match="initial"):
        LambdaSearch(-1.0)


def test_resolve_classes() -> None:
    idx, label = resolve_imagenet_classes("bicycle")
    assert idx == (444, 671) and label == "bicycle"
    idx, _ = resolve_imagenet_classes("zebra")
    assert idx == (340,)
    assert resolve_imagenet_classes("340")[0] == (340,)
    assert resolve_imagenet_classes([1, 2])[0] == (1, 2)
    with pytest.raises(ValueError, match="target_class"):
        resolve_imagenet_classes("no such class", "target_class")
    with pytest.raises(ValueError, match="indices"):
        resolve_imagenet_classes(1000)


class _FakeClassifier:
    kind = "classifier"


class _FakeDetector:
    kind = "detector"
    class_names = ("person", "dining table", "chair")

    def class_index(self, name: str) -> int:
        return self.class_names.index(name)


class _NamesOnlyDetector:
    """A detector with class names but no class_index: Disappearance.bind looks the names up itself."""

    kind = "detector"
    class_names = _FakeDetector.class_names


def test_criteria_margins() -> None:
    logits = torch.full((2, 1000), -5.0)
    logits[0, 444] = 3.0  # bicycle-built-for-two wins
    logits[1, 340] = 3.0  # zebra wins
    logits[1, 671] = 2.0
    crit = TargetedMisclassification("bicycle").bind(_FakeClassifier())
    assert crit.is_adversarial(logits).tolist() == [True, False]
    assert crit.margin(logits).tolist() == pytest.approx([8.0, -1.0])
    probs = torch.softmax(logits, dim=1)
    assert crit.score(logits).tolist() == pytest.approx((probs[:, 444] + probs[:, 671]).tolist())
    un = Misclassification("bicycle").bind(_FakeClassifier())
    assert un.is_adversarial(logits).tolist() == [False, True]
    with pytest.raises(ValueError, match="victim"):
        crit.bind(_FakeDetector())
    with pytest.raises(ValueError, match="^criterion is not bound"):
        TargetedMisclassification(1).margin(logits)


def test_disappearance_criterion() -> None:
    scores = torch.zeros(2, 5, 3)
    scores[0, 0, 1] = 0.8
    scores[1, 0, 0] = 0.9
    crit = Disappearance("dining table", threshold=0.5).bind(_FakeDetector())
    assert crit.is_adversarial(scores).tolist() == [False, True]
    everything = Disappearance("all").bind(_FakeDetector())
    assert everything.is_adversarial(scores).tolist() == [False, False]
    with pytest.raises(ValueError, match="threshold"):
        Disappearance("chair", threshold=0.0)
    assert Disappearance(["chair", "person"]).bind(_NamesOnlyDetector()).indices == (2, 0)
    with pytest.raises(ValueError, match="^class_name 'giraffe' is not a class of the victim"):
        Disappearance(["chair", "giraffe"]).bind(_NamesOnlyDetector())
