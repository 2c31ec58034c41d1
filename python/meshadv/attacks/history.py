"""What the attack loop reports per step: the loss-history row kept in the result and the callback's
:class:`StepInfo`.

Both are per target over all ``T`` targets, with ``None`` for targets that are no longer optimised.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Sequence, Tuple

from torch import Tensor

from meshadv.attacks.targets import TargetState

__all__ = ["StepInfo", "history_row", "first_view_top1", "step_info"]


@dataclass(frozen=True)
class StepInfo:
    """Progress of one optimiser step, passed to the ``callback`` of an attack call.

    Attributes:
        round: binary-search round (0-based); ``rounds`` the number of rounds.
        step: step within the round (0-based); ``steps`` the maximum steps per round.
        total_step: steps done over all rounds, this one included.
        lambdas: current ``lambda`` per target.
        loss: total loss per target (``None`` for finished targets).
        distance: current distortion per target (Laplacian for shape, colour RMSE for texture), or ``None``.
        margin: worst-view criterion margin per target, or ``None``.
        top1: top-1 class of the first view per target (classifiers), or ``None``.
        best_distance: least distortion of a success so far per target (``None`` before any success).
        active: number of targets still being optimised.
    """

    round: int
    rounds: int
    step: int
    steps: int
    total_step: int
    lambdas: Tuple[float, ...]
    loss: Tuple[Optional[float], ...]
    distance: Tuple[Optional[float], ...]
    margin: Tuple[Optional[float], ...]
    top1: Tuple[Optional[int], ...]
    best_distance: Tuple[Optional[float], ...]
    active: int


def history_row(round_index: int, step: int, num_targets: int, active: Sequence[int], total: Tensor, adv: Tensor,
                perceptual: Tensor, distance: Tensor, margins: Tensor, lambdas: Tensor) -> Dict[str, Any]:
    """The loss-history row of one step (JSON-able).

    Args:
        round_index: the round; ``step`` the step within it.
        num_targets: ``T``.
        active: the ``K`` targets optimised in the step.
        total, adv, perceptual, distance: ``(K,)`` detached per-target terms (``total = adv + lambda * perceptual``).
        margins: ``(K, V)`` per-view criterion margins (the row keeps the worst view's).
        lambdas: ``(T,)`` the perceptual weights of the round.

    Returns:
        ``{"round", "step", "loss", "adv", "perceptual", "distance", "margin", "lambda"}``; the per-target lists have
        ``T`` entries, ``None`` for targets not in ``active``.
    """
    row: Dict[str, Any] = {"round": round_index, "step": step, "loss": [None] * num_targets,
                           "adv": [None] * num_targets, "perceptual": [None] * num_targets,
                           "distance": [None] * num_targets, "margin": [None] * num_targets,
                           "lambda": lambdas.tolist()}
    for a, t in enumerate(active):
        row["loss"][t] = float(total[a])
        row["adv"][t] = float(adv[a])
        row["perceptual"][t] = float(perceptual[a])
        row["distance"][t] = float(distance[a])
        row["margin"][t] = float(margins[a].min())
    return row


def first_view_top1(top: Optional[Tensor], num_targets: int, active: Sequence[int]) -> List[Optional[int]]:
    """Per target (``T`` entries), the top-1 class of its first view from ``top`` (``(K,)``, one per active target;
    ``None`` for a victim without classes), ``None`` for the others."""
    top1: List[Optional[int]] = [None] * num_targets
    if top is not None:
        for a, t in enumerate(active):
            top1[t] = int(top[a])
    return top1


def step_info(row: Dict[str, Any], top1: Sequence[Optional[int]], *, rounds: int, steps: int, total_step: int,
              targets: Sequence[TargetState]) -> StepInfo:
    """The callback's :class:`StepInfo` of a step from its history row (:func:`history_row`), the first-view top-1
    classes and the targets' state after the step."""
    return StepInfo(
        round=row["round"], rounds=rounds, step=row["step"], steps=steps, total_step=total_step,
        lambdas=tuple(row["lambda"]), loss=tuple(row["loss"]), distance=tuple(row["distance"]),
        margin=tuple(row["margin"]), top1=tuple(top1),
        best_distance=tuple(None if math.isinf(tg.best_distance) else tg.best_distance for tg in targets),
        active=sum(tg.active for tg in targets),
    )
