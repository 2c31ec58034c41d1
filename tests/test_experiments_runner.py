"""The sweep runner: resumes after a kill without repeating or losing jobs, records crashes, retries."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from meshadv.experiments import (
    LocalBackend,
    ResultStore,
    SerialBackend,
    job_id,
    job_out_dir,
    make_backend,
    run_sweep,
)
from meshadv.experiments.spec import canonical_json, job_ref

PROBE = "probe_jobs:probe_job"


def _runs(out_root: Path, spec: dict) -> int:
    log = job_out_dir(out_root, job_id(spec)) / "runs.log"
    return len(log.read_text().splitlines()) if log.exists() else 0


def test_job_id_is_canonical_and_sensitive() -> None:
    a = {"victim": "v", "views": [{"azimuth": 0.1 + 0.2}], "seed": 0}
    b = {"seed": 0, "views": [{"azimuth": 0.3}], "victim": "v"}
    assert job_id(a) == job_id(b)
    assert job_id(a) != job_id({**a, "seed": 1})
    assert canonical_json((a)) == canonical_json(b)
    with pytest.raises(ValueError, match="finite"):
        job_id({"x": float("nan")})
    with pytest.raises(ValueError, match="JSON-able"):
        job_id({"x": object()})


def test_job_ref_rejects_unimportable_functions() -> None:
    assert job_ref(PROBE) == PROBE
    with pytest.raises(ValueError, match="^job must be a module-level function"):
        job_ref(lambda spec, out: {})
    with pytest.raises(ValueError, match="^job must look like 'package.module:function'"):
        job_ref("no_colon")


def test_store_state_machine(tmp_path: Path) -> None:
    store = ResultStore(tmp_path / "r.db")
    assert store._conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    specs = [{"i": i} for i in range(3)]
    assert store.add_jobs(specs) == 3
    assert store.add_jobs(specs) == 0  # same ids: nothing new
    ids = [job_id(s) for s in specs]
    assert store.runnable(2) == ids
    assert store.mark_running(ids[0]) == 1
    with pytest.raises(ValueError, match="running"):
        store.mark_running(ids[0])
    assert store.mark_done(ids[0], {"success": True, "distance": 0.5, "steps": 3, "time": 1.0})
    assert not store.mark_done(ids[0], {"success": False})  # never written twice
    assert store.rows("done")[0].record["distance"] == 0.5
    store.mark_running(ids[1])
    assert store.mark_failed(ids[1], "boom")
    assert ids[1] in store.runnable(2) and ids[1] not in store.runnable(1)
    store.mark_running(ids[2])
    assert store.requeue_running() == 1
    assert store.attempts(ids[2]) == 0
    counts = store.counts()
    assert (counts["done"], counts["failed"], counts["pending"], counts["successes"]) == (1, 1, 1, 1)
    with pytest.raises(ValueError, match="max_attempts"):
        store.runnable(0)


def test_crashes_are_recorded_and_sweep_goes_on(tmp_path: Path) -> None:
    specs = [
        {"probe": "ok", "distance": 1.0, "i": 0},
        {"probe": "raise", "i": 1},
        {"probe": "segfault", "i": 2},
        {"probe": "exit", "i": 3},
        {"probe": "flaky", "distance": 2.0, "i": 4},
        {"probe": "ok", "success": False, "i": 5},
    ]
    store = ResultStore(tmp_path / "r.db")
    backend = LocalBackend(workers=2, threads_per_job=1)
    summary = run_sweep(store, specs, PROBE, out_root=tmp_path, backend=backend, max_attempts=2, progress=False)
    backend.close()
    assert (summary.total, summary.done, summary.failed, summary.successes) == (6, 3, 3, 2)
    rows = {r.job_id: r for r in store.rows()}
    raised, segv, exited, flaky = (rows[job_id(specs[i])] for i in (1, 2, 3, 4))
    assert "RuntimeError: probe job asked to fail" in raised.error and raised.attempts == 2
    assert "SIGSEGV" in segv.error and segv.attempts == 2
    assert "exit code 7" in exited.error
    assert flaky.state == "done" and flaky.attempts == 2 and flaky.record["runs"] == 2
    assert _runs(tmp_path, specs[0]) == 1
    # A second call runs nothing: done jobs are skipped, failed ones have no attempts left.
    again = run_sweep(store, specs, PROBE, out_root=tmp_path, backend=SerialBackend(), max_attempts=2,
                      progress=False)
    assert again.ran == 0 and again.skipped == 3
    # Raising the attempt bound retries only the failed ones.
    backend = LocalBackend(workers=2, threads_per_job=1)
    third = run_sweep(store, specs, PROBE, out_root=tmp_path, backend=backend, max_attempts=3, progress=False)
    backend.close()
    assert third.ran == 3 and third.failed == 3
    assert {r.attempts for r in store.rows("failed")} == {3}
    assert _runs(tmp_path, specs[0]) == 1


def test_only_the_given_jobs_run_in_their_order(tmp_path: Path) -> None:
    """A database holding more jobs than the call names (another part of the sweep, ``--only``) runs and counts only
    the named ones, in the order named, not the database's insertion order."""
    specs = [{"probe": "ok", "i": i} for i in range(5)]
    store = ResultStore(tmp_path / "r.db")
    store.add_jobs(specs)  # the whole sweep, as a first run registers it
    order: list[str] = []
    part = [specs[3], specs[1]]
    summary = run_sweep(store, part, PROBE, out_root=tmp_path, backend=SerialBackend(), progress=False,
                        on_outcome=lambda jid, ok: order.append(jid))
    assert order == [job_id(specs[3]), job_id(specs[1])]
    assert (summary.total, summary.done, summary.ran) == (2, 2, 2)
    assert {r.job_id for r in store.rows("pending")} == {job_id(specs[i]) for i in (0, 2, 4)}
    assert store.counts()["total"] == 5 and store.counts([job_id(specs[3]), "unknown"])["done"] == 1


