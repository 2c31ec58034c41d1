"""Artefacts without a shared file system: a job runs in its own temporary folder and its files travel back to the
driver (or to a URL), which alone writes the job's folder and the database."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, List, Optional, Sequence, Tuple

import pytest

from meshadv.experiments import ResultStore, SerialBackend, job_id, run_sweep
from meshadv.experiments.artifacts import collect_files, deliver, run_detached, write_files
from meshadv.experiments.worker import Outcome

PROBE = "probe_jobs:probe_job"


def test_detached_job_returns_its_files_and_leaves_nothing_behind(tmp_path: Path) -> None:
    spec = {"probe": "ok", "distance": 2.0}
    outcome = run_detached(PROBE, job_id(spec), spec)
    assert outcome.ok and outcome.location is None
    assert set(outcome.artifacts) == {"artefact.json", "runs.log"}
    assert json.loads(outcome.artifacts["artefact.json"]) == spec
    worker_folder = Path(outcome.record["artifacts"]["artefact"]).parent
    assert not worker_folder.exists()  # the worker's temporary folder is gone
    driver = tmp_path / "driver" / "job"
    assert deliver(outcome, driver) == str(driver)
    assert collect_files(driver) == outcome.artifacts


def test_failed_detached_job_ships_nothing() -> None:
    outcome = run_detached(PROBE, "x", {"probe": "raise"})
    assert not outcome.ok and outcome.artifacts is None and "probe job asked to fail" in outcome.error


def test_upload_to_a_url_records_the_location(tmp_path: Path) -> None:
    spec = {"probe": "ok"}
    jid = job_id(spec)
    bucket = tmp_path / "bucket"
    outcome = run_detached(PROBE, jid, spec, destination=f"file://{bucket}")
    assert outcome.ok and outcome.artifacts is None
    assert outcome.location == f"file://{bucket}/jobs/{jid[:2]}/{jid}"
    assert json.loads((bucket / "jobs" / jid[:2] / jid / "artefact.json").read_text()) == spec
    assert deliver(outcome, tmp_path / "never") == outcome.location and not (tmp_path / "never").exists()


def test_write_files_is_confined_and_writes_the_marker_last(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="inside the job folder"):
        write_files({"../escape.txt": b"x"}, tmp_path / "job")
    with pytest.raises(ValueError, match="inside the job folder"):
        write_files({"/abs.txt": b"x"}, tmp_path / "job")
    out = write_files({"result.json": b"{}", "sub/after_v0.png": b"png", "adversarial.ply": b"ply"}, tmp_path / "j")
    files = sorted(out.rglob("*"), key=lambda p: p.stat().st_mtime_ns)
    assert files[-1].name == "result.json" and (out / "sub" / "after_v0.png").read_bytes() == b"png"


class _ReturningBackend(SerialBackend):
    """A backend whose jobs never see the driver's folder: the serial backend through run_detached."""

    def wait(self, handles: Sequence[Any], timeout: Optional[float] = None) -> List[Tuple[Any, Outcome]]:
        for handle in handles:
            if handle in self._pending:
                ref, jid, spec, _out_dir = self._pending.pop(handle)
                return [(handle, run_detached(ref, jid, spec))]
        return []


def test_runner_writes_returned_artifacts_before_recording(tmp_path: Path) -> None:
    specs = [{"probe": "ok", "distance": 1.0}, {"probe": "raise"}]
    with ResultStore(tmp_path / "r.db") as store:
        summary = run_sweep(store, specs, PROBE, out_root=tmp_path / "run", backend=_ReturningBackend(),
                            max_attempts=1, progress=False)
        rows = {r.job_id: r for r in store.rows()}
    assert (summary.done, summary.failed) == (1, 1)
    ok = rows[job_id(specs[0])]
    assert ok.out_dir == str(tmp_path / "run" / "jobs" / ok.job_id[:2] / ok.job_id)
    assert json.loads((Path(ok.out_dir) / "artefact.json").read_text()) == specs[0]
    assert not str(ok.record["artifacts"]["artefact"]).startswith(str(tmp_path))  # the job ran elsewhere
    assert not (tmp_path / "run" / "jobs" / job_id(specs[1])[:2] / job_id(specs[1])).exists()


def test_outcome_defaults_keep_old_pickles_compatible() -> None:
    plain = Outcome("a", True, {}, None, 0.1)
    assert plain.artifacts is None and plain.location is None
