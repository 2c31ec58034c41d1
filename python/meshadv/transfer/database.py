"""The ``transfer`` table of the sweep's SQLite database: write transfer rows (:func:`save_transfer_rows`) and read
them back (:func:`load_transfer_rows`).

The rows live in their own table ``transfer`` of the same database file as the sweep's ``jobs`` table (WAL mode, one
transaction per insert), so the report can read both. One row per (case, view) evaluation::

    transfer(id INTEGER PRIMARY KEY, experiment TEXT, kind TEXT, case_id TEXT, victim TEXT, true_class TEXT,
             target TEXT, perturbation TEXT, view INTEGER, success_meshadv INTEGER, success_mitsuba INTEGER,
             record TEXT (JSON), created REAL, UNIQUE(experiment, kind, case_id, view))

``kind`` is ``"controlled"`` or ``"blackbox"``; ``target`` is ``""`` for untargeted attacks. The records are the
typed rows of :mod:`meshadv.transfer.results` as dicts (their ``to_record()``).
"""

from __future__ import annotations

import contextlib
import json
import sqlite3
import time
from pathlib import Path
from typing import Any, Iterable, Iterator, Optional, Union

from meshadv import _validate

__all__ = ["load_transfer_rows", "save_transfer_rows"]

#: The ``transfer`` table.
_SCHEMA = """
CREATE TABLE IF NOT EXISTS transfer (
    id              INTEGER PRIMARY KEY AUTOINCREMENT,
    experiment      TEXT NOT NULL,
    kind            TEXT NOT NULL,
    case_id         TEXT NOT NULL,
    victim          TEXT NOT NULL,
    true_class      TEXT NOT NULL,
    target          TEXT NOT NULL,
    perturbation     TEXT NOT NULL,
    view            INTEGER NOT NULL,
    success_meshadv INTEGER,
    success_mitsuba INTEGER,
    record          TEXT NOT NULL,
    created         REAL NOT NULL,
    UNIQUE (experiment, kind, case_id, view)
);
"""

_COLUMNS = ("case_id", "victim", "true_class", "target", "perturbation", "view")


#: The column's name before issue 13 gave the concept one name (``perturbation``); old databases are migrated.
_LEGACY_PERTURBATION = "attack_type"


def _connect(db_path: Union[str, Path]) -> sqlite3.Connection:
    """A read-write connection (WAL mode) with the ``transfer`` table created, and renamed from an old database's
    ``attack_type`` column."""
    conn = sqlite3.connect(str(db_path), timeout=30.0)
    conn.execute("PRAGMA journal_mode=WAL")
    columns = {r[1] for r in conn.execute("PRAGMA table_info(transfer)")}
    if _LEGACY_PERTURBATION in columns and "perturbation" not in columns:  # a database written before issue 13
        with conn:
            conn.execute(f"ALTER TABLE transfer RENAME COLUMN {_LEGACY_PERTURBATION} TO perturbation")
    conn.executescript(_SCHEMA)
    return conn


@contextlib.contextmanager
def _read_only(db_path: Union[str, Path]) -> Iterator[sqlite3.Connection]:
    """A connection that only reads: reports leave a committed database byte-identical (old column names are
    handled when rows are read, see :func:`_with_perturbation`).

    Raises:
        FileNotFoundError: ``db_path`` does not exist.
    """
    if not Path(db_path).is_file():
        raise FileNotFoundError(f"db_path {db_path} does not exist")
    conn = sqlite3.connect(Path(db_path).resolve().as_uri() + "?mode=ro", uri=True, timeout=30.0)
    try:
        yield conn
    finally:
        conn.close()


def _with_perturbation(row: dict[str, Any]) -> dict[str, Any]:
    """A stored record with the perturbation under its one name (old records say ``attack_type``)."""
    if _LEGACY_PERTURBATION in row and "perturbation" not in row:
        row = dict(row)
        row["perturbation"] = row.pop(_LEGACY_PERTURBATION)
    return row


#: The kinds of transfer row.
KINDS = ("controlled", "blackbox")


