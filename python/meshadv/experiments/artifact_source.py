"""Where the report finds a finished job's artefacts (meshes, renders): on this machine, or regenerated from the
database's stored spec and seed (:class:`ArtifactSource`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Dict, List, Optional, Union

from meshadv.experiments.store import JobRow
from meshadv.util.atomic import write_text_atomic

__all__ = ["ArtifactSource", "artifact_path"]


def _artifact_names(record: Dict[str, Any]) -> List[str]:
    """The file names a record's ``artifacts`` lists (relative ones: what a complete job folder holds)."""
    names: List[str] = []
    for value in (record.get("artifacts") or {}).values():
        for name in value if isinstance(value, list) else [value]:
            if isinstance(name, str) and name and not Path(name).is_absolute():
                names.append(name)
    return names


def _complete(folder: Optional[Union[str, Path]], record: Dict[str, Any]) -> bool:
    """Whether ``folder`` holds every artefact ``record`` lists (a folder the job finished writing)."""
    if not folder or "://" in str(folder):
        return False
    names = _artifact_names(record)
    return bool(names) and all((Path(folder) / n).is_file() for n in names)


def _read_check(path: Path) -> Optional[Dict[str, Any]]:
    """The regeneration check stored at ``path``, or ``None`` when there is none or it is not a JSON object (a file
    cut short by a kill under an older version, which wrote it in place): the job is then regenerated again."""
    try:
        check = json.loads(path.read_text(encoding="utf-8"))
    except (FileNotFoundError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return check if isinstance(check, dict) else None


class ArtifactSource:
    """Where the report finds the artefacts (meshes, renders) of a finished job.

    The folder the database records for the job when it is complete on this machine (``use_stored``), else
    ``<root>/jobs/<id[:2]>/<id>`` when it is complete there (rebuilt or regenerated earlier), else, with ``root`` set,
    the job is rebuilt there from the perturbation the database keeps (:func:`meshadv.experiments.rebuild.
    rebuild_job`; its check says so), else (``regenerate_missing``) regenerated there from its stored spec and seed
    (:func:`meshadv.experiments.regenerate.regenerate_job`) and its new record is compared with the stored one; each
    regeneration's check is kept in :attr:`checks` and written to ``regeneration.json`` in the job's folder (read
    back when a later report reuses the folder).

    Args:
        db_path: the results database. root: the folder for regenerated artefacts (``None``: never regenerate).
        use_stored: use the folders the database records. threads: intra-op threads of a regeneration.
        regenerate_missing: regenerate a job the database keeps no perturbation of (``False``: rebuild only, and say
            in one line which jobs are left out).
        assume: the sweep's defaults for records that do not pin them (:func:`~meshadv.experiments.regenerate.
            pinned_spec`).
    """

    def __init__(self, db_path: Union[str, Path], root: Optional[Union[str, Path]] = None, *,
                 use_stored: bool = True, threads: int = 1, assume: Optional[Dict[str, Any]] = None,
                 regenerate_missing: bool = True) -> None:
        self.db_path = Path(db_path)
        self.regenerate_missing = bool(regenerate_missing)
        self._told: set = set()
        self.root = None if root is None else Path(root)
        self.use_stored = bool(use_stored)
        self.threads = int(threads)
        self.assume = dict(assume or {})
        self.checks: Dict[str, Dict[str, Any]] = {}
        self._folders: Dict[str, Optional[Path]] = {}

    def folder(self, row: JobRow, *, regenerate: bool = True) -> Optional[Path]:
        """The job's complete artefact folder, regenerating it when allowed and needed; ``None`` when there is none."""
        if row.job_id in self._folders and (self._folders[row.job_id] is not None or not regenerate):
            return self._folders[row.job_id]
        record = row.record or {}
        found: Optional[Path] = None
        if self.use_stored and _complete(row.out_dir, record):
            found = Path(str(row.out_dir))
        elif self.root is not None:
            from meshadv.experiments.store import job_out_dir

            target = job_out_dir(self.root, row.job_id)
            check = _read_check(target / "regeneration.json") if _complete(target, record) else None
            if check is not None:
                found = target
                self.checks[row.job_id] = check
            elif regenerate:
                found = self._rebuild(row, target)
                if found is None and self.regenerate_missing:
                    found = self._regenerate(row, target)
                elif found is None and row.job_id not in self._told:
                    from meshadv.experiments.rebuild import say_on_stderr

                    self._told.add(row.job_id)
                    say_on_stderr(f"job {row.job_id}: its artefacts are not here and the database keeps no "
                                  "perturbation of it; not regenerated (`meshadv report --artifacts DIR` "
                                  "regenerates it)")
        self._folders[row.job_id] = found
        return found

    def _rebuild(self, row: JobRow, target: Path) -> Optional[Path]:
        """The job's folder rebuilt from the perturbation the database keeps (``None`` when it keeps none)."""
        from meshadv.experiments.rebuild import rebuild_job, say_on_stderr

        found = rebuild_job(self.db_path, row, target)
        if found is not None:
            say_on_stderr(f"job {row.job_id}: artefacts rebuilt from the perturbation kept in the database, into "
                          f"{found}")
            self.checks[row.job_id] = {"job_id": row.job_id, "matches": True, "rebuilt": True, "differences": [],
                                       "notes": ["rebuilt from the stored perturbation: no attack ran"]}
            write_text_atomic(found / "regeneration.json", json.dumps(self.checks[row.job_id], indent=2))
        return found

    def _regenerate(self, row: JobRow, target: Path) -> Path:
        import time

        from meshadv.experiments.rebuild import regeneration_warning, say_on_stderr
        from meshadv.experiments.regenerate import regenerate_job

        say_on_stderr(f"job {row.job_id}: the database keeps no perturbation of this job; regenerating it from its "
                      f"stored spec and seed into {target}")
        cpu = time.process_time()
        done = regenerate_job(self.db_path, row.job_id, target, threads=self.threads, assume=self.assume)
        check = {"job_id": row.job_id, "matches": done.matches, "differences": list(done.differences),
                 "notes": list(done.notes), "cpu_s": round(time.process_time() - cpu, 2),
                 "stored": {k: (done.stored or {}).get(k) for k in ("success", "steps", "distance", "compute")},
                 "regenerated": {k: done.record.get(k) for k in ("success", "steps", "distance", "compute")}}
        write_text_atomic(target / "regeneration.json", json.dumps(check, indent=2, sort_keys=True))
        self.checks[row.job_id] = check
        warning = regeneration_warning(done)
        if warning is not None:
            say_on_stderr(warning)
        return target


def artifact_path(row: JobRow, key: str, index: int = 0, source: Optional[ArtifactSource] = None) -> Optional[Path]:
    """The file of the record's artefact ``key`` (its ``index``-th when a list) of a finished job, from ``source`` (the
    folder the database records when ``None``); ``None`` when the record lists none or the file is not there."""
    arts = (row.record or {}).get("artifacts", {})
    value = arts.get(key)
    if isinstance(value, list):
        value = value[index] if index < len(value) else None
    if not value:
        return None
    if source is not None:
        folder = source.folder(row)
    else:
        folder = None if row.out_dir is None else Path(row.out_dir)
    if folder is None:
        return None
    path = folder / value
    return path if path.exists() else None
