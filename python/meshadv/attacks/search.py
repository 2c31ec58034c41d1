"""Binary search over the perceptual weight ``lambda`` (one independent search per target).

The objective is ``L_adv + lambda * L_perceptual``: a larger ``lambda`` keeps the mesh closer to the original but
makes the attack harder. After each round (a full Adam run started from the pristine mesh), a target whose round
succeeded raises its ``lambda`` (towards less distortion) and one that failed lowers it:

* success: ``lo = lambda``; ``lambda = (lo + hi) / 2`` if an upper bound ``hi`` is known, else ``lambda * factor``;
* failure: ``hi = lambda``; ``lambda = (lo + hi) / 2`` if a successful ``lo`` is known, else ``lambda / factor``.

This is Carlini & Wagner's constant search with the roles swapped (their constant weights the adversarial term).
The paper runs 5 rounds of up to 1000 Adam steps and keeps the successful result of least distortion; the attack
keeps that result, not the one of the last round.

Example:
    >>> search = LambdaSearch(1.0, num_targets=2)
    >>> search.update([True, False]); search.lambdas.tolist()
    [10.0, 0.10000000149011612]
"""

from __future__ import annotations

import math
from typing import List, Sequence

import torch

from meshadv import _validate

__all__ = ["LambdaSearch"]


class LambdaSearch:
    """Per-target bisection of ``lambda`` between the largest success and the smallest failure seen.

    Args:
        initial: the starting ``lambda`` (>= 0). A start of 0 cannot be scaled: after a success it becomes 1e-3.
        num_targets: number of targets searched in parallel.
        factor: growth / shrink factor used while one of the bounds is unknown (> 1).

    Raises:
        TypeError: ``initial`` or ``factor`` not a real number, ``num_targets`` not an integer.
        ValueError: ``initial`` negative or not finite, ``num_targets < 1`` or ``factor <= 1``.
    """

    def __init__(self, initial: float, num_targets: int = 1, *, factor: float = 10.0) -> None:
        initial = _validate.finite_float("initial", initial, low=0.0)
        num_targets = _validate.positive_int("num_targets", num_targets)
        self.factor = _validate.finite_float("factor", factor, low=1.0, low_open=True)
        self._lam: List[float] = [float(initial)] * num_targets
        self._lo: List[float] = [-1.0] * num_targets  # -1: no success yet
        self._hi: List[float] = [math.inf] * num_targets

    @property
    def lambdas(self) -> torch.Tensor:
        """Current ``lambda`` of every target, float32 ``(T,)``."""
        return torch.tensor(self._lam, dtype=torch.float32)

    @property
    def largest_success(self) -> List[float]:
        """Largest successful ``lambda`` per target (``nan`` when none succeeded yet)."""
        return [lo if lo >= 0 else math.nan for lo in self._lo]

    def update(self, success: Sequence[bool]) -> None:
        """Move every target's ``lambda`` after one round.

        Args:
            success: one flag per target: did the round succeed?

        Raises:
            ValueError: wrong number of flags.
        """
        if len(success) != len(self._lam):
            raise ValueError(f"success must have {len(self._lam)} entries, got {len(success)}")
        for t, ok in enumerate(success):
            lam = self._lam[t]
            if ok:
                self._lo[t] = max(self._lo[t], lam)
                if math.isfinite(self._hi[t]):
                    lam = (self._lo[t] + self._hi[t]) / 2
                else:
                    lam = lam * self.factor if lam > 0 else 1e-3
            else:
                self._hi[t] = min(self._hi[t], lam)
                lam = (self._lo[t] + self._hi[t]) / 2 if self._lo[t] >= 0 else lam / self.factor
            self._lam[t] = lam
