"""``kill -TERM`` of a running ``meshadv sweep`` takes Ctrl-C's path: finished jobs kept, running ones put back to
pending, the database closed cleanly (not left marked open), and a ``--snapshot`` copy written once more."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from signal_fixtures import terminate_when
from sweep_fixtures import job_states, start_sweep_process

JOB = '''
import time
from pathlib import Path


def job(spec, out_dir):
    """The first job returns at once; every later one sleeps far longer than the test waits."""
    marker = Path(out_dir).parents[2] / "first.done"
    if marker.exists():
        time.sleep(600)
    marker.write_text("1")
    return {"success": True, "skipped": False, "distance": 0.0, "steps": 1, "time": 0.0}
'''


def test_sigterm_requeues_running_jobs_and_closes_the_database(tmp_path: Path) -> None:
    copy = tmp_path / "durable" / "results.db"
    proc, db, _ = start_sweep_process(tmp_path, "terminate", "slow_probe", JOB,
                                      args=["--snapshot", str(copy), "--snapshot-every", "1h"])

    def one_done_one_running() -> bool:
        states = job_states(db)
        return states.get("done") == 1 and states.get("running") == 1

    output, _ = terminate_when(proc, one_done_one_running, poll=0.2)
    assert proc.returncode == 130, output
    assert "interrupted" in output and "put back to pending" in output
    assert job_states(db) == {"done": 1, "pending": 1}  # chair -> sofa and sofa -> chair
    assert job_states(copy) == {"done": 1, "pending": 1}
    conn = sqlite3.connect(f"file:{copy}?mode=ro", uri=True)
    try:  # copied again after the running job was put back (the copy after the first outcome has it never started)
        assert conn.execute("SELECT COUNT(*) FROM jobs WHERE state = 'pending' AND started IS NOT NULL").fetchone() \
            == (1,)
    finally:
        conn.close()
    for path in (db, copy):
        conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            assert conn.execute("SELECT value FROM meta WHERE key = 'open'").fetchone() == ("0",)
        finally:
            conn.close()
