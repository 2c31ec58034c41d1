"""meshadv.transfer pipeline: results table, controlled transfer, sweep reader, black-box pipeline and CLI."""

from __future__ import annotations

from pathlib import Path
from typing import NoReturn
import json
import sqlite3

import pytest
import torch

from cli_output import unwrapped
from meshadv.render import native_available
from meshadv.victims import Victim
from meshadv.transfer.results import (
    confusion_matrices,
    load_transfer_rows,
    per_target_table,
    save_transfer_rows,
    transfer_report,
    transfer_table,
)

needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")


def _row(case: str, view: int, true: str, target: str, ok_ours: bool, ok_theirs: bool, victim: str = "v1") -> dict:
    return {"case_id": case, "victim": victim, "true_class": true, "target": target, "perturbation": "shape",
            "view": view, "success_meshadv": ok_ours, "success_mitsuba": ok_theirs,
            "untargeted_meshadv": True, "untargeted_mitsuba": ok_theirs or view == 0}


def test_results_roundtrip_tables_and_confusion(tmp_path: Path) -> None:
    db = tmp_path / "results.db"
    rows = [
        _row("a", 0, "chair", "sofa", True, True),
        _row("a", 1, "chair", "sofa", True, False),
        _row("b", 0, "chair", "boat", True, False),
        _row("c", 0, "sofa", "chair", True, True),
    ]
    assert save_transfer_rows(db, rows, experiment="t") == 4
    # Writing the same (experiment, kind, case, view) again replaces instead of duplicating.
    save_transfer_rows(db, [_row("c", 0, "sofa", "chair", True, False)], experiment="t")
    loaded = load_transfer_rows(db, experiment="t")
    assert len(loaded) == 4 and {r["kind"] for r in loaded} == {"controlled"}
    table = transfer_table(loaded)
    assert len(table) == 1
    assert table[0]["targeted_meshadv"] == pytest.approx(1.0)
    assert table[0]["targeted_mitsuba"] == pytest.approx(1 / 4)
    assert table[0]["untargeted_mitsuba"] == pytest.approx(3 / 4)  # a/1 is the only miss
    assert table[0]["n_benign_correct"] == 0 and table[0]["untargeted_mitsuba_benign_correct"] is None
    per_target = {r["target"]: r for r in per_target_table(loaded)}
    assert per_target["sofa"]["targeted_mitsuba"] == pytest.approx(0.5)
    names, matrix = confusion_matrices(loaded)["v1"]
    assert names == ["boat", "chair", "sofa"]
    assert matrix[1][2] == pytest.approx(0.5) and matrix[1][0] == pytest.approx(0.0)
    assert matrix[2][1] == pytest.approx(0.0) and matrix[0][0] is None
    text = transfer_report(loaded)
    assert "Controlled parameters" in text and "| chair |" in text
    with sqlite3.connect(db) as conn:  # lives beside any other table of the results database
        assert conn.execute("SELECT COUNT(*) FROM transfer").fetchone()[0] == 4
    with pytest.raises(ValueError, match=r"^rows\[0\] is missing keys"):
        save_transfer_rows(db, [{"case_id": "x"}])
    with pytest.raises(ValueError, match="kind"):
        save_transfer_rows(db, rows, kind="other")
    with pytest.raises(FileNotFoundError, match="^db_path .*missing.db"):
        load_transfer_rows(tmp_path / "missing.db")


@pytest.fixture(scope="module")
def victim() -> Victim:
    from meshadv.victims import load_victim

    return load_victim("efficientnet_lite0")


def _views(n: int) -> list:
    from meshadv.render import ViewSet

    return ViewSet.orbit([20.0 + 40.0 * i for i in range(n)], elevation=15.0, distance=3.0).to_records()


@needs_native
def test_controlled_transfer_tiny_run_produces_its_table(tmp_path: Path, victim: Victim) -> None:
    pytest.importorskip("mitsuba")
    from meshadv.mesh import builtin_mesh
    from meshadv.transfer.controlled import TransferCase, controlled_transfer
    from meshadv.victims.labels import PASCAL3D_TO_IMAGENET, imagenet_class_names

    case = TransferCase("case0", builtin_mesh("bottle"), tuple(_views(2)), "efficientnet_lite0", "bottle",
                        target="chair", perturbation="texture", image_size=64)
    rows = controlled_transfer([case], spp=8, victim_loader=lambda name: victim, image_dir=tmp_path / "img")
    assert len(rows) == 2 and (tmp_path / "img" / "case0_v1.png").is_file()
    names = imagenet_class_names()
    bottle = {names[i] for i in PASCAL3D_TO_IMAGENET["bottle"]}
    chair = {names[i] for i in PASCAL3D_TO_IMAGENET["chair"]}
    for row in rows:
        assert row.untargeted_mitsuba == (row.top1_mitsuba not in bottle)
        assert row.success_mitsuba == (row.top1_mitsuba in chair)
        assert row.untargeted_meshadv == (row.top1_meshadv not in bottle)
        assert 0.0 <= row.mean_abs_image_difference < 0.2
    db = tmp_path / "results.db"
    save_transfer_rows(db, [row.to_record() for row in rows], experiment="tiny")
    table = transfer_table(load_transfer_rows(db))
    assert table[0]["n"] == 2 and table[0]["victim"] == "efficientnet_lite0"
    assert "efficientnet_lite0" in confusion_matrices(load_transfer_rows(db))


