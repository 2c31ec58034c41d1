"""Transfer results: the typed rows of a run (:class:`ControlledResult`, :class:`BlackBoxResult`).

Their table in the sweep's SQLite database is in :mod:`meshadv.transfer.database` (:func:`save_transfer_rows`,
:func:`load_transfer_rows`), the paper's tables made from them in :mod:`meshadv.transfer.tables`; both are
re-exported here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Mapping, Optional

from meshadv.transfer.database import load_transfer_rows, save_transfer_rows
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
