"""A local multi-node Ray cluster without a shared file system loses a worker node mid-sweep and loses no job.

Runs ``benchmarks/ray_cluster_bench.py --skip-throughput`` in a child process (Ray reads its authentication mode
when first imported, so the driver needs a fresh interpreter): a head and two worker nodes started with ``ray start``,
each with its own temp dir and scratch folder and (where ``unshare --mount`` is permitted) its own mount namespace
in which the driver's folder is an empty tmpfs, jobs pinned to the workers by a custom resource; one worker node is
killed half-way through a job. The script itself asserts that every job is done once, that every artefact folder is
complete in the driver's folder, and that every job ran in a worker's scratch folder, never in the driver's folder.
About a minute on 2 cores.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

pytest.importorskip("ray", reason="the Ray backend needs ray (pip install 'ray>=2.9')")


@pytest.mark.slow
def test_lost_worker_node_is_retried_and_nothing_is_lost() -> None:
    script = Path(__file__).parents[1] / "benchmarks" / "ray_cluster_bench.py"
    out = Path(tempfile.mkdtemp(prefix="mrc-"))  # short: Ray's socket paths under it must stay < 108 bytes
    env = {**os.environ, "OMP_NUM_THREADS": "1", "RAYON_NUM_THREADS": "1"}
    try:
        proc = subprocess.run([sys.executable, str(script), "--skip-throughput", "--kill-jobs", "6", "--sleep", "3",
                               "--out", str(out)], capture_output=True, text=True, timeout=600, env=env)
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
        lost = json.loads((out / "ray_cluster_bench.json").read_text())["lost_node"]
    finally:
        shutil.rmtree(out, ignore_errors=True)
    assert lost["summary"]["done"] == 6 and lost["summary"]["failed"] == 0
    assert lost["killed"]["processes"] >= 1
    assert lost["retried_jobs"] >= 1  # the killed node's job ran again elsewhere
    assert set(lost["jobs_by_node"]) <= {"w1_scratch", "w2_scratch"} and lost["jobs_by_node"].get("w2_scratch")
    from ray_local import can_hide_folders

    if can_hide_folders():  # the workers could not see the driver's folder at all, and no job saw it
        assert lost["isolation"]["driver_folder_hidden_from_workers"] and lost["isolation"]["jobs_that_saw_it"] == 0
