"""Per-target bookkeeping of the attack loop: the best result so far, the first success and when a target stops.

A step *holds* for a target when at least ``success_fraction`` of its views are adversarial; a step that holds within
the distortion budget and inside the perceptibility cap (when the attack has one) is a *success*. Each target keeps
the parameters of its least distorted success (else those of the step closest to success among the steps inside the
cap: most views adversarial, then the largest mean margin), counts consecutive steps that hold with
``early_stop_margin`` on every view for early stopping, and stops once it leaves the budget (leaving the cap does not
stop it: the update rule may bring it back inside).

Example:
    >>> import torch
    >>> from meshadv.attacks import Misclassification
    >>> rule = StopRule(success_fraction=1.0, max_distortion=None, early_stop=None, early_stop_margin=0.0)
    >>> state = TargetState(Misclassification(1))
    >>> state.observe(torch.ones(2), 0.5, 1.0, torch.tensor([0.3]), 1.0, rule, total_steps=1, elapsed=0.1)
    >>> state.best_distance, state.first_step
    (0.5, 1)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional, Tuple

from torch import Tensor

from meshadv.attacks.criteria import Criterion
from meshadv.attacks.result import enough_views

__all__ = ["StopRule", "TargetState"]


@dataclass(frozen=True)
class StopRule:
    """The attack's thresholds that decide a target's success and its stop.

    Attributes:
        success_fraction: fraction of the views that must be adversarial, in ``(0, 1]``.
        max_distortion: the distortion budget, or ``None``.
        early_stop: consecutive steps a target must hold with ``early_stop_margin`` before it stops, or ``None``.
        early_stop_margin: the margin every view must hold with for early stopping.
        cap: the perceptibility cap (``meshadv.perceptibility.PerceptibilityCap``) steps must be inside to count,
            or ``None``.
    """

    success_fraction: float
    max_distortion: Optional[float]
    early_stop: Optional[int]
    early_stop_margin: float
    cap: Optional[Any] = None


@dataclass
class TargetState:
    """Per-target state of one attack call: its criterion, the best result so far and the current round's flags.

    Attributes:
        criterion: the bound criterion of the target.
        best_params: parameters of the least distorted success so far (``None`` before any).
        best_distance: their distortion (``inf`` before any success).
        best_lambda: the perceptual weight they were found with (``nan`` before any success).
        fallback: without a success, the parameters of the step closest to success among the steps inside the
            perceptibility cap (``None`` before any such step).
        fallback_key: ``(fraction of adversarial views, mean margin)`` of ``fallback``.
        first_step: total step count at the first success (``None`` before it).
        first_time: seconds from the start of the call to the first success (``None`` before it).
        active: whether the target is still optimised in this round.
        hold: consecutive steps it has held with ``early_stop_margin``.
        round_success: whether this round reached a success.
    """

    criterion: Criterion
    best_params: Optional[Tensor] = None
    best_distance: float = math.inf
    best_lambda: float = math.nan
    fallback: Optional[Tensor] = None
    fallback_key: Tuple[float, float] = (-math.inf, -math.inf)
    first_step: Optional[int] = None
    first_time: Optional[float] = None
    active: bool = True
    hold: int = 0
    round_success: bool = False

    def start_round(self) -> None:
        """Every target is optimised again from the pristine mesh."""
        self.active, self.hold, self.round_success = True, 0, False

    def observe(self, params: Tensor, distance: float, fraction: float, margins: Tensor, lam: float, rule: StopRule,
                total_steps: int, elapsed: float, inside_cap: bool = True) -> None:
        """Record one step's parameters (before the update), distortion and per-view margins.

        Args:
            params: the target's parameters that were rendered.
            distance: their distortion.
            fraction: the fraction of the views that were adversarial.
            margins: ``(V,)`` the criterion margins of the views.
            lam: the perceptual weight of the step.
            rule: the attack's success and stop thresholds.
            total_steps: steps done over all rounds, this one included.
            elapsed: seconds since the start of the call.
            inside_cap: whether the step's mesh is inside the attack's perceptibility cap (``True`` without one).
        """
        ok = enough_views(fraction, rule.success_fraction)
        within = rule.max_distortion is None or distance <= rule.max_distortion
        if ok and within and inside_cap:
            self._record_success(params, distance, lam, total_steps, elapsed)
        key = (fraction, float(margins.mean()))
        if self.best_params is None and inside_cap and key > self.fallback_key:
            self.fallback_key = key
            self.fallback = params.detach().clone()
        self.hold = self.hold + 1 if ok and float(margins.min()) >= rule.early_stop_margin else 0
        if rule.early_stop is not None and self.hold >= rule.early_stop:
            self.active = False
        if not within:
            self.active = False

    def _record_success(self, params: Tensor, distance: float, lam: float, total_steps: int, elapsed: float) -> None:
        """A success: note the first one, keep ``params`` when they are the least distorted so far."""
        self.round_success = True
        if self.first_step is None:
            self.first_step, self.first_time = total_steps, elapsed
        if distance < self.best_distance:
            self.best_distance = distance
            self.best_params = params.detach().clone()
            self.best_lambda = lam

    def chosen(self, pristine: Tensor) -> Tensor:
        """The least distorted success, else the step closest to success inside the cap, else ``pristine``."""
        if self.best_params is not None:
            return self.best_params
        return self.fallback if self.fallback is not None else pristine
