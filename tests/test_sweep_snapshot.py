"""Resumable copies of a running sweep's database: ``ResultStore.snapshot`` and ``meshadv sweep --snapshot``."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest
from typer.testing import CliRunner

from meshadv.commands.sweep import DatabaseSnapshots
from meshadv.experiments import ResultStore, SerialBackend, run_sweep
from sweep_fixtures import job_states, probe_jobs, sweep_cli, two_job_config

PROBE = "probe_jobs:mesh_probe_job"


def _meta_open(db: Path) -> str:
    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        return conn.execute("SELECT value FROM meta WHERE key = 'open'").fetchone()[0]
    finally:
        conn.close()


def test_a_snapshot_of_an_open_database_resumes_as_a_cleanly_closed_one(tmp_path: Path) -> None:
    jobs = probe_jobs(["chair", "sofa"])  # 2 jobs
    copy = tmp_path / "durable" / "results.db"
    with ResultStore(tmp_path / "results.db") as store:
        store.add_jobs(jobs)
        first = store.runnable(1)[0]
        store.mark_running(first)
        store.snapshot(copy)  # while open, with a job running and the WAL not checkpointed
        assert sorted(p.name for p in copy.parent.iterdir()) == ["results.db"]  # no temporary file, no WAL
        assert _meta_open(tmp_path / "results.db") == "1"
    assert _meta_open(copy) == "0"
    assert job_states(copy) == {"pending": 1, "running": 1}
    with ResultStore(copy) as resumed:  # opens without the lost-WAL refusal, and the sweep continues from it
        summary = run_sweep(resumed, jobs, PROBE, out_root=tmp_path / "out", backend=SerialBackend(), progress=False)
    assert (summary.requeued, summary.ran, summary.done) == (1, 2, 2)


def test_a_snapshot_replaces_the_previous_copy(tmp_path: Path) -> None:
    copy = tmp_path / "copy.db"
    copy.write_bytes(b"an older copy")
    with ResultStore(tmp_path / "results.db") as store:
        store.add_jobs(probe_jobs(["chair", "sofa", "boat"]))
        assert store.snapshot(copy) == copy
    assert job_states(copy) == {"pending": 6}


def test_a_snapshot_onto_the_database_itself_or_of_memory_is_refused(tmp_path: Path) -> None:
    db = tmp_path / "results.db"
    with ResultStore(db) as store:
        for target in (db, Path(f"{db}-wal"), tmp_path / "." / "results.db"):
            with pytest.raises(ValueError, match="is the database itself"):
                store.snapshot(target)
    with ResultStore(":memory:") as memory, pytest.raises(ValueError, match="':memory:'"):
        memory.snapshot(tmp_path / "copy.db")


def test_snapshots_after_outcomes_are_spaced_and_the_end_always_writes(tmp_path: Path) -> None:
    copy = tmp_path / "copy.db"
    with ResultStore(tmp_path / "results.db") as store:
        store.add_jobs(probe_jobs(["chair", "sofa"]))
        snapshots = DatabaseSnapshots(store, copy, every_s=3600.0)
        snapshots.after_outcome("a", True)  # the first outcome always copies
        assert job_states(copy) == {"pending": 2}
        store.add_jobs(probe_jobs(["boat", "bottle"]))
        snapshots.after_outcome("b", True)  # within the hour: no new copy
        assert job_states(copy) == {"pending": 2}
        snapshots.write()
        assert job_states(copy) == {"pending": 4}
        every = DatabaseSnapshots(store, tmp_path / "every.db", every_s=0.0)
        every.after_outcome("a", True)
        store.add_jobs(probe_jobs(["aeroplane", "bicycle", "diningtable"]))  # 6 more
        every.after_outcome("b", True)
        assert sum(job_states(tmp_path / "every.db").values()) == 10


def test_cli_snapshot_holds_the_finished_sweep_and_resumes(tmp_path: Path) -> None:
    (tmp_path / "sweep.toml").write_text(two_job_config("snap", PROBE))
    db, copy = tmp_path / "scratch" / "results.db", tmp_path / "home" / "results.db"
    args = ["sweep", str(tmp_path / "sweep.toml"), "--output", str(tmp_path / "out"), "--backend", "serial",
            "--no-progress"]
    res = CliRunner().invoke(sweep_cli(), args + ["--db", str(db), "--snapshot", str(copy), "--snapshot-every", "1h"])
    assert res.exit_code == 0, res.output
    assert job_states(copy) == {"done": 2} and _meta_open(copy) == "0"
    res = CliRunner().invoke(sweep_cli(), args + ["--db", str(copy)])  # the scratch folder gone: resume from the copy
    assert res.exit_code == 0, res.output
    assert "ran 0, skipped 2 finished" in res.output


@pytest.mark.parametrize("extra, option", [(["--snapshot", "{db}"], "--snapshot"),
                                           (["--snapshot", "{copy}", "--snapshot-every", "soon"], "--snapshot-every")])
def test_cli_bad_snapshot_options_are_named(tmp_path: Path, extra: list, option: str) -> None:
    (tmp_path / "sweep.toml").write_text(two_job_config("snap", PROBE))
    db, copy = tmp_path / "results.db", tmp_path / "copy.db"
    args = ["sweep", str(tmp_path / "sweep.toml"), "--db", str(db), "--output", str(tmp_path / "out"),
            "--backend", "serial", "--no-progress"] + [e.format(db=db, copy=copy) for e in extra]
    res = CliRunner().invoke(sweep_cli(), args)
    assert res.exit_code == 2 and option in res.output
    assert not db.exists() and not copy.exists()