def test_timeout_kills_the_job(tmp_path: Path) -> None:
    store = ResultStore(tmp_path / "r.db")
    backend = LocalBackend(workers=1, threads_per_job=1, timeout=3.0)
    specs = [{"probe": "ok", "sleep": 60.0}]
    summary = run_sweep(store, specs, PROBE, out_root=tmp_path, backend=backend, max_attempts=1, progress=False)
    backend.close()
    assert summary.failed == 1
    assert "timed out" in store.rows()[0].error


def test_workers_are_reused_and_recycled(tmp_path: Path) -> None:
    specs = [{"probe": "ok", "i": i} for i in range(4)]
    store = ResultStore(tmp_path / "r.db")
    backend = LocalBackend(workers=1, threads_per_job=1, max_jobs_per_worker=2)
    run_sweep(store, specs, PROBE, out_root=tmp_path, backend=backend, progress=False)
    backend.close()
    pids = [r.record["pid"] for r in store.rows()]
    assert pids[0] == pids[1] and pids[2] == pids[3] and pids[1] != pids[2]
    assert os.getpid() not in pids


def test_second_driver_is_refused(tmp_path: Path) -> None:
    from meshadv.experiments import driver_lock

    db = tmp_path / "r.db"
    with driver_lock(db):
        with pytest.raises(RuntimeError, match="already running"):
            with driver_lock(db):
                pass


def test_make_backend_validates() -> None:
    with pytest.raises(ValueError, match="backend must be"):
        make_backend("threads")
    with pytest.raises(ValueError, match="address"):
        make_backend("local", address="auto")
    with pytest.raises(ValueError, match="workers"):
        LocalBackend(workers=-1)


_DRIVER = textwrap.dedent(
    """
    import sys
    from meshadv.experiments import LocalBackend, ResultStore, run_sweep
    db, out_root, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
    specs = [{"probe": "ok", "sleep": 0.4, "distance": float(i), "i": i} for i in range(n)]
    store = ResultStore(db)
    run_sweep(store, specs, "probe_jobs:probe_job", out_root=out_root,
              backend=LocalBackend(workers=2, threads_per_job=1), progress=False)
    """
)


def test_resume_after_kill_neither_repeats_nor_loses_jobs(tmp_path: Path) -> None:
    n = 12
    db = tmp_path / "r.db"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    proc = subprocess.Popen([sys.executable, "-c", _DRIVER, str(db), str(tmp_path), str(n)], env=env,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        done = 0
        while time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
            if db.exists():
                try:
                    with sqlite3.connect(db) as conn:
                        done = conn.execute("SELECT COUNT(*) FROM jobs WHERE state = 'done'").fetchone()[0]
                except sqlite3.OperationalError:
                    continue
                if done >= 3:
                    break
        assert proc.poll() is None, "the sweep finished before it could be killed"
        os.killpg(proc.pid, signal.SIGKILL)  # the driver and its job processes, mid-sweep
        proc.wait()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    store = ResultStore(db)
    done_before = {r.job_id for r in store.rows("done")}
    assert 3 <= len(done_before) < n
    running_before = {r.job_id for r in store.rows("running")}
    specs = [{"probe": "ok", "sleep": 0.4, "distance": float(i), "i": i} for i in range(n)]
    summary = run_sweep(store, specs, PROBE, out_root=tmp_path, backend=LocalBackend(workers=2, threads_per_job=1),
                        progress=False)
    assert summary.requeued == len(running_before)
    assert summary.skipped == len(done_before)
    assert summary.ran == n - len(done_before)
    rows = store.rows()
    assert len(rows) == n and {r.state for r in rows} == {"done"}
    assert sorted(r.record["distance"] for r in rows) == [float(i) for i in range(n)]
    for spec in specs:
        jid = job_id(spec)
        runs = _runs(tmp_path, spec)
        if jid in done_before:
            assert runs == 1, "a finished job ran again"
        else:
            assert runs >= 1
    # Artefacts are complete files (written atomically), one per job.
    arts = sorted((tmp_path / "jobs").glob("*/*/artefact.json"))
    assert len(arts) == n