@needs_native
def test_controlled_transfer_survives_a_crashed_render(monkeypatch: pytest.MonkeyPatch, victim: Victim) -> None:
    from meshadv.mesh import builtin_mesh
    from meshadv.transfer import controlled
    from meshadv.transfer.mitsuba_process import MitsubaRenderError

    def crash(*args: object, **kwargs: object) -> NoReturn:
        raise MitsubaRenderError("Mitsuba (llvm_ad_rgb) was killed by signal 6")

    monkeypatch.setattr(controlled, "render_scenes", crash)
    case = controlled.TransferCase("c", builtin_mesh("cube"), tuple(_views(1)), "efficientnet_lite0", "bottle")
    rows = controlled.controlled_transfer([case], victim_loader=lambda name: victim)
    assert len(rows) == 1 and "signal 6" in rows[0].error and rows[0].success_mitsuba is None
    with pytest.raises(MitsubaRenderError, match="killed by signal 6"):
        controlled.controlled_transfer([case], victim_loader=lambda name: victim, on_error="raise")


def _fake_sweep(tmp_path: Path) -> tuple[Path, list]:
    """A sweep database with two finished texture attacks (one successful), as the experiment runner writes them."""
    from meshadv.experiments import ResultStore
    from meshadv.mesh import builtin_mesh, save_mesh

    db = tmp_path / "results.db"
    specs = [
        {"kind": "single", "victim": "efficientnet_lite0", "source_class": "bottle", "target": "chair",
         "perturbation": "texture", "mesh": {"name": "bottle"}, "seed": s}
        for s in (0, 1)
    ]
    views = _views(1)
    with ResultStore(db) as store:
        store.add_jobs(specs)
        for i, row in enumerate(store.rows()):
            out = tmp_path / f"job{i}"
            out.mkdir()
            save_mesh(builtin_mesh("bottle"), out / "adversarial.ply")
            (out / "result.json").write_text(json.dumps(
                {"views": views, "meshes": [["adversarial.ply", "adversarial.obj"]],
                 "config": {"image_size": [64, 64], "antialias": 2}}))
            store.mark_running(row.job_id)
            store.mark_done(row.job_id, {"success": row.spec["seed"] == 0, "benign_correct": True}, str(out))
    return db, views


def test_cases_from_store_reads_finished_attacks(tmp_path: Path) -> None:
    from meshadv.mesh import builtin_mesh
    from meshadv.transfer.controlled import cases_from_store

    db, views = _fake_sweep(tmp_path)
    cases = cases_from_store(db)
    assert len(cases) == 1
    case = cases[0]
    assert (case.victim, case.true_class, case.target, case.perturbation) == ("efficientnet_lite0", "bottle",
                                                                              "chair", "texture")
    assert case.image_size == (64, 64) and case.views[0]["azimuth"] == pytest.approx(views[0]["azimuth"])
    assert case.benign_correct is True
    assert case.antialias == 2, "the meshadv reference render uses the attack's supersampling"
    assert case.mesh.faces.shape == builtin_mesh("bottle").faces.shape
    assert len(cases_from_store(db, only_successful=False)) == 2
    with pytest.raises(FileNotFoundError, match="^db_path .*nope.db"):
        cases_from_store(tmp_path / "nope.db")


def store_rows(db: Path) -> list:
    """The rows of the sweep database ``db``."""
    from meshadv.experiments import ResultStore

    with ResultStore(db, read_only=True) as store:
        return store.rows()


def test_cases_from_store_leaves_out_retries_of_stages_the_config_no_longer_has(tmp_path: Path) -> None:
    from meshadv.experiments import ResultStore
    from meshadv.experiments.retries import retry_spec
    from meshadv.transfer.controlled import cases_from_store

    db, _ = _fake_sweep(tmp_path)
    with ResultStore(db) as store:
        failed = next(r for r in store.rows() if r.spec["seed"] == 1)
        store.add_jobs([retry_spec(failed.spec, failed.job_id, {"steps": 60})])
        retry = store.rows()[-1]
        store.mark_running(retry.job_id)
        store.mark_done(retry.job_id, {"success": True, "benign_correct": True}, failed.out_dir)
        store.set_meta("config_text", "[attack.retry]\ntexture = { steps = 60 }\n")
    assert retry.job_id in [c.case_id for c in cases_from_store(db)] and len(cases_from_store(db)) == 2
    with ResultStore(db) as store:
        store.set_meta("config_text", "[attack.retry]\ntexture = { steps = 90 }\n")  # the stage changed since
    main_success = next(r for r in store_rows(db) if r.spec["seed"] == 0)
    assert [c.case_id for c in cases_from_store(db)] == [main_success.job_id]


