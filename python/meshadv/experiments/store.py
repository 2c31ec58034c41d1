"""The results database: one SQLite row per job, resumable, crash-safe.

The database is a single SQLite file in WAL mode. Table ``jobs`` holds one row per job, keyed by the deterministic
job id (:func:`meshadv.experiments.spec.job_id`), with its spec, its state and, once done, its results:

``pending`` -> ``running`` (attempts + 1) -> ``done`` | ``failed``; a failed job is retried while
``attempts < max_attempts``. A run that was killed leaves ``running`` rows; :meth:`ResultStore.requeue_running` puts
them back to ``pending`` (the interrupted attempt is not counted) when the next run starts. Every state change is one
transaction, and a ``done`` row is written only after the job's artefacts are in place and is never written again, so a
finished job is never lost nor recorded twice. Table ``meta`` holds the run settings (config text, versions).

Only one driver process writes to a database at a time; :func:`driver_lock` enforces it.

Example:
    >>> store = ResultStore(":memory:")
    >>> store.add_jobs([{"a": 1}])
    1
    >>> store.counts()["pending"]
    1
"""

from __future__ import annotations

import contextlib
import json
import os
import shlex
import socket
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Collection, Dict, Iterable, Iterator, List, Optional, Tuple, Union

from meshadv.experiments.perturbation import PERTURBATION_KEY, Perturbation
from meshadv.experiments.spec import canonical, canonical_json, job_id
from meshadv.util.paths import relative_path

__all__ = ["JobRow", "ResultStore", "check_snapshot_target", "driver_lock", "job_out_dir", "STATES"]

