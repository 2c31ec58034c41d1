"""Experiments: declarative sweeps of MeshAdv attacks, a resumable SQLite-backed runner, the paper's tables and figures.

- :mod:`~meshadv.experiments.config`: the sweep file (TOML/YAML), its checks and its expansion into job specs;
  :mod:`~meshadv.experiments.sweep_views`: the views a sweep attacks from.
- :mod:`~meshadv.experiments.store`: the results database (one row per job, WAL, resumable).
- :mod:`~meshadv.experiments.runner` and :mod:`~meshadv.experiments.backends`: running jobs (process pool, Ray).
- :mod:`~meshadv.experiments.jobs`: the attack job.
- :mod:`~meshadv.experiments.tables`, :mod:`~meshadv.experiments.figures`, :mod:`~meshadv.experiments.report`: results.

Heavy modules (tables, figures, jobs) are imported on use, not here.
"""

from __future__ import annotations

from meshadv.experiments.backends import BACKENDS, Backend, LocalBackend, RayBackend, SerialBackend, make_backend
from meshadv.experiments.runner import SweepSummary, run_sweep
from meshadv.experiments.spec import canonical_json, job_id, job_ref, resolve_job
from meshadv.experiments.store import STATES, JobRow, ResultStore, driver_lock, job_out_dir
from meshadv.experiments.worker import Outcome, execute

__all__ = [
    "BACKENDS",
    "Backend",
    "LocalBackend",
    "RayBackend",
    "SerialBackend",
    "make_backend",
    "SweepSummary",
    "run_sweep",
    "job_out_dir",
    "canonical_json",
    "job_id",
    "job_ref",
    "resolve_job",
    "STATES",
    "JobRow",
    "ResultStore",
    "driver_lock",
    "Outcome",
    "execute",
]
