"""Files a user keeps are written atomically (:mod:`meshadv.util.atomic`: a temporary file in the same folder, then
``os.replace``), and an interrupted run leaves nothing a later run trusts wrongly.

Atomicity is checked by recording every ``os.replace`` while a writer runs: a kept file that was not moved into place
by one was written in place, and a kill in the middle of that write leaves it truncated.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Callable, List, Set

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from cli_output import unwrapped
from sweep_fixtures import probe_jobs, run_probe_sweep


@pytest.fixture
def replaced(monkeypatch: pytest.MonkeyPatch) -> Set[Path]:
    """The resolved destinations of every ``os.replace`` made while the test runs."""
    seen: Set[Path] = set()
    real = os.replace

    def recording(src: Any, dst: Any, **kwargs: Any) -> None:
        real(src, dst, **kwargs)
        seen.add(Path(dst).resolve())

    monkeypatch.setattr(os, "replace", recording)
    return seen


def _files(folder: Path) -> Set[Path]:
    return {p.resolve() for p in folder.rglob("*") if p.is_file()}


def _probe_db(tmp_path: Path) -> Path:
    jobs = [{**j, "success": j["source_class"] == "boat"} for j in probe_jobs(["boat", "chair"])]
    return run_probe_sweep(tmp_path / "r.db", jobs, tmp_path / "run")


def test_report_writes_every_file_atomically(tmp_path: Path, replaced: Set[Path]) -> None:
    """Tables, README (with a caller's section), settings.json, figures and proxies.csv all go through os.replace."""
    from meshadv.experiments.report import write_report

    db = _probe_db(tmp_path)
    out = tmp_path / "rep"
    report = write_report(db, out, figures=True, sections=[lambda done, folder: ("## Extra section\n", [])])
    written = _files(out)
    assert {"README.md", "settings.json", "table1.md", "table1.csv", "paper_comparison.md"} <= {p.name for p in written}
    assert report.figures, "the probe sweep has figures to draw"
    assert written - replaced == set(), "written in place, not atomically"
    readme = (out / "README.md").read_text(encoding="utf-8")
    assert readme.endswith("\n## Extra section\n") and readme.startswith("# Results")


def _fake_regeneration(calls: List[str]) -> Callable[..., Any]:
    """A stand-in for ``regenerate_job``: copies the stored artefacts into the target folder."""
    import shutil

    from meshadv.experiments.regenerate import Regenerated
    from meshadv.experiments.store import ResultStore

    def regenerate_job(db_path: Path, job: str, out_dir: Path, **_kwargs: Any) -> Any:
        calls.append(job)
        with ResultStore(db_path, read_only=True) as store:
            row = next(r for r in store.rows() if r.job_id == job)
        shutil.copytree(str(row.out_dir), str(out_dir), dirs_exist_ok=True)
        return Regenerated(job, Path(out_dir), dict(row.record or {}), row.record, [])

    return regenerate_job


def test_a_truncated_regeneration_check_is_regenerated_not_fatal(tmp_path: Path, replaced: Set[Path],
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """regeneration.json is written atomically; one cut short (a kill under a version that wrote it in place) makes
    the next report regenerate the job instead of failing on the JSON."""
    import meshadv.experiments.regenerate as regenerate
    from meshadv.experiments.artifact_source import ArtifactSource
    from meshadv.experiments.store import ResultStore

    db = _probe_db(tmp_path)
    calls: List[str] = []
    monkeypatch.setattr(regenerate, "regenerate_job", _fake_regeneration(calls))
    with ResultStore(db, read_only=True) as store:
        row = next(r for r in store.rows() if r.state == "done")
    root = tmp_path / "regen"
    folder = ArtifactSource(db, root, use_stored=False).folder(row)
    assert folder is not None and calls == [row.job_id]
    check_file = folder / "regeneration.json"
    assert check_file.resolve() in replaced
    again = ArtifactSource(db, root, use_stored=False)
    assert again.folder(row) == folder and calls == [row.job_id], "a complete regeneration is reused"
    text = check_file.read_text(encoding="utf-8")
    check_file.write_text(text[: len(text) // 2], encoding="utf-8")
    third = ArtifactSource(db, root, use_stored=False)
    assert third.folder(row) == folder and calls == [row.job_id, row.job_id]
    assert json.loads(check_file.read_text(encoding="utf-8"))["job_id"] == row.job_id


def _blackbox_result(interrupted: bool) -> Any:
    from meshadv.mesh import builtin_mesh
    from meshadv.transfer.results import BlackBoxResult

    row = {"case_id": "case", "victim": "v", "true_class": "aeroplane", "target": "", "perturbation": "texture",
           "view": 0, "success_meshadv": True, "success_mitsuba": False, "steps": 100,
           "steps_run": 3 if interrupted else 100, "interrupted": interrupted}
    images = {"benign_mitsuba": np.zeros((8, 8, 3)), "adversarial_meshadv": np.ones((8, 8, 3))}
    return BlackBoxResult(row=row, images=images, adversarial_mesh=builtin_mesh("sphere"),
                          attack_result=SimpleNamespace(loss_history=[{"loss": [1.0]}]))


def _run_blackbox(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, interrupted: bool, *extra: str,
                  runs: Any = None) -> Any:
    """``transfer blackbox-classifier --db tmp/t.db -o tmp/out`` with a stand-in pipeline (appends to ``runs``)."""
    import meshadv.transfer.blackbox as blackbox
    import meshadv.transfer.setups as setups
    import meshadv.victims as victims
    from meshadv.cli import build_app

    def pipeline(*_args: Any, **_kwargs: Any) -> Any:
        if runs is not None:
            runs.append(1)
        return _blackbox_result(interrupted)

    monkeypatch.setattr(blackbox, "blackbox_classifier", pipeline)
    monkeypatch.setattr(setups, "default_aeroplane", lambda: None)
    monkeypatch.setattr(setups, "outdoor_classifier_setup", lambda *a, **k: None)
    monkeypatch.setattr(victims, "load_victim", lambda name: name)
    return CliRunner().invoke(build_app({"transfer": "transfer:transfer"}),
                              ["transfer", "blackbox-classifier", "--db", str(tmp_path / "t.db"),
                               "-o", str(tmp_path / "out"), "--progress", "0", "--case-id", "case", *extra])


def test_blackbox_writes_its_folder_atomically_and_stores_a_finished_row(
        tmp_path: Path, replaced: Set[Path], monkeypatch: pytest.MonkeyPatch) -> None:
    from meshadv.transfer.results import load_transfer_rows

    result = _run_blackbox(monkeypatch, tmp_path, interrupted=False)
    assert result.exit_code == 0, result.output
    written = _files(tmp_path / "out")
    assert {"blackbox.json", "loss_history.json", "adversarial.ply", "benign_mitsuba.png"} <= {p.name for p in written}
    assert written - replaced == set(), "written in place, not atomically"
    assert [r["case_id"] for r in load_transfer_rows(tmp_path / "t.db", kind="blackbox")] == ["case"]


def test_an_interrupted_blackbox_attack_keeps_its_files_but_not_a_row(tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C / SIGTERM stops the attack with its best mesh so far: the folder keeps it (flagged), the database does
    not get a row that reads like a finished run, and the command exits 130."""
    result = _run_blackbox(monkeypatch, tmp_path, interrupted=True)
    assert result.exit_code == 130, result.output
    assert "interrupted after 3 of 100 attack steps" in unwrapped(result.output)
    assert json.loads((tmp_path / "out" / "blackbox.json").read_text())["interrupted"] is True
    assert not (tmp_path / "t.db").exists()


def test_blackbox_resume_skips_a_finished_case_and_reruns_an_interrupted_one(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``--resume``: a list of black-box commands run again after a kill redoes only the unfinished runs."""
    from meshadv.transfer.results import load_transfer_rows

    runs: List[int] = []
    interrupted = _run_blackbox(monkeypatch, tmp_path, True, "--resume", runs=runs)
    assert interrupted.exit_code == 130 and len(runs) == 1
    finished = _run_blackbox(monkeypatch, tmp_path, False, "--resume", runs=runs)
    assert finished.exit_code == 0 and len(runs) == 2, "an interrupted run left no row: it runs again"
    skipped = _run_blackbox(monkeypatch, tmp_path, False, "--resume", runs=runs)
    assert skipped.exit_code == 0 and len(runs) == 2, skipped.output
    assert "case: already in" in unwrapped(skipped.output) and "skipped (--resume)" in unwrapped(skipped.output)
    other = _run_blackbox(monkeypatch, tmp_path, False, "--resume", "--experiment", "other", runs=runs)
    assert other.exit_code == 0 and len(runs) == 3, "another experiment's row does not count"
    again = _run_blackbox(monkeypatch, tmp_path, False, runs=runs)
    assert again.exit_code == 0 and len(runs) == 4, "without --resume the run is made again"
    assert len(load_transfer_rows(tmp_path / "t.db", kind="blackbox")) == 2  # (blackbox, case) and (other, case)


def test_blackbox_resume_needs_a_database(monkeypatch: pytest.MonkeyPatch) -> None:
    import meshadv.transfer.blackbox as blackbox
    from meshadv.cli import build_app

    monkeypatch.setattr(blackbox, "blackbox_classifier", lambda *a, **k: pytest.fail("ran without --db"))
    result = CliRunner().invoke(build_app({"transfer": "transfer:transfer"}),
                                ["transfer", "blackbox-detector", "--resume"])
    assert result.exit_code == 2 and "--resume needs --db" in unwrapped(result.output)


def test_blackbox_rows_say_whether_the_attack_was_interrupted() -> None:
    from meshadv.transfer.blackbox import _attack_record

    attack = SimpleNamespace(config=lambda: {"steps": 100, "lr": 0.01, "lambda_perceptual": 0.0, "loss": "ce",
                                             "kappa": 0.0, "early_stop": None})
    for interrupted in (True, False):
        result = SimpleNamespace(steps=3, steps_to_success=[None], wall_time=1.0, distances=[{"color_rmse": 0.1}],
                                 interrupted=interrupted)
        record = _attack_record(attack, SimpleNamespace(antialias=1), result)
        assert record["interrupted"] is interrupted and record["steps_run"] == 3


def test_scene_attack_records_an_interruption() -> None:
    from stand_in_victims import DarkBlobDetector

    from meshadv.attacks import Disappearance
    from meshadv.scenes.attack import attack_scene

    def stopped_attack(*_args: Any, **_kwargs: Any) -> Any:
        return SimpleNamespace(original_images=torch.zeros(1, 3, 64, 64), images=torch.ones(1, 1, 3, 64, 64),
                               success=torch.tensor([[True]]), succeeded=torch.tensor([True]), mesh=None,
                               success_rate=torch.ones(1), success_fraction=1.0, eval_success=None,
                               eval_scores=None, held_out_fraction=None,
                               original_scores=torch.ones(1, 1),
                               scores=torch.zeros(1, 1), distances=[{"color_rmse": 0.1}],
                               loss_history=[{"loss": [0.5]}], steps=2, wall_time=0.1, config={}, interrupted=True)

    setup = SimpleNamespace(mesh=None, views=lambda: None, render_setup=lambda antialias: None)
    result = attack_scene(stopped_attack, setup, DarkBlobDetector(), Disappearance("blob", threshold=0.5))
    assert result.interrupted and result.to_record()["interrupted"] is True


def test_saving_over_an_earlier_result_never_leaves_its_record_beside_new_files(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A kill while a new result replaces an old one in the same folder leaves no result.json (the folder reads as
    incomplete), not the old record describing meshes that were already replaced."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import TargetedMisclassification, TextureAttack
    from meshadv.attacks.result import load_result_record
    from meshadv.mesh import builtin_mesh
    from meshadv.render import RenderSetup, ViewSet, native_available

    if not native_available():
        pytest.skip("native module meshadv._raster not built")
    views = ViewSet.orbit([40.0], elevation=20.0, distance=2.6)
    result = TextureAttack(steps=1, lr=0.05)(builtin_mesh("sofa"), views, PooledLinearClassifier(),
                                             TargetedMisclassification(728), setup=RenderSetup(image_size=32))
    result.save(tmp_path)
    assert load_result_record(tmp_path)["steps"] == 1
    real = os.replace
    moves: List[str] = []

    def killed_after_one_move(src: Any, dst: Any, **kwargs: Any) -> None:
        if Path(dst).parent == tmp_path:  # a file moved from the staging folder into place
            if moves:
                raise KeyboardInterrupt
            moves.append(str(dst))
        real(src, dst, **kwargs)

    monkeypatch.setattr(os, "replace", killed_after_one_move)
    with pytest.raises(KeyboardInterrupt):
        result.save(tmp_path)
    monkeypatch.setattr(os, "replace", real)
    assert len(moves) == 1 and not (tmp_path / "result.json").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "no temporary files left behind"
    result.save(tmp_path)
    assert load_result_record(tmp_path)["steps"] == 1


def test_small_writers_are_atomic(tmp_path: Path, replaced: Set[Path]) -> None:
    """The study's attention picture and `transfer report -o`."""
    from meshadv.cli import build_app
    from meshadv.study.selection import attention_image
    from meshadv.transfer.results import save_transfer_rows

    picture = attention_image("dog", tmp_path / "pics" / "dog.png", size=32)
    assert picture.resolve() in replaced
    db = tmp_path / "t.db"
    save_transfer_rows(db, [{"case_id": "c", "victim": "v", "true_class": "boat", "target": "chair",
                             "perturbation": "shape", "view": 0, "success_meshadv": True, "success_mitsuba": False}])
    result = CliRunner().invoke(build_app({"transfer": "transfer:transfer"}),
                                ["transfer", "report", str(db), "-o", str(tmp_path / "rep" / "transfer.md")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "rep" / "transfer.md").resolve() in replaced


def test_a_study_export_interrupted_while_replacing_keeps_the_old_study(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """--overwrite moves the old study folder aside until the new one is in place: Ctrl-C / SIGTERM between the two
    leaves the old study where it was (before, it had already been deleted and the new one was thrown away)."""
    from meshadv.study.export import write_study_folder
    from meshadv.study.plan import make_plan
    from meshadv.study.selection import Stimulus, attention_image

    picture = attention_image("dog", tmp_path / "dog.png", size=16)
    stimuli = [Stimulus(f"img{i}", "adversarial", "dog", "cat", "v", "shape", 0.1, f"job{i}", str(picture))
               for i in range(2)]
    plan = make_plan([s.image_id for s in stimuli], per_image=1, max_trials=2)
    out = tmp_path / "study"
    write_study_folder(out, stimuli[:1], make_plan(["img0"], per_image=1, max_trials=1), {})
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    real_rename = Path.rename

    def interrupted_rename(self: Path, target: Any) -> Any:
        if ".staging-" in self.name:
            raise KeyboardInterrupt
        return real_rename(self, target)

    monkeypatch.setattr(Path, "rename", interrupted_rename)
    with pytest.raises(KeyboardInterrupt):
        write_study_folder(out, stimuli, plan, {}, overwrite=True)
    monkeypatch.setattr(Path, "rename", real_rename)
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dog.png", "study"], "nothing hidden left behind"
    write_study_folder(out, stimuli, plan, {}, overwrite=True)
    assert sorted(p.name for p in (out / "images").iterdir()) == ["img0.png", "img1.png"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dog.png", "study"]


def test_private_files_are_never_readable_by_others(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``mode=0o600`` (the local Ray cluster's token): owner-only while written and after; the default follows the
    umask as before."""
    import stat

    from ray_local import write_token
    from meshadv.util import atomic

    modes: List[int] = []
    real = os.replace

    def checking(src: Any, dst: Any, **kwargs: Any) -> None:
        modes.append(stat.S_IMODE(os.stat(src).st_mode))  # the finished temporary file, just before it is moved
        real(src, dst, **kwargs)

    monkeypatch.setattr(os, "replace", checking)
    token = write_token(tmp_path / "cluster" / "auth_token")
    assert stat.S_IMODE(token.stat().st_mode) == 0o600 and modes == [0o600]
    assert len(token.read_text()) == 64
    old_mask = os.umask(0o022)
    try:
        plain = atomic.write_text_atomic(tmp_path / "plain.txt", "x")
    finally:
        os.umask(old_mask)
    assert stat.S_IMODE(plain.stat().st_mode) == 0o644
