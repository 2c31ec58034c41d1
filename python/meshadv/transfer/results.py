"""Transfer results: the typed rows of a run (:class:`ControlledResult`, :class:`BlackBoxResult`), their table in the
sweep's SQLite database (:func:`save_transfer_rows`, :func:`load_transfer_rows`) and the transfer tables made from
them as Markdown (Table 3, targeted success per target class, Fig. 5's confusion matrices, the black-box tables:
:func:`transfer_report`).

The rows live in their own table ``transfer`` of the same database file as the sweep's ``jobs`` table (WAL mode, one
transaction per insert), so the report can read both. One row per (case, view) evaluation::

    transfer(id INTEGER PRIMARY KEY, experiment TEXT, kind TEXT, case_id TEXT, victim TEXT, true_class TEXT,
             target TEXT, perturbation TEXT, view INTEGER, success_meshadv INTEGER, success_mitsuba INTEGER,
             record TEXT (JSON), created REAL, UNIQUE(experiment, kind, case_id, view))

``kind`` is ``"controlled"`` or ``"blackbox"``; ``target`` is ``""`` for untargeted attacks. The records are the
typed rows as dicts (their ``to_record()``).
"""

from __future__ import annotations

import contextlib
import json
import math
import sqlite3
import time
from collections import defaultdict
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Optional, Sequence, Union

from meshadv import _validate
from meshadv.util.markdown import markdown_table as _markdown_table

__all__ = [
    "BLACKBOX_ESTIMATION_COLUMNS", "BLACKBOX_MARGIN_COLUMNS", "BLACKBOX_OUTCOME_COLUMNS", "BLACKBOX_SCORE_COLUMNS",
    "BLACKBOX_SETTINGS_COLUMNS", "BlackBoxResult", "ControlledResult", "blackbox_report", "confusion_matrices",
    "load_transfer_rows", "markdown_confusion", "markdown_table", "per_target_table", "save_transfer_rows",
    "transfer_report", "transfer_table",
]


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


def _connect(db_path: Union[str, Path]) -> sqlite3.Connection:
    """A read-write connection (WAL mode) with the ``transfer`` table created."""
    conn = sqlite3.connect(str(db_path), timeout=30.0)
    conn.execute("PRAGMA journal_mode=WAL")
    conn.executescript(_SCHEMA)
    return conn


@contextlib.contextmanager
def _read_only(db_path: Union[str, Path]) -> Iterator[sqlite3.Connection]:
    """A connection that only reads: reports leave a committed database byte-identical.

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
            row = json.loads(record)
            row.update(experiment=exp, kind=knd)
            out.append(row)
        return out


def _rate(values: Sequence[Optional[bool]]) -> Optional[float]:
    """The fraction of true values among those that are not None (None when all are None)."""
    vals = [bool(v) for v in values if v is not None]
    return sum(vals) / len(vals) if vals else None


def transfer_table(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The paper's Table 3: success rates per victim and attack type, untargeted and targeted.

    A targeted row counts for the targeted rate (top-1 in the target group); every row also counts for the untargeted
    rate through ``untargeted_meshadv`` / ``untargeted_mitsuba`` (top-1 not in the true group). Untargeted transfer
    to Mitsuba counts only on views whose benign mesh Mitsuba renders the victim classifies right
    (``benign_correct_mitsuba``, the benign control): a benign object the victim already gets wrong there is no
    transfer. Groups whose rows carry no control at all (older runs) fall back to every row, and say so with
    ``n_benign_mitsuba_checked`` 0.

    Returns:
        One dict per (victim, perturbation): ``n``, ``untargeted_meshadv``, ``untargeted_mitsuba`` (controlled, see
        above), ``targeted_meshadv``, ``targeted_mitsuba`` (rates in [0, 1] or None), ``n_benign_mitsuba_checked``
        (rows with the control) and ``n_benign_mitsuba_correct`` (rows whose benign Mitsuba render is right),
        ``untargeted_mitsuba_uncontrolled`` (the rate over every row, for comparison), ``n_benign_correct`` (rows
        whose benign meshadv render the sweep found right) and ``untargeted_mitsuba_benign_correct`` (the
        controlled rate over those rows only).
    """
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        groups[(row["victim"], row["perturbation"])].append(row)
    table = []
    for (victim, perturbation), items in sorted(groups.items()):
        targeted = [r for r in items if r.get("target")]
        checked = [r for r in items if r.get("benign_correct_mitsuba") is not None]
        counted = [r for r in items if r.get("benign_correct_mitsuba")] if checked else items
        table.append(
            {
                "victim": victim,
                "perturbation": perturbation,
                "n": len(items),
                "untargeted_meshadv": _rate([r.get("untargeted_meshadv") for r in items]),
                "untargeted_mitsuba": _rate([r.get("untargeted_mitsuba") for r in counted]),
                "targeted_meshadv": _rate([r.get("success_meshadv") for r in targeted]),
                "targeted_mitsuba": _rate([r.get("success_mitsuba") for r in targeted]),
                "n_benign_mitsuba_checked": len(checked),
                "n_benign_mitsuba_correct": sum(1 for r in checked if r.get("benign_correct_mitsuba")),
                "untargeted_mitsuba_uncontrolled": _rate([r.get("untargeted_mitsuba") for r in items]),
                "n_benign_correct": sum(1 for r in items if r.get("benign_correct")),
                "untargeted_mitsuba_benign_correct": _rate(
                    [r.get("untargeted_mitsuba") for r in counted if r.get("benign_correct")]
                ),
            }
        )
    return table


