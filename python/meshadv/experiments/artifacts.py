"""Job artefacts without a shared file system: run a job in its own temporary folder, then ship the folder.

A cluster node need not see the driver's output folder. :func:`run_detached` (the worker side) runs a job in a fresh
temporary folder of the worker's machine and then either

- returns the folder's files as bytes inside the :class:`~meshadv.experiments.worker.Outcome` (``destination=None``;
  they travel back to the driver as the task's return value, through Ray's object store), or
- copies them to ``<destination>/jobs/<id[:2]>/<id>/`` with fsspec (any URL fsspec knows: ``s3://bucket/run``,
  ``gs://...``, ``file:///mnt/...``) and returns only that location;

and deletes the temporary folder. On the driver, :func:`deliver` writes returned files into the job's artefact folder
(each file atomically, ``result.json`` last, as the job itself would) before the runner records the job, so the
database is written by the driver only and never points to a folder that is not complete.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Dict, Optional, Union

from meshadv.experiments.worker import Outcome, execute
from meshadv.util.atomic import write_bytes_atomic

__all__ = ["collect_files", "write_files", "upload_folder", "run_detached", "deliver", "LAST_FILES"]

#: Files written last when a folder is rebuilt (the attack job's completeness marker).
LAST_FILES = ("result.json",)


def collect_files(folder: Union[str, Path]) -> Dict[str, bytes]:
    """Every regular file under ``folder``, keyed by its POSIX path relative to ``folder``."""
    root = Path(folder)
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _ordered(names: "list[str]") -> "list[str]":
    return sorted(names, key=lambda n: (Path(n).name in LAST_FILES, n))


def write_files(files: Dict[str, bytes], folder: Union[str, Path]) -> Path:
    """Write ``files`` (relative path -> bytes) under ``folder``, each atomically, the completeness markers last.

    Raises:
        ValueError: a path that is absolute or leaves ``folder``.
    """
    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    for name in _ordered(list(files)):
        rel = Path(name)
        if rel.is_absolute() or ".." in rel.parts:
            raise ValueError(f"artefact path {name!r} must be relative and stay inside the job folder")
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(path, files[name])
    return root


def upload_folder(folder: Union[str, Path], url: str) -> str:
    """Copy every file under ``folder`` to the fsspec URL ``url`` (a folder), completeness markers last.

    Returns:
        ``url`` without a trailing slash.
    """
    import fsspec

    fs, base = fsspec.core.url_to_fs(url)
    base = base.rstrip("/")
    root = Path(folder)
    names = [p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file()]
    for name in _ordered(names):
        target = f"{base}/{name}"
        fs.makedirs(target.rsplit("/", 1)[0], exist_ok=True)
        fs.put_file(str(root / name), target)
    return url.rstrip("/")


def run_detached(job_ref: str, job_id: str, spec: dict, threads: int = 0,
                 destination: Optional[str] = None) -> Outcome:
    """Worker side: run one job in a temporary folder of this machine and ship its artefacts (module docstring).

    Args:
        job_ref, job_id, spec, threads: as :func:`meshadv.experiments.worker.execute`.
        destination: an fsspec URL to copy the artefacts to, or ``None`` to return them in the outcome.

    Returns:
        The outcome, with ``artifacts`` (returned files) or ``location`` (the URL folder) set when the job succeeded.
    """
    tmp = tempfile.mkdtemp(prefix=f"meshadv-{job_id}-")
    try:
        outcome = execute(job_ref, job_id, spec, os.path.join(tmp, "job"), threads=threads)
        if not outcome.ok:
            return outcome
        if destination is None:
            return replace(outcome, artifacts=collect_files(os.path.join(tmp, "job")))
        url = f"{destination.rstrip('/')}/jobs/{job_id[:2]}/{job_id}"
        try:
            return replace(outcome, location=upload_folder(os.path.join(tmp, "job"), url))
        except Exception as err:  # noqa: BLE001 - an unreachable bucket fails this attempt, not the sweep
            return Outcome(job_id, False, None, f"uploading artefacts to {url} failed: {type(err).__name__}: {err}",
                           outcome.seconds)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def deliver(outcome: Outcome, out_dir: Union[str, Path]) -> str:
    """Driver side: put a finished job's artefacts in place and return the location to record in the database.

    Returned files are written into ``out_dir``; an uploaded job's location is its URL; otherwise the job wrote
    ``out_dir`` itself (a shared or local file system).
    """
    if outcome.location:
        return outcome.location
    if outcome.artifacts is not None:
        write_files(outcome.artifacts, out_dir)
    return os.fspath(out_dir)
