"""Transfer results: the typed rows of a run (:class:`ControlledResult`, :class:`BlackBoxResult`) and their table in
the sweep's SQLite database (:func:`save_transfer_rows`, :func:`load_transfer_rows`). The paper's tables made from
them are in :mod:`meshadv.transfer.tables` (re-exported here).

The rows live in their own table ``transfer`` of the same database file as the sweep's ``jobs`` table (WAL mode, one
transaction per insert), so the report can read both. One row per (case, view) evaluation::

    transfer(id INTEGER PRIMARY KEY, experiment TEXT, kind TEXT, case_id TEXT, victim TEXT, true_class TEXT,
             target TEXT, perturbation TEXT, view INTEGER, success_meshadv INTEGER, success_mitsuba INTEGER,
             record TEXT (JSON), created REAL, UNIQUE(experiment, kind, case_id, view))

``kind`` is ``"controlled"`` or ``"blackbox"``; ``target`` is ``""`` for untargeted attacks.
"""

from __future__ import annotations

import contextlib
import json
import math
import sqlite3
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Optional, Union

from meshadv.transfer.tables import (
    BLACKBOX_ESTIMATION_COLUMNS,
    BLACKBOX_MARGIN_COLUMNS,
    BLACKBOX_OUTCOME_COLUMNS,
    BLACKBOX_SCORE_COLUMNS,
    BLACKBOX_SETTINGS_COLUMNS,
    blackbox_report,
    confusion_matrices,
    markdown_confusion,
    markdown_table,
    per_target_table,
    transfer_report,
    transfer_table,
)

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
        ValueError: a row lacks a required key, or ``kind`` is unknown.
    """
    if kind not in ("controlled", "blackbox"):
        raise ValueError(f"kind must be 'controlled' or 'blackbox', got {kind!r}")
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


@dataclass(frozen=True)
class BlackBoxResult:
    """One black-box run (:func:`~meshadv.transfer.blackbox.blackbox_classifier` / ``blackbox_detector``).

    Attributes:
        row: the JSON-able result row (outcome, margins / scores, attack settings, estimation errors); the
            columns are described in :data:`~meshadv.transfer.tables.BLACKBOX_OUTCOME_COLUMNS` and the
            neighbouring tuples.
        images: ``(H, W, 3)`` float images in ``[0, 1]``: ``benign_mitsuba`` (the estimation's photo),
            ``adversarial_mitsuba`` (under the hidden parameters), ``adversarial_mitsuba_estimated`` (under the
            estimates) and ``adversarial_meshadv`` (meshadv's render the victim saw).
        adversarial_mesh: the attacked object's adversarial mesh.
        attack_result: the attack's :class:`~meshadv.attacks.AttackResult`.
    """

    row: Mapping[str, Any]
    images: Mapping[str, Any]
    adversarial_mesh: Any
    attack_result: Any

    def to_record(self) -> dict[str, Any]:
        """The row as a JSON-able dict (NaN floats become ``None``)."""
        return {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in self.row.items()}


@dataclass(frozen=True)
class ControlledResult:
    """One (case, view) evaluation of the controlled transfer (:func:`~meshadv.transfer.controlled.evaluate_case`).

    The successes are targeted when the case has a target, else untargeted; they are ``None`` (and ``error`` says
    why) when the Mitsuba render failed. The stored record (:meth:`to_record`) has the same keys as the rows written
    before this type existed, so old and new rows of the ``transfer`` table read alike.

    Attributes:
        case_id: the case (the sweep job id, or any string).
        victim: the victim's name.
        true_class: the class of the benign object.
        target: the target class, ``""`` for an untargeted attack.
        perturbation: ``"shape"`` or ``"texture"``.
        view: index of the view in the case's views.
        success_meshadv: the attack succeeds on meshadv's render of the adversarial mesh.
        success_mitsuba: the attack succeeds on Mitsuba's render.
        untargeted_meshadv: meshadv's top-1 is outside the true class.
        untargeted_mitsuba: Mitsuba's top-1 is outside the true class.
        top1_meshadv: the victim's top-1 class name on meshadv's render.
        top1_mitsuba: the victim's top-1 class name on Mitsuba's render.
        mean_abs_image_difference: mean absolute difference of the two renders (linear values in [0, 1]).
        variant: the Mitsuba variant that rendered the view.
        benign_correct: whether the victim classified the benign render correctly (from the sweep), if known.
        error: why the Mitsuba render failed, ``None`` when it did not.
    """

    case_id: str
    victim: str
    true_class: str
    target: str
    perturbation: str
    view: int
    success_meshadv: Optional[bool]
    success_mitsuba: Optional[bool]
    untargeted_meshadv: Optional[bool] = None
    untargeted_mitsuba: Optional[bool] = None
    top1_meshadv: Optional[str] = None
    top1_mitsuba: Optional[str] = None
    mean_abs_image_difference: Optional[float] = None
    variant: Optional[str] = None
    benign_correct: Optional[bool] = None
    error: Optional[str] = None

    def to_record(self) -> dict[str, Any]:
        """The row as a JSON-able dict (the ``transfer`` table's record); ``error`` only when the render failed."""
        record = {f.name: getattr(self, f.name) for f in fields(self)}
        if record["error"] is None:
            del record["error"]
        return record


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
    """
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


__all__ = [
    "BlackBoxResult",
    "ControlledResult",
    "BLACKBOX_ESTIMATION_COLUMNS",
    "BLACKBOX_MARGIN_COLUMNS",
    "BLACKBOX_OUTCOME_COLUMNS",
    "BLACKBOX_SCORE_COLUMNS",
    "BLACKBOX_SETTINGS_COLUMNS",
    "blackbox_report",
    "confusion_matrices",
    "load_transfer_rows",
    "markdown_confusion",
    "markdown_table",
    "per_target_table",
    "save_transfer_rows",
    "transfer_report",
    "transfer_table",
]