def per_target_table(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Targeted transfer success per victim and target class (meshadv vs Mitsuba)."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        if row.get("target"):
            groups[(row["victim"], row["target"])].append(row)
    return [
        {
            "victim": victim,
            "target": target,
            "n": len(items),
            "targeted_meshadv": _rate([r.get("success_meshadv") for r in items]),
            "targeted_mitsuba": _rate([r.get("success_mitsuba") for r in items]),
        }
        for (victim, target), items in sorted(groups.items())
    ]


def confusion_matrices(
    rows: Sequence[dict[str, Any]], classes: Optional[Sequence[str]] = None, *, renderer: str = "mitsuba"
) -> dict[str, tuple[list[str], list[list[Optional[float]]]]]:
    """Targeted confusion matrices (the paper's Fig. 5): rate of success for each (true class, target class).

    Args:
        rows: transfer rows.
        classes: the class order (default: every class seen, sorted).
        renderer: ``"mitsuba"`` or ``"meshadv"`` (which success to count).

    Returns:
        ``{victim: (classes, matrix)}`` with ``matrix[i][j]`` the success rate of attacks on class ``i`` toward
        target ``j`` (None when there is no such attack).

    Raises:
        ValueError: unknown ``renderer``.
    """
    if renderer not in ("mitsuba", "meshadv"):
        raise ValueError(f"renderer must be 'mitsuba' or 'meshadv', got {renderer!r}")
    key = f"success_{renderer}"
    targeted = [r for r in rows if r.get("target")]
    names = list(classes) if classes is not None else sorted({r["true_class"] for r in targeted} |
                                                             {r["target"] for r in targeted})
    out = {}
    for victim in sorted({r["victim"] for r in targeted}):
        cells: dict[tuple[str, str], list[Any]] = defaultdict(list)
        for r in targeted:
            if r["victim"] == victim:
                cells[(r["true_class"], r["target"])].append(r.get(key))
        matrix = [[_rate(cells[(t, g)]) if (t, g) in cells else None for g in names] for t in names]
        out[victim] = (names, matrix)
    return out


def _fmt(value: Any) -> str:
    """A table cell: ``–`` for None, floats with two decimals (two significant digits when tiny)."""
    if value is None:
        return "–"
    if isinstance(value, float):
        if value != 0 and abs(value) < 0.005:
            return f"{value:.2g}"  # a learning rate or a weight such as 1e-05, not 0.00
        return f"{value:.2f}"
    return str(value)


def markdown_table(table: Sequence[dict[str, Any]], columns: Optional[Sequence[str]] = None) -> str:
    """Render a list of dicts as a GitHub-flavoured markdown table."""
    if not table:
        return "(no rows)\n"
    cols = list(columns) if columns is not None else list(table[0].keys())
    return _markdown_table(cols, [[_fmt(row.get(c)) for c in cols] for row in table]) + "\n"


def markdown_confusion(names: Sequence[str], matrix: Sequence[Sequence[Optional[float]]]) -> str:
    """Render a confusion matrix (rows: true class, columns: target class) as markdown."""
    rows = [[name, *(_fmt(v) for v in row)] for name, row in zip(names, matrix)]
    return _markdown_table(["true \\ target", *names], rows) + "\n"


#: Columns of the black-box tables: outcome, classifier margins, detector scores, attack settings, estimation errors.
BLACKBOX_OUTCOME_COLUMNS = ("case_id", "victim", "true_class", "target", "perturbation", "context", "success_meshadv",
                            "robust_rate_meshadv", "success_mitsuba_estimated", "success_mitsuba",
                            "benign_correct_mitsuba", "top1_adversarial_mitsuba")
BLACKBOX_MARGIN_COLUMNS = ("case_id", "margin_meshadv", "margin_mitsuba_estimated", "margin_mitsuba",
                           "margin_benign_mitsuba", "top1_meshadv", "top1_mitsuba_estimated")
BLACKBOX_SCORE_COLUMNS = ("case_id", "hide_score_meshadv", "hide_score_mitsuba_estimated",
                          "hide_score_adversarial_mitsuba", "hide_score_benign_mitsuba", "score_threshold")
BLACKBOX_SETTINGS_COLUMNS = ("case_id", "eot", "required_margin", "pixel_noise", "pixel_noise_on", "antialias",
                             "texture_smoothing", "object_scale", "method", "steps", "steps_run", "steps_to_success",
                             "lr", "lambda_perceptual", "color_rmse", "laplacian_pair_mean", "spp", "attack_time")
BLACKBOX_ESTIMATION_COLUMNS = ("case_id", "azimuth_error", "elevation_error", "distance_error", "mask_iou",
                               "light_fit", "light_fit_pixels", "light_rmse", "direction_error")


def blackbox_report(rows: Sequence[dict[str, Any]]) -> str:
    """The black-box section: outcome, margins (classifiers) or scores (detectors), settings, estimation errors.

    ``success_meshadv`` is meshadv's render of the final mesh on the estimated view, ``robust_rate_meshadv`` the
    fraction of fresh jittered estimated views on which it is adversarial, ``success_mitsuba_estimated`` Mitsuba's
    render under the *estimated* camera and lights (renderer mismatch only), ``success_mitsuba`` Mitsuba under the
    hidden parameters (the pipeline's result). A table is shown when some row has one of its columns, a column when
    some of the table's rows has it; a missing value shows as "–".
    """
    parts = ["\n### Black-box pipeline (estimated camera and lights)\n"]
    classifier = [r for r in rows if "hide_score_adversarial_mitsuba" not in r]
    detector = [r for r in rows if "hide_score_adversarial_mitsuba" in r]
    sections = (("Outcome", BLACKBOX_OUTCOME_COLUMNS, rows),
                ("Classifier margins (logits, > 0 = adversarial) and top-1 classes", BLACKBOX_MARGIN_COLUMNS,
                 classifier),
                ("Detector: best score of the hidden class (detected at >= score_threshold)", BLACKBOX_SCORE_COLUMNS,
                 detector),
                ("Attack settings and distortion", BLACKBOX_SETTINGS_COLUMNS, rows),
                ("Estimation errors (degrees; distance relative)", BLACKBOX_ESTIMATION_COLUMNS, rows))
    for title, cols, subset in sections:
        present = [c for c in cols if any(r.get(c) is not None for r in subset)]
        if len(present) <= 1:
            continue
        parts.append(f"\n#### {title}\n")
        parts.append(markdown_table(subset, present))
    return "\n".join(parts)


def transfer_report(rows: Sequence[dict[str, Any]]) -> str:
    """A markdown section with the transfer tables and confusion matrices of ``rows``."""
    controlled = [r for r in rows if r.get("kind", "controlled") == "controlled"]
    blackbox = [r for r in rows if r.get("kind") == "blackbox"]
    parts = ["## Transfer to Mitsuba 3\n"]
    if controlled:
        parts.append("### Controlled parameters (same camera and lights)\n")
        parts.append(markdown_table(transfer_table(controlled)))
        parts.append("\n#### Targeted success per target class\n")
        parts.append(markdown_table(per_target_table(controlled)))
        for victim, (names, matrix) in confusion_matrices(controlled).items():
            parts.append(f"\n#### Targeted confusion matrix, {victim} (Mitsuba)\n")
            parts.append(markdown_confusion(names, matrix))
    if blackbox:
        parts.append(blackbox_report(blackbox))
    return "\n".join(parts)


@dataclass(frozen=True)
class BlackBoxResult:
    """One black-box run (:func:`~meshadv.transfer.blackbox.blackbox_classifier` / ``blackbox_detector``).

    Attributes:
        row: the JSON-able result row (outcome, margins / scores, attack settings, estimation errors); the
            columns are described in :data:`~meshadv.transfer.results.BLACKBOX_OUTCOME_COLUMNS` and the
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
    why) when the Mitsuba render failed. The stored record (:meth:`to_record`) is flat: these attributes, ``error``
    and the benign control's two only when set.

    Attributes:
        case_id: the case (the sweep job id, or any string).
        victim: the victim's name.
        true_class: the class of the benign object.
        target: the target class, ``""`` for an untargeted attack.
        perturbation: ``"shape"`` or ``"texture"``.
        view: index of the view in the case's views.
        success_meshadv: the attack succeeds on meshadv's render of the adversarial mesh.
        success_mitsuba: the attack succeeds on Mitsuba's render.
        untargeted_meshadv: meshadv's top-1 is outside the true class's group
            (:func:`~meshadv.attacks.criteria.resolve_true_class`).
        untargeted_mitsuba: Mitsuba's top-1 is outside the true class's group.
        top1_meshadv: the victim's top-1 class name on meshadv's render.
        top1_mitsuba: the victim's top-1 class name on Mitsuba's render.
        mean_abs_image_difference: mean absolute difference of the two renders (linear values in [0, 1]).
        variant: the Mitsuba variant that rendered the view.
        benign_correct: whether the victim classified the benign render correctly (from the sweep), if known.
        benign_correct_mitsuba: whether the victim classifies Mitsuba's render of the benign mesh on this view as
            the true class (``None``: the case had no benign mesh); untargeted transfer counts only where it does.
        top1_benign_mitsuba: the victim's top-1 class name on that render.
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
    benign_correct_mitsuba: Optional[bool] = None
    top1_benign_mitsuba: Optional[str] = None
    error: Optional[str] = None

    @property
    def untargeted_counted(self) -> Optional[bool]:
        """The untargeted transfer of this view as the tables count it: ``untargeted_mitsuba`` where the benign
        Mitsuba render is right, ``None`` (not counted) where it is wrong or was not rendered."""
        return self.untargeted_mitsuba if self.benign_correct_mitsuba else None

    def to_record(self) -> dict[str, Any]:
        """The row as a JSON-able dict (the ``transfer`` table's record); ``error`` only when the render failed, the
        benign control's ``benign_correct_mitsuba`` / ``top1_benign_mitsuba`` only when it was rendered."""
        record = {f.name: getattr(self, f.name) for f in fields(self)}
        for optional in ("error", "benign_correct_mitsuba", "top1_benign_mitsuba"):
            if record[optional] is None:
                del record[optional]
        return record
