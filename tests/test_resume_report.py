"""``meshadv report --artifacts`` killed with SIGTERM while it regenerates the figures' jobs: it exits 130, every
regeneration it finished is complete on disk, and the next report reuses those and regenerates only the rest.

A real subprocess and a real signal; the jobs are the synthetic mesh probe (no renderer, no victim), slowed down so
that the signal lands between regenerations or inside one.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Dict, List

import pytest

from meshadv.experiments import ResultStore
from sweep_fixtures import probe_jobs, run_probe_sweep
from signal_fixtures import terminate_when

#: Seconds each regeneration sleeps before running the probe.
SLOW_S = 0.8


def slow_mesh_probe_job(spec: Dict[str, Any], out_dir: Path) -> Dict[str, Any]:
    """The mesh probe after :data:`SLOW_S` seconds (a regeneration that takes a while)."""
    from probe_jobs import mesh_probe_job

    time.sleep(SLOW_S)
    return mesh_probe_job(spec, out_dir)


def _moved_db(tmp_path: Path) -> Path:
    """A probe sweep of 3 classes x 1 configuration x 2 targets whose artefact folders are gone; regenerating runs
    :func:`slow_mesh_probe_job`."""
    jobs = [{**j, "success": True} for j in probe_jobs(["aeroplane", "bicycle", "boat"])]
    db = run_probe_sweep(tmp_path / "r.db", jobs, tmp_path / "run")
    shutil.rmtree(tmp_path / "run")
    with ResultStore(db) as store:
        store.set_meta("config_text", '[runner]\njob = "test_resume_report:slow_mesh_probe_job"\n')
    return db


def _checks(root: Path) -> Dict[Path, int]:
    return {p: p.stat().st_mtime_ns for p in root.rglob("regeneration.json")}


def test_sigterm_during_report_regeneration_keeps_finished_jobs(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    import meshadv.experiments.regenerate as regenerate
    from meshadv.experiments.report import write_report

    db = _moved_db(tmp_path)
    regen = tmp_path / "regen"
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1", "RAYON_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join([str(Path(__file__).parent), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-m", "meshadv", "report", str(db), "-o", str(tmp_path / "rep"),
                             "--artifacts", str(regen)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env)
    _, stderr = terminate_when(proc, lambda: len(_checks(regen)) >= 2, exit_timeout=60)
    assert proc.returncode == 130, stderr
    assert "interrupted: the jobs regenerated so far are kept in" in stderr and "Traceback" not in stderr
    kept = _checks(regen)
    assert 2 <= len(kept) < 6
    for path in kept:  # written atomically: complete JSON, never cut short
        assert json.loads(path.read_text(encoding="utf-8"))["matches"] is True
    assert not list(regen.rglob(".*.tmp")), "no temporary files left behind"

    calls: List[str] = []
    real = regenerate.regenerate_job

    def counting(db_path: Any, job: str, *args: Any, **kwargs: Any) -> Any:
        calls.append(job)
        return real(db_path, job, *args, **kwargs)

    monkeypatch.setattr(regenerate, "regenerate_job", counting)
    out = write_report(db, tmp_path / "rep2", artifacts=regen)
    assert len(out.regenerations) == 6 and all(c["matches"] for c in out.regenerations.values())
    assert len(calls) == 6 - len(kept), "the finished regenerations are reused, only the rest run"
    after = _checks(regen)
    assert {p: after[p] for p in kept} == kept, "a finished regeneration is not redone"


def test_regeneration_and_transfer_cases_only_read_the_database(tmp_path: Path) -> None:
    """``regenerate_job`` (run by long reports) and ``cases_from_store`` (``transfer controlled``) leave the database
    byte-identical: they never mark it open, so a kill while they hold it cannot leave a file that the next open
    refuses as "not closed cleanly"."""
    import hashlib

    from meshadv.experiments.regenerate import regenerate_job
    from meshadv.transfer.controlled import cases_from_store

    db = _moved_db(tmp_path)
    with ResultStore(db, read_only=True) as store:
        job = store.rows()[0].job_id

    def digest() -> str:
        return hashlib.sha256(db.read_bytes()).hexdigest()

    before = digest()
    done = regenerate_job(db, job, tmp_path / "regen")
    assert done.matches and (tmp_path / "regen" / "adversarial.ply").is_file()
    assert digest() == before
    cases_from_store(db, regenerate=False)
    assert digest() == before
