"""A readable index of a sweep's job folders (which are named by job hash), and the failed jobs' errors.

``meshadv sweep`` writes ``<output>/index.csv`` and ``<output>/index.md`` at the end of every run and
``meshadv report`` writes them into the report folder: one row per job with its folder, state, victim, mesh,
class, target, perturbation, success and, for failed jobs, the last line of the error. Folders are relative to the
index's folder.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any, Dict, List, Optional, Union

__all__ = ["INDEX_COLUMNS", "error_line", "failed_jobs", "index_rows", "warn_damaged_results", "write_job_index"]

#: Columns of the index.
INDEX_COLUMNS = ("job_id", "folder", "state", "attempts", "victim", "mesh", "class", "target", "perturbation", "kind",
                 "success", "error")


def error_line(error: Optional[str]) -> str:
    """The last non-empty line of a stored error (a traceback ends with the exception and its message)."""
    lines = [line.strip() for line in (error or "").splitlines() if line.strip()]
    return lines[-1] if lines else ""


def index_rows(store: Any, out_root: Optional[Union[str, Path]] = None) -> List[Dict[str, Any]]:
    """One dict per job of ``store`` (a ``ResultStore``), in :data:`INDEX_COLUMNS` order."""
    from meshadv.experiments.store import job_out_dir

    rows = []
    for job in store.rows():
        spec = job.spec or {}
        mesh = spec.get("mesh") or {}
        record = job.record or {}
        folder = job.out_dir or (str(job_out_dir(out_root, job.job_id)) if out_root is not None else "")
        success = record.get("success")
        rows.append({
            "job_id": job.job_id,
            "folder": folder,
            "state": job.state,
            "attempts": job.attempts,
            "victim": spec.get("victim", ""),
            "mesh": mesh.get("path", "") if isinstance(mesh, dict) else str(mesh),
            "class": spec.get("source_class", ""),
            "target": spec.get("target", ""),
            "perturbation": spec.get("perturbation", ""),
            "kind": spec.get("kind", ""),
            "success": "" if success is None else bool(success),
            "error": error_line(job.error) if job.state == "failed" else "",
        })
    return rows


def failed_jobs(store: Any) -> List[Dict[str, Any]]:
    """``{"job_id", "attempts", "error"}`` of every failed job (``error``: the last line of its traceback)."""
    return [{"job_id": r.job_id, "attempts": r.attempts, "error": error_line(r.error)} for r in store.rows("failed")]


def write_job_index(store: Any, folder: Union[str, Path], out_root: Optional[Union[str, Path]] = None) -> Path:
    """Write ``index.csv`` and ``index.md`` (job id -> folder, settings, state, error) into ``folder`` atomically.

    The job folders are written relative to ``folder`` (a URL as it is), so a copied results folder keeps its index
    right and carries no path of the machine that wrote it.

    Returns:
        The path of ``index.csv``.
    """
    from meshadv.util.atomic import write_text_atomic
    from meshadv.util.paths import relative_path

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rows = index_rows(store, out_root)
    for row in rows:
        if row["folder"] and "://" not in row["folder"]:
            row["folder"] = relative_path(row["folder"], folder)
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=INDEX_COLUMNS)
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomic(folder / "index.csv", buffer.getvalue())
    lines = ["| " + " | ".join(INDEX_COLUMNS) + " |", "|" + " --- |" * len(INDEX_COLUMNS)]
    for row in rows:
        lines.append("| " + " | ".join(str(row[c]).replace("|", "\\|") for c in INDEX_COLUMNS) + " |")
    write_text_atomic(folder / "index.md", "# Jobs\n\n" + "\n".join(lines) + "\n")
    return folder / "index.csv"


def warn_damaged_results(store: Any, db_path: Union[str, Path], *, limit: int = 10) -> int:
    """Print (to stderr) the finished jobs of ``store`` whose ``result.json`` is missing or truncated, each with the
    ``meshadv regenerate`` command that rebuilds it; returns how many there are."""
    import typer

    damaged = store.damaged_results()
    for job, reason in damaged[:limit]:
        typer.echo(f"warning: job {job} is recorded as done but {reason}; rebuild its artefacts with "
                   f"`meshadv regenerate {db_path} {job}`", err=True)
    if len(damaged) > limit:
        typer.echo(f"warning: {len(damaged) - limit} more finished job(s) have damaged artefacts", err=True)
    return len(damaged)
