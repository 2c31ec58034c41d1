"""The perceptibility cap: a success outside it is refused, a capped attack keeps its closest step inside it, and the
cap's own parsing and checks (stand-in victim)."""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest

from meshadv.attacks import ShapeAttack, TargetedMisclassification, TextureAttack
from meshadv.mesh import builtin_mesh
from meshadv.perceptibility import DEFAULT_CAP, NO_CAP, PerceptibilityCap, as_cap, recommended_cap
from meshadv.perceptibility.cap import CAP_SLACK
from meshadv.render import RenderSetup, ViewSet, native_available

needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")

#: ddn options for the 48-vertex builtin chair and the stand-in victim (as in tests/test_attacks_cap.py).
OPTIONS = {
    "shape": {"step_size": 3e-2, "final_step_size": 3e-3, "init_budget": 1e-2, "gamma": 0.1},
    "texture": {"step_size": 3e-2, "final_step_size": 3e-3, "init_budget": 2e-2},
}
#: The measure each family's cap bounds in these tests.
MEASURE = {"shape": "max_displacement", "texture": "color_change_p95"}


def _run(perturbation: str, cap: Any) -> Any:
    from stand_in_victims import PooledLinearClassifier

    family = ShapeAttack if perturbation == "shape" else TextureAttack
    attack = family(method="ddn", steps=40, method_options=OPTIONS[perturbation], perceptibility_cap=cap)
    targets = [TargetedMisclassification(728), TargetedMisclassification(247)]  # ranked 2nd and 3rd
    return attack(builtin_mesh("chair"), ViewSet.orbit([40.0], elevation=20.0, distance=2.6), PooledLinearClassifier(),
                  targets, setup=RenderSetup(image_size=64))


@needs_native
def test_the_cap_refuses_a_wrecked_success() -> None:
    free = _run("shape", None)
    assert bool(free.succeeded[0]) and free.perceptibility_cap is None
    moved = free.distances[0]["max_displacement"]
    # the same result judged under a cap its mesh exceeds: its views still say adversarial, the result says failed
    judged = dataclasses.replace(free, perceptibility_cap={"max_displacement": 0.5 * moved})
    assert bool(free.success[0].all()) and not bool(judged.succeeded[0])
    record = judged.to_record()
    assert record["succeeded"][0] is False and record["inside_cap"][0] is False
    assert "outside the perceptibility cap: max_displacement" in judged.summary()
    loose = dataclasses.replace(free, perceptibility_cap={"max_displacement": 2.0 * moved})
    assert bool(loose.succeeded[0])


@needs_native
@pytest.mark.parametrize("perturbation", ["shape", "texture"])
def test_a_capped_attack_never_returns_a_success_outside_the_cap(perturbation: str) -> None:
    measure = MEASURE[perturbation]
    free = _run(perturbation, None)
    assert free.succeeded.any()
    reached = [d[measure] for ok, d in zip(free.succeeded.tolist(), free.distances) if ok]
    ceiling = 0.5 * min(reached)  # below every success the free run found
    capped = _run(perturbation, {measure: ceiling})
    assert capped.config["perceptibility_cap"][measure] == ceiling
    for t, d in enumerate(capped.distances):
        # kept results, successes and failures alike, lie inside the cap: the closest inside, never a wrecked one
        assert d[measure] <= ceiling * (1 + CAP_SLACK), (t, d[measure], ceiling)
        if bool(capped.succeeded[t]):
            assert bool(capped.success[t].all())
    assert bool(capped.inside_cap.all())


@needs_native
def test_a_cap_nothing_fits_in_keeps_the_closest_step_inside_it_and_fails() -> None:
    capped = _run("shape", {"max_displacement": 1e-6})
    assert not capped.succeeded.any()
    for d in capped.distances:
        assert d["max_displacement"] <= 1e-6
    assert "failed" in capped.summary() and "max_displacement <= 1e-06" in capped.summary()


def test_cap_parsing_records_and_checks() -> None:
    cap = PerceptibilityCap.parse("max_displacement=0.03, normal_change_p95_deg=none")
    assert cap.limits == {"max_displacement": 0.03}
    assert PerceptibilityCap.parse("none") is NO_CAP and PerceptibilityCap.parse("default") is DEFAULT_CAP
    assert PerceptibilityCap.from_record(DEFAULT_CAP.to_record()) == DEFAULT_CAP
    assert as_cap(None) is None and as_cap("none") is None and as_cap({"max_displacement": 0.1}) == \
        PerceptibilityCap(max_displacement=0.1)
    assert recommended_cap("shape") == recommended_cap("texture") == DEFAULT_CAP
    assert cap.admits({"max_displacement": 0.03}) and not cap.admits({"max_displacement": 0.031})
    # one mesh measured in float32 and in float64 gets one verdict at the ceiling
    assert cap.admits({"max_displacement": 0.03 * (1 + 1e-7)}) and not cap.admits({"max_displacement": 0.03 * 1.001})
    assert not cap.admits({})  # a bounded measure that is missing is not inside
    assert cap.violations({"max_displacement": 0.05}) == ["max_displacement 0.05 > 0.03"]
    with pytest.raises(ValueError, match="unknown keys"):
        PerceptibilityCap.parse("max_move=0.1")
    with pytest.raises(ValueError, match="not a number"):
        PerceptibilityCap.parse("max_displacement=big")
    with pytest.raises(ValueError, match="NAME=VALUE"):
        PerceptibilityCap.parse("0.02")
    with pytest.raises(ValueError, match="normal_change_p95_deg"):
        PerceptibilityCap(normal_change_p95_deg=200.0)
    with pytest.raises(ValueError, match="max_displacement"):
        PerceptibilityCap(max_displacement=-0.1)
    with pytest.raises(TypeError, match="perceptibility_cap"):
        ShapeAttack(perceptibility_cap=0.02)


def test_sweeps_pin_the_recommended_cap_for_ddn_and_none_for_the_papers_adam() -> None:
    from meshadv.experiments.jobs import default_attack_options

    for perturbation in ("shape", "texture"):
        assert default_attack_options(perturbation, "ddn")["perceptibility_cap"] == DEFAULT_CAP.to_record()
        assert default_attack_options(perturbation, "adam")["perceptibility_cap"] is None
        assert default_attack_options(perturbation, None)["perceptibility_cap"] is None  # the class default: Adam