@needs_native
def test_blackbox_classifier_tiny_run(victim: Victim) -> None:
    pytest.importorskip("mitsuba")
    from meshadv.mesh import builtin_mesh
    from meshadv.transfer.blackbox import blackbox_classifier
    from meshadv.transfer.robust import Robustness
    from meshadv.transfer.setups import outdoor_classifier_setup

    mesh = builtin_mesh("chair")
    hidden = outdoor_classifier_setup(mesh, camera={"distance": 3.2, "azimuth": 50.0, "elevation": 20.0},
                                      image_size=64, spp=8)
    steps = []
    robustness = Robustness(eot=2, margin=1.5, pixel_noise=0.01, verify_samples=3)
    row = blackbox_classifier(mesh, hidden, victim=victim, true_class="chair", perturbation="texture",
                              attack_kwargs={"steps": 2, "antialias": 2}, robustness=robustness,
                              camera_steps=20, light_steps=20, callback=lambda info: steps.append(info.step))
    public = row.to_record()
    json.dumps(public)  # JSON-able
    for key in ("azimuth_error", "elevation_error", "distance_error", "light_rmse", "mask_iou", "direction_error",
                "success_meshadv", "success_mitsuba", "success_mitsuba_estimated", "benign_correct_mitsuba",
                "margin_meshadv", "margin_mitsuba", "margin_mitsuba_estimated", "margin_benign_mitsuba",
                "top1_meshadv", "top1_mitsuba_estimated", "color_rmse", "steps_run", "attack_time"):
        assert key in public, key
    assert public["mask_iou"] > 0.8
    assert steps == [0, 1] and public["steps_run"] == 2
    assert (public["eot"], public["required_margin"], public["pixel_noise"], public["antialias"]) == (2, 1.5, 0.01, 2)
    # The successes are the signs of the margins (margin 0: the required margin is for the attack only).
    for where in ("meshadv", "mitsuba", "mitsuba_estimated"):
        assert public[f"success_{where}"] == (public[f"margin_{where}"] > 0)
    rate = public["robust_rate_meshadv"]
    assert rate is not None and round(rate * 3) == rate * 3 and 0.0 <= rate <= 1.0  # 3 verification views
    assert set(row.images) == {"benign_mitsuba", "adversarial_mitsuba", "adversarial_mitsuba_estimated",
                                   "adversarial_meshadv"}
    assert all(im.shape == (64, 64, 3) for im in row.images.values())
    assert torch.as_tensor(row.adversarial_mesh.face_colors).shape == mesh.face_colors.shape
    # Mitsuba under the estimates differs from meshadv's render (renderer mismatch) but not by much.
    diff = abs(row.images["adversarial_mitsuba_estimated"] - row.images["adversarial_meshadv"]).mean()
    assert 0.0 < diff < 0.1


@needs_native
def test_cli_transfer_check_and_report(tmp_path: Path) -> None:
    pytest.importorskip("mitsuba")
    from typer.testing import CliRunner

    from meshadv.cli import build_app

    app = build_app({"transfer": "transfer:transfer"})
    runner = CliRunner()
    result = runner.invoke(app, ["transfer", "check", "builtin:sphere", "--size", "32", "--spp", "16",
                                 "-o", str(tmp_path / "check")])
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "check" / "check.json").read_text())
    assert summary["mask_iou"] > 0.95
    db = tmp_path / "results.db"
    save_transfer_rows(db, [_row("a", 0, "chair", "sofa", True, True)])
    result = runner.invoke(app, ["transfer", "report", str(db)])
    assert result.exit_code == 0 and "Transfer to Mitsuba 3" in result.output
    result = runner.invoke(app, ["transfer", "report", str(tmp_path / "missing.db")])
    assert result.exit_code == 2, result.output  # a usage error naming the argument, not a crash
    message = unwrapped(result.output)
    assert "Invalid value for RESULTS: " in message and message.endswith("does not exist"), message


@needs_native
def test_cli_controlled_transfer_is_resumable(tmp_path: Path) -> None:
    pytest.importorskip("mitsuba")
    from typer.testing import CliRunner

    from meshadv.cli import build_app

    db, _ = _fake_sweep(tmp_path)
    app = build_app({"transfer": "transfer:transfer"})
    runner = CliRunner()
    result = runner.invoke(app, ["transfer", "controlled", str(db), "--spp", "4", "--all"])
    assert result.exit_code == 0, result.output
    assert "transferring 2" in result.output and "Controlled parameters" in result.output
    assert len(load_transfer_rows(db, kind="controlled")) == 2
    result = runner.invoke(app, ["transfer", "controlled", str(db), "--spp", "4", "--all"])
    assert result.exit_code == 0 and "transferring 0" in result.output
