"""``max_distortion`` caps the ddn budget: a capped run never returns a success above the cap (stand-in victim).

The cap is in the attack's own distance: the Eq. 4 *sum* (``laplacian_sum``) for shape, not the per-pair mean the
paper's tables use, and the face-colour RMSE for texture (docs/guide/attacks.md, "A ceiling on the distortion").
"""

from __future__ import annotations

from typing import Any, Dict, List

import pytest

from meshadv.attacks import ShapeAttack, TargetedMisclassification, TextureAttack
from meshadv.mesh import builtin_mesh, vertex_edges
from meshadv.render import RenderSetup, ViewSet, native_available

needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")

#: ddn options for the 48-vertex builtin chair and the stand-in victim (as in tests/test_attacks_budget.py).
OPTIONS: Dict[str, Dict[str, float]] = {
    "shape": {"step_size": 3e-2, "final_step_size": 3e-3, "init_budget": 1e-2, "gamma": 0.1},
    "texture": {"step_size": 3e-2, "final_step_size": 3e-3, "init_budget": 2e-2},
}
#: The distance each family's ``max_distortion`` bounds.
MEASURE = {"shape": "laplacian_sum", "texture": "color_rmse"}


def _run(perturbation: str, cap: Any) -> Any:
    from stand_in_victims import PooledLinearClassifier

    family = ShapeAttack if perturbation == "shape" else TextureAttack
    attack = family(method="ddn", steps=40, max_distortion=cap, method_options=OPTIONS[perturbation])
    targets = [TargetedMisclassification(728), TargetedMisclassification(247)]  # ranked 2nd and 3rd
    return attack(builtin_mesh("chair"), ViewSet.orbit([40.0], elevation=20.0, distance=2.6), PooledLinearClassifier(),
                  targets, setup=RenderSetup(image_size=64))


def _step_distances(result: Any) -> List[float]:
    return [d for row in result.loss_history for d in row["distance"] if d is not None]


@needs_native
@pytest.mark.parametrize("perturbation", ["shape", "texture"])
def test_capped_ddn_never_returns_a_success_above_the_cap(perturbation: str) -> None:
    free = _run(perturbation, None)
    assert free.succeeded.any()
    finals = [d[MEASURE[perturbation]] for ok, d in zip(free.succeeded.tolist(), free.distances) if ok]
    # a cap between the easiest success and the farthest step the free run took: it binds
    cap = 0.5 * (min(finals) + max(_step_distances(free)))
    assert max(_step_distances(free)) > cap
    capped = _run(perturbation, cap)
    assert capped.config["max_distortion"] == cap
    assert max(_step_distances(capped)) <= cap  # the budget never lets a step past it
    assert capped.succeeded.any()  # the easiest target is still reached, inside the cap
    for ok, d in zip(capped.succeeded.tolist(), capped.distances):
        assert d[MEASURE[perturbation]] <= cap * (1 + 1e-6)
        if ok:
            assert d[MEASURE[perturbation]] < max(_step_distances(free))
    # a cap below every success the free run found: the targets fail rather than return a more distorted mesh
    small = 0.7 * min(finals)
    starved = _run(perturbation, small)
    for d in starved.distances:
        assert d[MEASURE[perturbation]] <= small * (1 + 1e-6)
    assert not starved.succeeded.any()


@needs_native
def test_shape_cap_is_the_eq4_sum_so_a_pair_mean_cap_scales_with_the_edges() -> None:
    mesh = builtin_mesh("chair")
    pairs = 2 * len(vertex_edges(mesh.faces))  # 2E (vertex, neighbour) pairs
    free = _run("shape", None)
    for d in free.distances:
        assert d["laplacian_sum"] == pytest.approx(d["laplacian_pair_mean"] * pairs, rel=1e-5)
    # a per-pair-mean ceiling (the paper's scale) becomes max_distortion = ceiling * 2E
    ceiling = 0.5 * max(d["laplacian_pair_mean"] for d in free.distances)
    capped = _run("shape", ceiling * pairs)
    for d in capped.distances:
        assert d["laplacian_pair_mean"] <= ceiling * (1 + 1e-6)