#: The states a job row can be in.
STATES = ("pending", "running", "done", "failed")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    job_id    TEXT PRIMARY KEY,
    spec      TEXT NOT NULL,
    state     TEXT NOT NULL CHECK (state IN ('pending', 'running', 'done', 'failed')),
    attempts  INTEGER NOT NULL DEFAULT 0,
    error     TEXT,
    success   INTEGER,
    distance  REAL,
    steps     INTEGER,
    time_s    REAL,
    out_dir   TEXT,
    record    TEXT,
    created   REAL NOT NULL,
    started   REAL,
    finished  REAL,
    host      TEXT
);
CREATE INDEX IF NOT EXISTS jobs_state ON jobs (state);
CREATE TABLE IF NOT EXISTS meta (
    key   TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS perturbations (
    job_id  TEXT PRIMARY KEY,
    kind    TEXT NOT NULL,
    data    BLOB NOT NULL,
    source  TEXT NOT NULL CHECK (source IN ('attack', 'regenerated'))
);
"""


_SQLITE_MAGIC = b"SQLite format 3\x00"


def _check_existing_file(path: Path) -> bool:
    """True when ``path`` exists; refuse an empty or non-SQLite file with advice instead of overwriting it.

    Raises:
        ValueError: ``path`` is a directory, an empty file or not an SQLite database.
    """
    if not path.exists():
        return False
    if not path.is_file():
        raise ValueError(f"path {str(path)!r} is not a file (a results database was expected)")
    size = path.stat().st_size
    if size == 0:
        raise ValueError(
            f"path {str(path)!r} is an empty file (0 bytes), not a results database: it was truncated or copied "
            "while being written; restore it from a backup or the machine that ran the sweep, or delete it to "
            "start a new sweep"
        )
    with path.open("rb") as fh:
        head = fh.read(len(_SQLITE_MAGIC))
    if head != _SQLITE_MAGIC:
        raise ValueError(f"path {str(path)!r} is not an SQLite database (it does not start with the SQLite header)")
    return True


@dataclass(frozen=True)
class JobRow:
    """One row of the ``jobs`` table.

    Attributes:
        job_id: deterministic id (hash of the canonical spec).
        spec: the job spec.
        state: one of :data:`STATES`.
        attempts: number of started attempts (an attempt interrupted by a killed run is not counted).
        error: the last error (traceback or crash reason), ``None`` when the last attempt succeeded.
        record: the job's result record (``None`` unless done).
        out_dir: where the job wrote its artefacts, on this machine: the database stores it relative to its own
            folder (a URL as it is), so a copied database points into the copy's folder.
        started: UNIX time of the last start, finished: UNIX time of completion (or ``None``).
    """

    job_id: str
    spec: Dict[str, Any]
    state: str
    attempts: int
    error: Optional[str]
    record: Optional[Dict[str, Any]]
    out_dir: Optional[str]
    started: Optional[float]
    finished: Optional[float]


class ResultStore:
    """The SQLite results database of a sweep.

    Args:
        path: database file (created with its folder when missing), or ``":memory:"``.
        timeout: seconds to wait for a lock held by a reader before failing.
        read_only: open an existing database without writing to it (reports, study export): no schema, no open
            mark, no checkpoint, so a committed ``results.db`` stays byte-identical.

    Raises:
        ValueError: ``path`` exists and is not an SQLite database of this format, or it cannot be opened or
            created (a folder this user cannot write).
        FileNotFoundError: ``read_only`` and ``path`` does not exist.
    """

    def __init__(self, path: Union[str, Path], *, timeout: float = 30.0, read_only: bool = False) -> None:
        self.path = str(path)
        self.read_only = bool(read_only) and self.path != ":memory:"
        existed = wal_present = False
        if self.path != ":memory:":
            existed = _check_existing_file(Path(self.path))
            if self.read_only and not existed:
                raise FileNotFoundError(f"path {self.path!r} does not exist (give the results.db of a sweep)")
            wal_present = Path(self.path + "-wal").exists()  # before connecting: connecting creates it
            Path(self.path).parent.mkdir(parents=True, exist_ok=True)
        try:
            if self.read_only:
                uri = Path(self.path).resolve().as_uri() + "?mode=ro"
                self._conn = sqlite3.connect(uri, uri=True, timeout=timeout, isolation_level=None)
            else:
                self._conn = sqlite3.connect(self.path, timeout=timeout, isolation_level=None)
        except sqlite3.OperationalError as err:
            raise self._cannot_open(err) from None
        self._closed = False
        try:
            if existed and not wal_present:
                self._check_not_a_lost_wal_copy()
            if self.read_only:
                self._conn.execute("SELECT count(*) FROM jobs").fetchone()  # not a results database: fails here
                return
            self._conn.execute("PRAGMA journal_mode=WAL")
            self._conn.execute("PRAGMA synchronous=NORMAL")
            self._conn.executescript(_SCHEMA)
        except sqlite3.DatabaseError as err:
            self._closed = True
            self._conn.close()
            if not existed and isinstance(err, sqlite3.OperationalError):
                raise self._cannot_open(err) from None
            raise ValueError(f"path {self.path!r} is not a meshadv results database: {err}") from err
        except ValueError:
            self._closed = True
            self._conn.close()
            raise
        if self.path != ":memory:":
            # Mark the database open in its main file: a copy taken without its -wal file then shows the mark.
            self._conn.execute("INSERT OR REPLACE INTO meta (key, value) VALUES ('open', '1')")
            self.checkpoint()

    def _cannot_open(self, err: Exception) -> ValueError:
        """The error of a database file SQLite cannot open or create (an unwritable folder)."""
        return ValueError(f"path {self.path!r}: cannot open or create the results database there ({err}); give a "
                          "database path in a folder this user can write")

    def _check_not_a_lost_wal_copy(self) -> None:
        """Refuse a database whose write-ahead log is missing (copied without ``<db>-wal``)."""
        wal = Path(self.path + "-wal")
        tables = {r[0] for r in self._conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        advice = (
            f"copy {wal.name} (and {Path(self.path).name}-shm) from where the sweep ran next to it, or open the "
            "original; to start over instead, delete the file"
        )
        if "jobs" not in tables:
            raise ValueError(
                f"path {self.path!r} is an SQLite database without a jobs table: it looks like a copy made "
                f"without its write-ahead log ({wal.name}), which held every result; {advice}"
            )
        if "meta" in tables:
            row = self._conn.execute("SELECT value FROM meta WHERE key = 'open'").fetchone()
            if row is not None and row[0] == "1":
                raise ValueError(
                    f"path {self.path!r} was not closed cleanly and its write-ahead log {wal.name} is missing: "
                    f"results recorded since the last checkpoint are not in this file; {advice}. If this is the "
                    "original file and another SQLite program (e.g. the sqlite3 shell) opened it after the sweep was "
                    "killed, that program moved the log into it and deleted it: nothing is lost, and "
                    f"`sqlite3 {shlex.quote(str(self.path))} \"UPDATE meta SET value = '0' WHERE key = 'open'\"` "
                    "clears the mark"
                )

    def close(self) -> None:
        """Close the connection (after a checkpoint, so the ``.db`` file alone holds every result); closing twice
        does nothing."""
        if self._closed:
            return
        self._closed = True
        if self.read_only:
            self._conn.close()
            return
        if self.path != ":memory:":
            with contextlib.suppress(sqlite3.Error):
                self._conn.execute("INSERT OR REPLACE INTO meta (key, value) VALUES ('open', '0')")
        self.checkpoint()
        self._conn.close()

    def __del__(self) -> None:
        # A store dropped without close() (an exception or an interrupt in its owner): clear the open mark while the
        # connection is alive. Otherwise SQLite's own close at garbage collection checkpoints and deletes the -wal
        # file but leaves the mark, and the next open refuses the file as a copy that lost its write-ahead log.
        if not getattr(self, "_closed", True):
            with contextlib.suppress(Exception):
                self.close()

    def checkpoint(self) -> None:
        """Copy the write-ahead log into the ``.db`` file, so that a copy of that one file (committed to git, moved
        to another machine) holds every recorded result. A busy database is left for the next checkpoint."""
        if self.path != ":memory:":
            with contextlib.suppress(sqlite3.OperationalError):
                self._conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")

    def snapshot(self, path: Union[str, Path]) -> Path:
        """Write a consistent copy of the database to ``path`` atomically (a temporary file beside it, then a rename).

        The copy is a cleanly closed database that a sweep can resume from: a durable copy of the results so far
        (a home folder, a mounted bucket, a git checkout) while the sweep runs on scratch space that may vanish with
        its machine. Jobs running at the time are ``running`` in the copy and run again when a sweep resumes from it.

        Returns:
            ``path`` as a :class:`~pathlib.Path`.

        Raises:
            ValueError: this database is in memory, or ``path`` is the database itself or its write-ahead log.
        """
        if self.path == ":memory:":
            raise ValueError("snapshot needs a database file; this one is ':memory:'")
        check_snapshot_target(self.path, path)
        target = Path(path)
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
        leftovers = [tmp, Path(f"{tmp}-wal"), Path(f"{tmp}-shm")]
        for stale in leftovers:
            stale.unlink(missing_ok=True)
        try:
            copy = sqlite3.connect(tmp, isolation_level=None)
            try:
                self._conn.backup(copy)
                copy.execute("UPDATE meta SET value = '0' WHERE key = 'open'")  # closed cleanly, as far as it knows
                copy.execute("PRAGMA wal_checkpoint(TRUNCATE)")
            finally:
                copy.close()
            with open(tmp, "rb+") as handle:
                os.fsync(handle.fileno())
            os.replace(tmp, target)
        finally:
            for stale in leftovers:
                stale.unlink(missing_ok=True)
        return target

    def __enter__(self) -> "ResultStore":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextlib.contextmanager
    def _transaction(self) -> Iterator[sqlite3.Connection]:
        self._conn.execute("BEGIN IMMEDIATE")
        try:
            yield self._conn
        except BaseException:
            self._conn.execute("ROLLBACK")
            raise
        self._conn.execute("COMMIT")

    # ------------------------------------------------------------------ meta
    def set_meta(self, key: str, value: Any) -> None:
        """Store a JSON-able value under ``key`` in the ``meta`` table (replacing it)."""
        with self._transaction() as conn:
            conn.execute("INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)", (key, json.dumps(value)))

    def get_meta(self, key: str, default: Any = None) -> Any:
        """Return the value stored under ``key``, or ``default``."""
        row = self._conn.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return default if row is None else json.loads(row[0])

    def meta(self) -> Dict[str, Any]:
        """Return every ``meta`` entry as a dict."""
        return {k: json.loads(v) for k, v in self._conn.execute("SELECT key, value FROM meta ORDER BY key")}

    # ------------------------------------------------------------------ jobs
    def add_jobs(self, specs: Iterable[Dict[str, Any]]) -> int:
        """Insert jobs as ``pending``; jobs already present (same id) are left untouched.

        Args:
            specs: job specs.

        Returns:
            The number of new rows.
        """
        now = time.time()
        rows = [(job_id(s), canonical_json(s), now) for s in specs]
        with self._transaction() as conn:
            before = conn.total_changes
            conn.executemany(
                "INSERT OR IGNORE INTO jobs (job_id, spec, state, created) VALUES (?, ?, 'pending', ?)", rows
            )
            return conn.total_changes - before

    def requeue_running(self) -> int:
        """Put the ``running`` rows left by a killed run back to ``pending`` (their attempt is not counted).

        Returns:
            The number of re-queued jobs.
        """
        with self._transaction() as conn:
            cur = conn.execute(
                "UPDATE jobs SET state = 'pending', attempts = MAX(attempts - 1, 0) WHERE state = 'running'"
            )
            return cur.rowcount

    def runnable(self, max_attempts: int) -> List[str]:
        """Ids of the jobs to run: pending ones and failed ones with ``attempts < max_attempts``, in insertion order.

        Args:
            max_attempts: the bounded number of attempts per job (>= 1).
        """
        if max_attempts < 1:
            raise ValueError(f"max_attempts must be >= 1, got {max_attempts}")
        cur = self._conn.execute(
            "SELECT job_id FROM jobs WHERE state = 'pending' OR (state = 'failed' AND attempts < ?) ORDER BY rowid",
            (max_attempts,),
        )
        return [r[0] for r in cur]

    def spec(self, job: str) -> Dict[str, Any]:
        """Return the spec of job ``job``.

        Raises:
            KeyError: no such job.
        """
        row = self._conn.execute("SELECT spec FROM jobs WHERE job_id = ?", (job,)).fetchone()
        if row is None:
            raise KeyError(job)
        return json.loads(row[0])

    def attempts(self, job: str) -> int:
        """Number of counted attempts of job ``job``.

        Raises:
            KeyError: no such job.
        """
        row = self._conn.execute("SELECT attempts FROM jobs WHERE job_id = ?", (job,)).fetchone()
        if row is None:
            raise KeyError(job)
        return int(row[0])

    def mark_running(self, job: str) -> int:
        """Mark a pending/failed job ``running`` and count the attempt.

        Returns:
            The attempt number (1 for the first).

        Raises:
            KeyError: no such job. ValueError: the job is already done or running.
        """
        with self._transaction() as conn:
            row = conn.execute("SELECT state, attempts FROM jobs WHERE job_id = ?", (job,)).fetchone()
            if row is None:
                raise KeyError(job)
            if row[0] not in ("pending", "failed"):
                raise ValueError(f"job {job} is {row[0]}, cannot start it")
            conn.execute(
                "UPDATE jobs SET state = 'running', attempts = attempts + 1, started = ?, host = ? WHERE job_id = ?",
                (time.time(), socket.gethostname(), job),
            )
            return int(row[1]) + 1

    def mark_done(self, job: str, record: Dict[str, Any], out_dir: Optional[str] = None) -> bool:
        """Record a finished job in one transaction (only a ``running`` row changes, so nothing is written twice).

        Args:
            job: the job id.
            record: the job's JSON-able result record; ``success``, ``distance``, ``steps`` and ``time`` keys, when
                present, are also stored in their own columns.
            out_dir: the job's artefact folder.

        Returns:
            ``True`` when the row changed, ``False`` when the job was not running (e.g. already done).
        """
        record = dict(record)
        packed = record.pop(PERTURBATION_KEY, None)
        rec = canonical(record)
        success = rec.get("success")
        with self._transaction() as conn:
            cur = conn.execute(
                "UPDATE jobs SET state = 'done', error = NULL, success = ?, distance = ?, steps = ?, time_s = ?, "
                "record = ?, out_dir = ?, finished = ? WHERE job_id = ? AND state = 'running'",
                (
                    None if success is None else int(bool(success)),
                    rec.get("distance"),
                    rec.get("steps"),
                    rec.get("time"),
                    json.dumps(rec, sort_keys=True),
                    self._stored_dir(out_dir),
                    time.time(),
                    job,
                ),
            )
            if cur.rowcount == 1 and packed is not None:
                self._put_perturbation(conn, job, Perturbation.from_record(packed), "attack")
            return cur.rowcount == 1

    def _stored_dir(self, out_dir: Optional[str]) -> Optional[str]:
        """``out_dir`` as the database keeps it: relative to the database's folder (a URL as it is)."""
        if out_dir is None or "://" in str(out_dir) or self.path == ":memory:":
            return None if out_dir is None else str(out_dir)
        return relative_path(out_dir, Path(self.path).resolve().parent)

    def _local_dir(self, stored: Optional[str]) -> Optional[str]:
        """A stored ``out_dir`` on this machine: a relative one joined to the database's folder."""
        if not stored or "://" in stored or Path(stored).is_absolute() or self.path == ":memory:":
            return stored
        return os.path.normpath(Path(self.path).resolve().parent / stored)

    @staticmethod
    def _put_perturbation(conn: sqlite3.Connection, job: str, packed: "Perturbation", source: str) -> None:
        conn.execute("INSERT OR REPLACE INTO perturbations (job_id, kind, data, source) VALUES (?, ?, ?, ?)",
                     (job, packed.kind, packed.data, source))

    def put_perturbation(self, job: str, packed: "Perturbation", source: str) -> None:
        """Keep a finished job's perturbation (:class:`~meshadv.experiments.perturbation.Perturbation`).

        Args:
            job: the job id. packed: the perturbation. source: ``"attack"`` (the job's own) or ``"regenerated"``
                (a rerun's, which may differ from the attack the tables counted: another CPU's kernels).
        """
        if source not in ("attack", "regenerated"):
            raise ValueError(f"source must be 'attack' or 'regenerated', got {source!r}")
        with self._transaction() as conn:
            self._put_perturbation(conn, job, packed, source)

    def perturbation(self, job: str) -> "Optional[Tuple[Perturbation, str]]":
        """``(perturbation, source)`` kept for ``job``, or ``None`` (none kept, or a database older than the table)."""
        try:
            row = self._conn.execute("SELECT kind, data, source FROM perturbations WHERE job_id = ?",
                                     (job,)).fetchone()
        except sqlite3.OperationalError:  # no such table: a database written before perturbations were kept
            return None
        if row is None:
            return None
        return Perturbation.from_kind(str(row[0]), bytes(row[1])), str(row[2])

    def mark_failed(self, job: str, error: str) -> bool:
        """Record a failed attempt (exception traceback or crash reason) of a ``running`` job.

        Returns:
            ``True`` when the row changed.
        """
        with self._transaction() as conn:
            cur = conn.execute(
                "UPDATE jobs SET state = 'failed', error = ?, finished = ? WHERE job_id = ? AND state = 'running'",
                (error, time.time(), job),
            )
            return cur.rowcount == 1

    def damaged_results(self, marker: str = "result.json") -> List[Tuple[str, str]]:
        """Finished jobs whose artefact folder (on this machine) holds an unreadable ``marker`` file.

        A folder that is absent is not reported (the artefacts live on another machine, or were not kept), nor is a
        job its record marks ``skipped`` (e.g. a benign render the victim misclassifies: no attack ran, so no
        ``marker`` was written); a ``result.json`` that is missing, empty, truncated or not JSON is.

        Returns:
            ``(job_id, reason)`` pairs.
        """
        damaged = []
        for row in self.rows("done"):
            if not row.out_dir or not Path(row.out_dir).is_dir() or (row.record or {}).get("skipped"):
                continue
            path = Path(row.out_dir) / marker
            if not path.is_file():
                damaged.append((row.job_id, f"{path} is missing"))
                continue
            try:
                json.loads(path.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError, ValueError) as err:
                damaged.append((row.job_id, f"{path} is truncated or not JSON ({err})"))
        return damaged

    def counts(self, job_ids: Optional[Collection[str]] = None) -> Dict[str, int]:
        """Number of jobs in each state (every state present, zero when empty), plus ``total`` and ``successes``.

        Args:
            job_ids: count only these jobs (ids not in the database are not counted); ``None``: every job.
        """
        out = {s: 0 for s in STATES}
        successes = 0
        wanted = None if job_ids is None else set(job_ids)
        for jid, state, success in self._conn.execute("SELECT job_id, state, success FROM jobs"):
            if wanted is None or jid in wanted:
                out[state] += 1
                successes += int(state == "done" and success == 1)
        out["total"] = sum(out[s] for s in STATES)
        out["successes"] = successes
        return out

    def rows(self, state: Optional[str] = None) -> List[JobRow]:
        """All job rows (optionally only those in ``state``), in insertion order."""
        if state is not None and state not in STATES:
            raise ValueError(f"state must be one of {STATES}, got {state!r}")
        query = "SELECT job_id, spec, state, attempts, error, record, out_dir, started, finished FROM jobs"
        args: tuple = ()
        if state is not None:
            query += " WHERE state = ?"
            args = (state,)
        out = []
        for r in self._conn.execute(query + " ORDER BY rowid", args):
            out.append(
                JobRow(
                    job_id=r[0],
                    spec=json.loads(r[1]),
                    state=r[2],
                    attempts=int(r[3]),
                    error=r[4],
                    record=None if r[5] is None else json.loads(r[5]),
                    out_dir=self._local_dir(r[6]),
                    started=r[7],
                    finished=r[8],
                )
            )
        return out


def job_out_dir(out_root: Union[str, Path], job_id: str) -> Path:
    """Artefact folder of a job: ``<out_root>/jobs/<first 2 hex digits>/<job_id>``."""
    return Path(out_root) / "jobs" / job_id[:2] / job_id


def check_snapshot_target(db_path: Union[str, Path], target: Union[str, Path]) -> None:
    """Refuse ``target`` as the place of :meth:`ResultStore.snapshot`'s copy of the database ``db_path`` when it is
    that database itself (or its write-ahead log or shared-memory file).

    Raises:
        ValueError: naming ``target``.
    """
    own = Path(db_path).resolve()
    if Path(target).resolve() in (own, Path(f"{own}-wal"), Path(f"{own}-shm")):
        raise ValueError(f"path {str(target)!r} is the database itself; give another file for its copy")


@contextlib.contextmanager
def driver_lock(db_path: Union[str, Path]) -> Iterator[None]:
    """Hold an exclusive lock on ``<db_path>.lock`` so that only one sweep driver uses a database at a time.

    Args:
        db_path: the database path.

    Raises:
        RuntimeError: another live process holds the lock.
    """
    if str(db_path) == ":memory:":
        yield
        return
    try:
        import fcntl
    except ImportError:  # pragma: no cover - non-POSIX
        yield
        return
    lock_path = f"{db_path}.lock"
    Path(lock_path).parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as err:
            raise RuntimeError(f"another sweep is already running on {db_path} (lock {lock_path} is held)") from err
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield
    finally:
        os.close(fd)
