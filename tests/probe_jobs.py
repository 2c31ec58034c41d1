"""Probe jobs: cheap job functions that exercise the sweep machinery without rendering anything.

The runner's tests use them (``"probe_jobs:probe_job"``); job functions must be importable by spawned and Ray worker
processes, so the test session puts this folder on ``PYTHONPATH`` (conftest.py).

``probe_job`` reads ``spec["probe"]``:

- ``"ok"`` (default): write an artefact and return a record (``success``/``distance`` taken from the spec);
- ``"raise"``: raise ``RuntimeError``; ``"segfault"``: kill its own process with SIGSEGV; ``"exit"``: ``os._exit(7)``;
- ``"flaky"``: raise on the first attempt, succeed on later ones.

``spec["sleep"]`` (seconds) delays the job. A job that returns first reports ``spec["steps"]`` steps (default 1) to the
sweep driver (:func:`meshadv.experiments.worker.report_steps`), as an attack does. Every start appends a line to
``<out_dir>/runs.log``, so tests can count how many times a job really ran.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path
from typing import Any, Dict

from meshadv.experiments.worker import report_steps
from meshadv.util.atomic import write_text_atomic

__all__ = ["probe_job", "mesh_probe_job"]


def probe_job(spec: Dict[str, Any], out_dir: Path) -> Dict[str, Any]:
    """Run the probe described by ``spec`` (see the module docstring).

    Args:
        spec: the job spec; keys ``probe``, ``sleep``, ``success``, ``distance`` are used.
        out_dir: the job's artefact folder.

    Returns:
        A record with ``success``, ``distance``, ``steps``, ``time``, ``artifacts`` and ``runs``.

    Raises:
        RuntimeError: for the ``raise`` probe and the first attempt of the ``flaky`` probe.
        ValueError: unknown probe name.
    """
    start = time.perf_counter()
    out_dir = Path(out_dir)
    log = out_dir / "runs.log"
    with open(log, "a", encoding="utf-8") as fh:
        fh.write(f"{os.getpid()}\n")
    runs = len(log.read_text(encoding="utf-8").splitlines())
    kind = spec.get("probe", "ok")
    time.sleep(float(spec.get("sleep", 0.0)))
    if kind == "raise":
        raise RuntimeError(f"probe job asked to fail (spec {spec})")
    if kind == "segfault":
        os.kill(os.getpid(), signal.SIGSEGV)
        time.sleep(10.0)
    if kind == "exit":
        os._exit(7)
    if kind == "flaky" and runs == 1:
        raise RuntimeError("flaky probe job: failing on its first attempt")
    if kind not in ("ok", "flaky"):
        raise ValueError(f"spec['probe'] must be ok, raise, segfault, exit or flaky, got {kind!r}")
    steps = int(spec.get("steps", 1))
    for done in range(1, steps + 1):
        report_steps(done, steps)
    artefact = out_dir / "artefact.json"
    write_text_atomic(artefact, json.dumps(spec, sort_keys=True))
    return {
        "success": bool(spec.get("success", True)),
        "distance": float(spec.get("distance", 0.0)),
        "steps": steps,
        "time": time.perf_counter() - start,
        "runs": runs,
        "pid": os.getpid(),
        "artifacts": {"artefact": str(artefact)},
    }


def mesh_probe_job(spec: Dict[str, Any], out_dir: Path) -> Dict[str, Any]:
    """A synthetic "attack" with the artefacts and record layout of :func:`meshadv.experiments.jobs.run_attack_job`.

    It moves the vertices of an icosphere by a smooth, seeded displacement field (amplitude ``spec["amplitude"]``,
    default 0.02), writes ``benign.ply`` / ``adversarial.ply`` and flat-coloured ``benign_v0.png`` / ``after_v0.png``
    and reports ``success`` from ``spec["success"]`` (default: ``True``) and distances computed from the field (after
    ``spec["sleep"]`` seconds; ``job_dir`` in the record is the folder it wrote). With ``spec["look_for"]`` (a path)
    the record's ``saw`` says whether that path existed where the job ran (a cluster test's check that a worker
    cannot see the driver's folder). Use it to check reports, figures and clusters without rendering.

    Args:
        spec: a job spec as made by ``expand_jobs`` (``source_class``, ``target``, ``perturbation``, ``seed``...).
        out_dir: the job's artefact folder.

    Returns:
        The record.
    """
    import zlib

    import numpy as np
    import trimesh
    from PIL import Image

    start = time.perf_counter()
    out_dir = Path(out_dir)
    time.sleep(float(spec.get("sleep", 0.0)))
    seed = zlib.crc32(json.dumps(spec, sort_keys=True).encode())
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=2)
    v = np.asarray(sphere.vertices)
    f = np.asarray(sphere.faces)
    centre = rng.normal(size=3)
    centre /= np.linalg.norm(centre)
    weight = np.exp(-4.0 * np.linalg.norm(v - centre, axis=1) ** 2)
    amplitude = float(spec.get("amplitude", 0.02))
    flow = amplitude * weight[:, None] * (v + 0.3 * rng.normal(size=v.shape))
    shape = spec.get("perturbation", "shape") == "shape"
    va = v + flow if shape else v
    edges = sphere.edges_unique
    lap_sum = 2.0 * float(np.sum((flow[edges[:, 0]] - flow[edges[:, 1]]) ** 2)) if shape else 0.0  # Eq. 4
    rmse = 0.0 if shape else amplitude
    trimesh.Trimesh(v, f, process=False).export(out_dir / "benign.ply")
    trimesh.Trimesh(va, f, process=False).export(out_dir / "adversarial.ply")
    for name, key in (("benign_v0.png", spec.get("source_class", "a")), ("after_v0.png", spec.get("target", "b"))):
        colour = [zlib.crc32(str(key).encode()) >> s & 255 for s in (0, 8, 16)]
        Image.new("RGB", (16, 16), tuple(colour)).save(out_dir / name)
    distances = {"laplacian_sum": lap_sum, "laplacian_pair_mean": lap_sum / (2 * len(edges)), "color_rmse": rmse,
                 "num_edges": len(edges), "max_displacement": float(np.linalg.norm(flow, axis=1).max())}
    return {
        "success": bool(spec.get("success", True)),
        "skipped": False,
        "benign_correct": True,
        "distance": distances["laplacian_pair_mean" if shape else "color_rmse"],
        "distances": distances,
        "steps": 1,
        "time": time.perf_counter() - start,
        "eval_success_rate": 0.5 if spec.get("kind") == "multiview" else None,
        "job_dir": str(out_dir),
        **({"saw": os.path.exists(str(spec["look_for"]))} if spec.get("look_for") else {}),
        "artifacts": {"benign_mesh": "benign.ply", "benign_images": ["benign_v0.png"],
                      "adversarial_mesh": "adversarial.ply", "adversarial_images": ["after_v0.png"]},
    }
