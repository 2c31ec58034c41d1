"""benchmarks/cap_candidates.py: its candidate measures on hand-checkable changes of a built-in mesh (no attack run)."""

from __future__ import annotations

import math

import pytest
import torch

from benchmark_scripts import load_benchmark


def test_candidates_of_a_uniform_scale_a_rotation_and_a_shift() -> None:
    from meshadv.mesh import builtin_mesh

    bench = load_benchmark("cap_candidates")
    mesh = builtin_mesh("chair")
    grown = bench.candidates(mesh, mesh.vertices * 1.2)
    # every edge and every principal stretch grows by 20%, every face's area by 44%, no normal or angle turns
    assert grown["strain_p95"] == pytest.approx(0.2, rel=1e-4) and grown["strain_p99"] == pytest.approx(0.2, rel=1e-4)
    assert grown["principal_p95"] == pytest.approx(0.2, rel=1e-4) and grown["area_p95"] == pytest.approx(0.44, rel=1e-4)
    assert grown["normals_p95"] == pytest.approx(0.0, abs=1e-2) and grown["flipped"] == 0.0
    assert grown["dihedral_p95"] == pytest.approx(0.0, abs=1e-2) and grown["new_selfx"] == 0.0
    assert grown["patch_turn_max"] == pytest.approx(0.0, abs=1e-2)
    assert grown["region_turn_max"] == pytest.approx(0.0, abs=1e-2)
    c, s = math.cos(0.5), math.sin(0.5)
    turned = mesh.vertices @ torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]).T
    rigid = bench.candidates(mesh, turned)
    assert rigid["strain_p95"] == pytest.approx(0.0, abs=1e-5)
    assert rigid["normals_p95"] == pytest.approx(math.degrees(0.5), abs=1e-2)  # a rigid turn turns every normal
    assert rigid["patch_turn_max"] == pytest.approx(math.degrees(0.5), abs=1e-2)
    assert rigid["region_turn_max"] == pytest.approx(math.degrees(0.5), abs=1e-2)
    assert rigid["bend_p95"] > 0.01  # the flow's Laplacian is (R - I) L v: a rotation of a curved mesh bends it
    shifted = bench.candidates(mesh, mesh.vertices + torch.tensor([0.1, 0.0, -0.2]))
    assert shifted["bend_p95"] == pytest.approx(0.0, abs=1e-6) and shifted["move_p95"] > 0
    table = bench.table({"grown": grown}).splitlines()
    assert len(table) == 3 and table[0].count("|") == table[2].count("|") == len(bench.COLUMNS) + 2
