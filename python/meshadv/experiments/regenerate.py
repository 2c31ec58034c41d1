"""Per-job artefacts on demand: re-run a finished job from the spec and seed stored in the results database.

The database alone holds everything the tables need; meshes and renders (figures, the Mitsuba transfer pass) are
regenerated from a job's stored spec (which carries its seed) by running the same job function again into a folder
of the caller's choice. The database is only read: the regenerated record is compared with the stored one (success,
steps, distance), so a drift between the code that ran the sweep and the code that regenerates is visible.

Example:
    >>> out = regenerate_job("out/paper_medium/results.db", "0f3a9c...", "out/regen")   # doctest: +SKIP
    >>> out.matches, out.out_dir                                                        # doctest: +SKIP
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Optional, Union

from meshadv.experiments.runner import job_out_dir
from meshadv.experiments.store import ResultStore
from meshadv.experiments.worker import execute

__all__ = ["Regenerated", "regenerate_job", "ensure_artifacts", "stored_job_ref", "COMPARED_KEYS"]

#: Record keys compared between the stored and the regenerated record (floats to a relative 1e-3).
COMPARED_KEYS = ("success", "skipped", "steps", "distance")


@dataclass(frozen=True)
class Regenerated:
    """A regenerated job.

    Attributes:
        job_id: the job. out_dir: where its artefacts now are. record: the new record.
        stored: the record in the database (``None`` when the job had not finished).
        differences: ``"key: stored -> new"`` for each of :data:`COMPARED_KEYS` that differs; empty when it matches.
    """

    job_id: str
    out_dir: Path
    record: Dict[str, Any]
    stored: Optional[Dict[str, Any]]
    differences: List[str]

    @property
    def matches(self) -> bool:
        """Whether the regenerated record agrees with the stored one on :data:`COMPARED_KEYS`."""
        return self.stored is not None and not self.differences


def stored_job_ref(store: ResultStore) -> str:
    """The job function the sweep ran (``[runner] job`` of the config text stored in the database, else the default)."""
    from meshadv.experiments.config import DEFAULT_JOB

    text = store.get_meta("config_text")
    if not text:
        return DEFAULT_JOB
    try:
        import tomllib

        raw = tomllib.loads(text)
    except Exception:  # noqa: BLE001 - a YAML config or an old database: fall back to YAML, then the default
        try:
            import yaml

            raw = yaml.safe_load(text) or {}
        except Exception:  # noqa: BLE001
            return DEFAULT_JOB
    return str((raw.get("runner") or {}).get("job", DEFAULT_JOB))


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, (int, float)) and not isinstance(b, bool):
        return math.isclose(a, float(b), rel_tol=1e-3, abs_tol=1e-9)
    return a == b


def regenerate_job(db_path: Union[str, Path], job: str, out_dir: Optional[Union[str, Path]] = None, *,
                   threads: int = 0) -> Regenerated:
    """Run job ``job`` of the database again into ``out_dir`` and compare its record with the stored one.

    Args:
        db_path: the results database.
        job: the job id (a unique prefix is enough).
        out_dir: the artefact folder (created; default ``<database folder>/jobs/<id[:2]>/<id>``).
        threads: intra-op threads (0 = process default).

    Returns:
        A :class:`Regenerated`.

    Raises:
        FileNotFoundError: no database. KeyError: no such job, or an ambiguous prefix.
        RuntimeError: the job failed (its traceback in the message).
    """
    db = Path(db_path)
    if not db.is_file():
        raise FileNotFoundError(f"results database {db} does not exist")
    with ResultStore(db) as store:
        ids = [r.job_id for r in store.rows() if r.job_id.startswith(job)]
        if len(ids) != 1:
            raise KeyError(f"job {job!r} matches {len(ids)} jobs of {db} (give the full 16-digit id)")
        (jid,) = ids
        row = next(r for r in store.rows() if r.job_id == jid)
        ref = stored_job_ref(store)
    out = Path(out_dir) if out_dir is not None else job_out_dir(db.parent, jid)
    outcome = execute(ref, jid, row.spec, str(out), threads=threads)
    if not outcome.ok or outcome.record is None:
        raise RuntimeError(f"job {jid} failed while regenerating:\n{outcome.error}")
    stored = row.record if row.state == "done" else None
    diffs = []
    if stored is not None:
        for key in COMPARED_KEYS:
            if key in stored and not _same(stored.get(key), outcome.record.get(key)):
                diffs.append(f"{key}: {stored.get(key)!r} -> {outcome.record.get(key)!r}")
    return Regenerated(jid, out, outcome.record, stored, diffs)


def ensure_artifacts(db_path: Union[str, Path], job: str, artifact_root: Union[str, Path],
                     stored_out_dir: Optional[str] = None, marker: str = "result.json") -> Path:
    """The artefact folder of a finished job, regenerated when neither its stored folder nor
    ``<artifact_root>/jobs/..`` holds ``marker``.

    Args:
        db_path: the results database.
        job: the full job id.
        artifact_root: where regenerated artefacts go (``job_out_dir(artifact_root, job)``), e.g. the database's folder.
        stored_out_dir: the folder the database records for the job (another machine's path, perhaps).
        marker: the file that proves a folder complete (the attack job writes ``result.json`` last).

    Returns:
        A folder holding the job's artefacts.
    """
    for folder in (stored_out_dir, job_out_dir(artifact_root, job)):
        if folder and (Path(folder) / marker).is_file():
            return Path(folder)
    return regenerate_job(db_path, job, job_out_dir(artifact_root, job)).out_dir
