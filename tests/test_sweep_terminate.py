"""``kill -TERM`` of a running ``meshadv sweep`` takes Ctrl-C's path: finished jobs kept, running ones put back to
pending, the database closed cleanly (not left marked open)."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
from pathlib import Path

from signal_fixtures import terminate_when

CONFIG = """
[experiment]
name = "terminate"

[meshes]
source = "builtin"
builtin = [{name = "chair", class = "chair"}, {name = "sofa", class = "sofa"}]

[render]
image_size = 32
configurations = 1
distance = 2.4
elevation = [15, 25]

[victims]
names = ["efficientnet_lite0"]

[attack]
types = ["shape"]
benign_correct_only = false

[runner]
job = "slow_probe:slow_job"
max_attempts = 1
"""

JOB = '''
import time
from pathlib import Path


def slow_job(spec, out_dir):
    """The first job returns at once; every later one sleeps far longer than the test waits."""
    marker = Path(out_dir).parents[2] / "first.done"
    if marker.exists():
        time.sleep(600)
    marker.write_text("1")
    return {"success": True, "skipped": False, "distance": 0.0, "steps": 1, "time": 0.0}
'''


def _states(db: Path) -> dict:
    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
    try:
        return dict(conn.execute("SELECT state, COUNT(*) FROM jobs GROUP BY state").fetchall())
    finally:
        conn.close()


def test_sigterm_requeues_running_jobs_and_closes_the_database(tmp_path: Path) -> None:
    (tmp_path / "sweep.toml").write_text(CONFIG)
    (tmp_path / "slow_probe.py").write_text(JOB)
    db, out = tmp_path / "results.db", tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]),
           "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "meshadv.cli", "sweep", str(tmp_path / "sweep.toml"), "--db",
                             str(db), "--output", str(out), "--workers", "1", "--no-progress"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    def one_done_one_running() -> bool:
        try:
            states = _states(db) if db.is_file() else {}
        except sqlite3.OperationalError:  # the schema is not there yet
            states = {}
        return states.get("done") == 1 and states.get("running") == 1

    output, _ = terminate_when(proc, one_done_one_running, poll=0.2)
    assert proc.returncode == 130, output
    assert "interrupted" in output and "put back to pending" in output
    assert _states(db) == {"done": 1, "pending": 1}  # chair -> sofa and sofa -> chair
    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        assert conn.execute("SELECT value FROM meta WHERE key = 'open'").fetchone() == ("0",)
    finally:
        conn.close()
