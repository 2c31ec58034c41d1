"""``kill -TERM`` of a running ``meshadv sweep`` takes Ctrl-C's path: finished jobs kept, running ones put back to
pending, the database closed cleanly (not left marked open)."""

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
    proc, db, _ = start_sweep_process(tmp_path, "terminate", "slow_probe", JOB)

    def one_done_one_running() -> bool:
        states = job_states(db)
        return states.get("done") == 1 and states.get("running") == 1

    output, _ = terminate_when(proc, one_done_one_running, poll=0.2)
    assert proc.returncode == 130, output
    assert "interrupted" in output and "put back to pending" in output
    assert job_states(db) == {"done": 1, "pending": 1}  # chair -> sofa and sofa -> chair
    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        assert conn.execute("SELECT value FROM meta WHERE key = 'open'").fetchone() == ("0",)
    finally:
        conn.close()
