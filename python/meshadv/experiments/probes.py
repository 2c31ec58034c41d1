"""Probe jobs: cheap job functions that exercise the sweep machinery without rendering anything.

Use them to check a backend or a cluster before spending hours on attacks, e.g. a config with
``[runner] job = "meshadv.experiments.probes:probe_job"``. The runner's tests use them too, because job functions must
be importable by spawned and Ray worker processes.

``probe_job`` reads ``spec["probe"]``:

- ``"ok"`` (default): write an artefact and return a record (``success``/``distance`` taken from the spec);
- ``"raise"``: raise ``RuntimeError``; ``"segfault"``: kill its own process with SIGSEGV; ``"exit"``: ``os._exit(7)``;
- ``"flaky"``: raise on the first attempt, succeed on later ones.

``spec["sleep"]`` (seconds) delays the job. Every start appends a line to ``<out_dir>/runs.log``, so tests can count how
many times a job really ran.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path
from typing import Any, Dict

__all__ = ["probe_job", "atomic_write_text"]


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (temporary file in the same folder, fsync, rename)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


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
    artefact = out_dir / "artefact.json"
    atomic_write_text(artefact, json.dumps(spec, sort_keys=True))
    return {
        "success": bool(spec.get("success", True)),
        "distance": float(spec.get("distance", 0.0)),
        "steps": int(spec.get("steps", 1)),
        "time": time.perf_counter() - start,
        "runs": runs,
        "artifacts": {"artefact": str(artefact)},
    }
