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


@needs_native
def test_an_edge_strain_ceiling_nothing_fits_in_keeps_the_closest_step_inside_it_and_fails() -> None:
    free = _run("shape", None)
    assert max(d["edge_strain_p95"] for d in free.distances) > 1e-4  # the free attack strains its edges
    capped = _run("shape", {"edge_strain_p95": 1e-4})
    assert not capped.succeeded.any()
    for d in capped.distances:
        assert d["edge_strain_p95"] <= 1e-4 * (1 + CAP_SLACK)
    assert "failed" in capped.summary() and "edge_strain_p95 <= 0.0001" in capped.summary()


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


def _sheet(nx: int, ny: int, length: float, width: float, height: float = 0.0) -> "tuple[Any, Any]":
    """A flat ``nx`` x ``ny`` grid of triangles in the plane ``z = height``: vertices ``(nx * ny, 3)``, faces."""
    import torch

    x, y = torch.meshgrid(torch.linspace(0, length, nx), torch.linspace(0, width, ny), indexing="ij")
    vertices = torch.stack([x.flatten(), y.flatten(), torch.full((nx * ny,), height)], dim=1)
    index = torch.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = (index[:-1, :-1].flatten(), index[1:, :-1].flatten(), index[1:, 1:].flatten(),
                  index[:-1, 1:].flatten())
    return vertices, torch.cat([torch.stack([a, b, c], dim=1), torch.stack([a, c, d], dim=1)])


def _thin_plate() -> "tuple[Any, Any]":
    """A wing-like plate: two sheets 1 x 0.25, 0.01 apart (1% of its length), facing away from each other."""
    import torch

    top, faces = _sheet(41, 11, 1.0, 0.25, 0.005)
    bottom = top - torch.tensor([0.0, 0.0, 0.01])
    return torch.cat([top, bottom]), torch.cat([faces, faces.flip(1) + top.shape[0]])


def _verdict(cap: PerceptibilityCap, moved: Any, vertices: Any, faces: Any) -> "tuple[bool, list]":
    """The per-step check's verdict on ``moved`` and the ceilings the result's measures exceed."""
    import torch

    from meshadv.perceptibility import surface_measures
    from meshadv.perceptibility.cap import step_measures

    colors = torch.zeros(faces.shape[0], 3)
    inside = cap.admits(step_measures(cap, moved[None], colors, vertices, colors, faces))
    return bool(inside[0]), cap.violations(surface_measures(moved, colors, vertices, colors, faces))


def test_the_default_cap_refuses_a_thin_plate_broken_into_fragments_that_moves_and_turns_little() -> None:
    import torch

    vertices, faces = _thin_plate()
    diagonal = float((vertices.max(dim=0).values - vertices.min(dim=0).values).norm())
    # the trailing 40% of the plate broken up: each vertex there jittered by at most 1% of the diagonal
    trailing = vertices[:, 1] > 0.15
    jitter = torch.rand(vertices.shape, generator=torch.Generator().manual_seed(0)) * 2 - 1
    jitter = jitter * torch.tensor([1.0, 1.0, 0.3])
    jitter = jitter / jitter.norm(dim=1, keepdim=True).clamp(min=1.0)
    broken = vertices + 0.01 * diagonal * jitter * trailing[:, None]
    inside, violations = _verdict(DEFAULT_CAP, broken, vertices, faces)
    assert not inside and [v.split()[0] for v in violations] == ["edge_strain_p95"]
    # the older ceilings alone pass it: it moves 1% of the diagonal and turns 95% of the area by less than 25 degrees
    older = dataclasses.replace(DEFAULT_CAP, edge_strain_p95=None)
    assert _verdict(older, broken, vertices, faces) == (True, [])


def test_the_default_cap_refuses_a_thin_plate_torn_open_along_its_closed_edge() -> None:
    import torch

    vertices, faces = _thin_plate()
    n = vertices.shape[0] // 2
    last_row = torch.arange(n).reshape(41, 11)[:, -1]  # the sheets' edge y = 0.25, closed by a wall 0.01 high
    a, b = last_row[:-1], last_row[1:]
    faces = torch.cat([faces, torch.stack([a, b, b + n], dim=1), torch.stack([a, b + n, a + n], dim=1)])
    diagonal = float((vertices.max(dim=0).values - vertices.min(dim=0).values).norm())
    # the trailing 60% of the plate opened: the top sheet pulled up and the bottom one down, smoothly, by up to
    # 1.8% of the diagonal at the edge, so the wall's 0.01 grows to about 0.047
    ramp = ((vertices[:, 1] - 0.1) / 0.15).clamp(0.0, 1.0)
    side = torch.cat([torch.ones(n), -torch.ones(n)])
    torn = vertices.clone()
    torn[:, 2] += 0.018 * diagonal * ramp * side
    inside, violations = _verdict(DEFAULT_CAP, torn, vertices, faces)
    assert not inside and [v.split()[0] for v in violations] == ["edge_strain_max"]
    # the percentile ceilings alone pass it: the wall's edges are under 5% of the edge length, its faces of the area
    percentiles = dataclasses.replace(DEFAULT_CAP, edge_strain_max=None)
    assert _verdict(percentiles, torn, vertices, faces) == (True, [])


def test_the_default_cap_refuses_a_fold_and_passes_a_smooth_small_bend() -> None:
    import math

    import torch

    vertices, faces = _sheet(41, 11, 1.0, 0.25)
    diagonal = float((vertices.max(dim=0).values - vertices.min(dim=0).values).norm())
    x = vertices[:, 0]
    # a fold across the sheet: a band of 12% of its length pushed in by 1.2% of the diagonal, gathered to its line
    t = ((x - 0.5) / 0.06).clamp(-1.0, 1.0)
    band = ((x - 0.5).abs() < 0.06).float()
    folded = vertices.clone()
    folded[:, 2] -= 0.012 * diagonal * band * torch.cos(t * math.pi / 2) ** 2
    folded[:, 0] -= 0.012 * diagonal * band * torch.sin(t * math.pi)
    inside, violations = _verdict(DEFAULT_CAP, folded, vertices, faces)
    assert not inside and [v.split()[0] for v in violations] == ["edge_strain_p95"]
    # the whole sheet bent smoothly by 1% of the diagonal: inside every ceiling
    bent = vertices.clone()
    bent[:, 2] += 0.01 * diagonal * torch.sin(math.pi * x)
    assert _verdict(DEFAULT_CAP, bent, vertices, faces) == (True, [])


def test_the_edge_strain_ceiling_parses_and_must_be_positive() -> None:
    cap = PerceptibilityCap.parse("edge_strain_p95=0.1")
    assert cap.limits == {"edge_strain_p95": 0.1}
    assert not cap.admits({"edge_strain_p95": 0.11}) and cap.admits({"edge_strain_p95": 0.1})
    assert DEFAULT_CAP.edge_strain_p95 is not None and "edge_strain_p95" in DEFAULT_CAP.describe()
    with pytest.raises(ValueError, match="edge_strain_p95"):
        PerceptibilityCap(edge_strain_p95=0.0)