def _check_selection(experiment: Optional[str], kind: Optional[str]) -> None:
    """Raise unless ``experiment`` is a non-empty string and ``kind`` one of :data:`KINDS` (either may be None)."""
    if experiment is not None and not isinstance(experiment, str):
        raise TypeError(f"experiment must be a string, got {type(experiment).__name__}")
    if experiment == "":
        raise ValueError("experiment must be a non-empty name")
    if kind is not None:
        _validate.choice("kind", kind, KINDS)


def save_transfer_rows(
    db_path: Union[str, Path], rows: Iterable[dict[str, Any]], *, experiment: str = "default", kind: str = "controlled"
) -> int:
    """Insert (or replace) transfer rows into the ``transfer`` table of ``db_path``.

    Args:
        db_path: the SQLite database (the sweep's ``results.db``; created if missing).
        rows: dicts with at least ``case_id, victim, true_class, target, perturbation, view`` and the booleans
            ``success_meshadv`` / ``success_mitsuba`` (any other keys are kept in the JSON record).
        experiment: experiment name (several transfer runs can share a database).
        kind: ``"controlled"`` or ``"blackbox"``.

    Returns:
        The number of rows written.

    Raises:
        TypeError: ``experiment`` or ``kind`` is not a string.
        ValueError: a row lacks a required key, ``kind`` is unknown or ``experiment`` is empty.
    """
    if experiment is None or kind is None:
        raise TypeError(f"experiment and kind must be strings, got {experiment!r} and {kind!r}")
    _check_selection(experiment, kind)
    rows = list(rows)
    for i, row in enumerate(rows):
        missing = [c for c in _COLUMNS if c not in row]
        if missing:
            raise ValueError(f"rows[{i}] is missing keys {missing}")
    Path(db_path).parent.mkdir(parents=True, exist_ok=True)
    conn = _connect(db_path)
    try:
        with conn:
            for row in rows:
                conn.execute(
                    "INSERT OR REPLACE INTO transfer (experiment, kind, case_id, victim, true_class, target, "
                    "perturbation, view, success_meshadv, success_mitsuba, record, created) "
                    "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    (
                        experiment,
                        kind,
                        str(row["case_id"]),
                        str(row["victim"]),
                        str(row["true_class"]),
                        str(row["target"] or ""),
                        str(row["perturbation"]),
                        int(row["view"]),
                        None if row.get("success_meshadv") is None else int(bool(row["success_meshadv"])),
                        None if row.get("success_mitsuba") is None else int(bool(row["success_mitsuba"])),
                        json.dumps(row, default=str, sort_keys=True),
                        time.time(),
                    ),
                )
    finally:
        conn.close()
    return len(rows)


def load_transfer_rows(
    db_path: Union[str, Path], *, experiment: Optional[str] = None, kind: Optional[str] = None
) -> list[dict[str, Any]]:
    """Read transfer rows (their JSON records plus ``experiment`` and ``kind``); ``[]`` when the database has no
    ``transfer`` table yet. The database is only read (no table is created).

    Args:
        db_path: the database.
        experiment: only this experiment (default all).
        kind: only this kind (default all).

    Raises:
        FileNotFoundError: ``db_path`` does not exist.
        TypeError: ``experiment`` is neither a string nor None.
        ValueError: ``kind`` is neither ``"controlled"``, ``"blackbox"`` nor None, or ``experiment`` is empty.
    """
    _check_selection(experiment, kind)
    with _read_only(db_path) as conn:
        if not conn.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'transfer'").fetchone():
            return []  # no transfer pass has written to this database yet
        query, args = "SELECT experiment, kind, record FROM transfer WHERE 1=1", []
        if experiment is not None:
            query += " AND experiment = ?"
            args.append(experiment)
        if kind is not None:
            query += " AND kind = ?"
            args.append(kind)
        out = []
        for exp, knd, record in conn.execute(query + " ORDER BY id", args):
            row = _with_perturbation(json.loads(record))
            row.update(experiment=exp, kind=knd)
            out.append(row)
        return out
