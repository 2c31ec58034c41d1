"""Tiny sweep configurations on the built-in chair and sofa, shared by the sweep tests."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
from pathlib import Path
from typing import Any, Dict, Iterable, List, Sequence, Tuple

import typer

from meshadv.experiments import ResultStore, SerialBackend, run_sweep
from meshadv.experiments.config import expand_jobs, parse_config


def tiny_builtin_config(name: str, *, image_size: int = 32, steps: int = 3,
                        perturbations: Sequence[str] = ("shape", "texture")) -> Dict[str, Any]:
    """A sweep config (as parsed TOML) attacking the built-in chair and sofa with EfficientNet-Lite0 for ``steps``
    steps at ``image_size`` px, one configuration each, every job run whether or not the benign render is right."""
    return {
        "experiment": {"name": name},
        "meshes": {"source": "builtin", "builtin": [{"name": "chair", "class": "chair"},
                                                    {"name": "sofa", "class": "sofa"}]},
        "render": {"image_size": image_size, "configurations": 1, "distance": 2.4, "elevation": [15, 25]},
        "victims": {"names": ["efficientnet_lite0"]},
        "attack": {"perturbations": list(perturbations), "benign_correct_only": False,
                   "shape": {"steps": steps, "lr": 0.01}, "texture": {"steps": steps}},
    }


def run_probe_sweep(db: Path, jobs: Iterable[Dict[str, Any]], out_root: Path) -> Path:
    """Run synthetic attack jobs (:func:`probe_jobs.mesh_probe_job`: no renderer, no victim; each
    job's ``success`` key decides its outcome) serially into the database ``db``; return ``db``."""
    with ResultStore(db) as store:
        run_sweep(store, jobs, "probe_jobs:mesh_probe_job", out_root=out_root,
                  backend=SerialBackend(), progress=False)
    return db


def probe_jobs(classes: Sequence[str], *, configurations: int = 1) -> List[Dict[str, Any]]:
    """The job specs of a shape-attack sweep of the PASCAL3D+ ``classes`` (``configurations`` drawn views each, the
    stand-in victim name ``"v"``, every other listed class a target), for :func:`run_probe_sweep`."""
    return expand_jobs(parse_config({"meshes": {"classes": list(classes)},
                                     "render": {"configurations": configurations},
                                     "victims": {"names": ["v"]}, "attack": {"types": ["shape"]}}))


def two_job_config(name: str, job: str) -> str:
    """A sweep file (TOML text) of two shape jobs, the built-in chair -> sofa and sofa -> chair, run by the job
    function ``job`` (``"module:function"``) with one attempt each: for the command-line tests."""
    return f"""
[experiment]
name = "{name}"

[meshes]
source = "builtin"
builtin = [{{name = "chair", class = "chair"}}, {{name = "sofa", class = "sofa"}}]

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
job = "{job}"
max_attempts = 1
"""


def sweep_cli() -> typer.Typer:
    """A typer application with the ``sweep`` and ``report`` commands, for ``typer.testing.CliRunner``."""
    from meshadv.commands import report as report_cmd
    from meshadv.commands import sweep as sweep_cmd

    app = typer.Typer()
    sweep_cmd.register(app)
    report_cmd.register(app)
    return app


def job_states(db: Path) -> Dict[str, int]:
    """Jobs per state of a results database that a running sweep may be writing (read-only; ``{}`` while the file
    or its schema is not there yet)."""
    if not Path(db).is_file():
        return {}
    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
    try:
        return dict(conn.execute("SELECT state, COUNT(*) FROM jobs GROUP BY state").fetchall())
    except sqlite3.OperationalError:  # the schema is not there yet
        return {}
    finally:
        conn.close()


def start_sweep_process(tmp_path: Path, name: str, job_module: str, job_source: str, *, args: Sequence[str] = (),
                        **popen: Any) -> Tuple[subprocess.Popen, Path, Path]:
    """Start ``meshadv sweep`` (one worker, no progress bars, output piped as text, then ``args``) in a subprocess
    on :func:`two_job_config`'s two jobs, run by ``job_module.py`` (written into ``tmp_path`` from ``job_source``,
    which defines ``job``); ``popen``: more ``subprocess.Popen`` arguments. Returns ``(process, database, output
    folder)``."""
    (tmp_path / "sweep.toml").write_text(two_job_config(name, f"{job_module}:job"))
    (tmp_path / f"{job_module}.py").write_text(job_source)
    db, out = tmp_path / "results.db", tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]),
           "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "meshadv.cli", "sweep", str(tmp_path / "sweep.toml"), "--db",
                             str(db), "--output", str(out), "--workers", "1", "--no-progress", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, **popen)
    return proc, db, out
