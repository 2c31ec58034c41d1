"""The Ray backend runs a tiny sweep on a local one-CPU Ray instance, including a crashing job."""

from __future__ import annotations

from pathlib import Path

import pytest

from meshadv.experiments import RayBackend, ResultStore, job_id, run_sweep

ray = pytest.importorskip("ray", reason="the Ray backend needs ray (pip install 'ray>=2.9')")


def test_ray_backend_tiny_sweep(tmp_path: Path) -> None:
    specs = [{"probe": "ok", "distance": 1.5}, {"probe": "raise"}, {"probe": "ok", "success": False}]
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        backend = RayBackend()
        assert backend.capacity == 1 and not backend._owns  # an existing Ray instance is reused, not shut down
        store = ResultStore(tmp_path / "r.db")
        summary = run_sweep(store, specs, "probe_jobs:probe_job", out_root=tmp_path,
                            backend=backend, max_attempts=1, progress=False)
        backend.close()
        assert ray.is_initialized()
    finally:
        ray.shutdown()
    assert (summary.done, summary.failed, summary.successes) == (2, 1, 1)
    rows = {r.job_id: r for r in store.rows()}
    assert rows[job_id(specs[0])].record["distance"] == 1.5
    assert "RuntimeError: probe job asked to fail" in rows[job_id(specs[1])].error
    assert (tmp_path / "jobs" / job_id(specs[0])[:2] / job_id(specs[0]) / "artefact.json").is_file()
    # the task ran in a temporary folder of its node; the driver wrote the files it returned
    assert not str(rows[job_id(specs[0])].record["artifacts"]["artefact"]).startswith(str(tmp_path))
