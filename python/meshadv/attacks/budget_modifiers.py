"""The optional step modifiers of the distortion-budget rule (``method="ddn"``, :mod:`meshadv.attacks.budget`).

Each keeps its own per-round state and is built only when its option is on (see the rule's module docstring for
what each does and what it measured): :class:`Momentum` (``momentum``), :class:`StallRestarts` (``stall_steps``,
``stall_factor``) and :class:`AdamReach` (``reach="adam"``). Rows are indexed by target: ``idx`` holds the targets of
the rows of a step's tensors.
"""

from __future__ import annotations

import math
from typing import Any, Tuple

import torch
from torch import Tensor

from meshadv.attacks.norms import per_row, unit_rows

__all__ = ["Momentum", "StallRestarts", "AdamReach", "ADAM_BETAS", "ADAM_EPS"]

#: Adam's moment decays and denominator offset for ``reach="adam"`` (torch's defaults).
ADAM_BETAS = (0.9, 0.999)
ADAM_EPS = 1e-8


class Momentum:
    """MI-FGSM's accumulation of unit step directions: ``v <- beta v + d``, stepped along ``v / ||v||``.

    Args:
        beta: the decay, in ``(0, 1)``.
        like: the perturbation ``(T, ...)`` whose shape and dtype the velocity takes (zero at the start).
    """

    def __init__(self, beta: float, like: Tensor) -> None:
        self.beta = float(beta)
        self.velocity = torch.zeros_like(like)

    def heading(self, idx: Tensor, direction: Tensor, norm: Any) -> Tensor:
        """The unit heading of the targets ``idx`` after adding their unit ``direction`` to their velocity."""
        v = self.beta * self.velocity[idx] + direction.to(self.velocity.dtype)
        self.velocity[idx] = v
        return unit_rows(v, norm.norm(v)).to(direction.dtype)

    def clear(self, targets: Tensor) -> None:
        """Forget the velocity of ``targets`` (restarted targets start again from rest)."""
        self.velocity[targets] = 0


class StallRestarts:
    """Finds the targets whose adversarial loss has not fallen below its lowest value for ``stall_steps`` steps
    without holding, and puts them back at their lowest-loss perturbation.

    Args:
        stall_steps: steps without a new lowest loss that make a stall (``>= 1``).
        start: the round's starting perturbation ``(T, ...)`` (the first lowest-loss point).
    """

    def __init__(self, stall_steps: int, start: Tensor) -> None:
        self.stall_steps = int(stall_steps)
        num_targets = start.shape[0]
        self.best_delta = start.clone()
        self.best_loss = torch.full((num_targets,), math.inf, dtype=torch.float64)
        self.since_best = torch.zeros(num_targets, dtype=torch.long)

    def check(self, idx: Tensor, delta: Tensor, loss: Tensor, held: Tensor) -> Tuple[Tensor, Tensor]:
        """Record the rows' losses ``loss (K,)`` at ``delta (K, ...)`` and whether they ``held (K,)``; return
        ``delta`` with every stalled row put back at its lowest-loss point, and the stalled rows (bool ``(K,)``)."""
        better = loss < self.best_loss[idx]
        self.best_loss[idx] = torch.where(better, loss, self.best_loss[idx])
        rows = idx[better]
        if len(rows):
            self.best_delta[rows] = delta[better].to(self.best_delta.dtype)
        since = torch.where(better | held, torch.zeros_like(self.since_best[idx]), self.since_best[idx] + 1)
        stalled = since >= self.stall_steps
        if bool(stalled.any()):
            delta = delta.clone()
            delta[stalled] = self.best_delta[idx[stalled]].to(delta.dtype)
            since = torch.where(stalled, torch.zeros_like(since), since)
        self.since_best[idx] = since
        return delta, stalled


class AdamReach:
    """Adam's per-coordinate normalised direction ``-m_hat / (sqrt(v_hat) + eps)`` for the targets that have not
    held yet; its moments (float64, on the CPU) advance only while a target is unheld.

    Args:
        like: the perturbation ``(T, ...)`` whose shape the moments take.
    """

    def __init__(self, like: Tensor) -> None:
        self.m = torch.zeros_like(like, dtype=torch.float64)
        self.v = torch.zeros_like(like, dtype=torch.float64)
        self.t = torch.zeros(like.shape[0], dtype=torch.long)

    def heading(self, idx: Tensor, unheld: Tensor, grad: Tensor, heading: Tensor, norm: Any) -> Tensor:
        """``heading`` with the rows ``unheld`` (bool ``(K,)``) replaced by Adam's direction of their gradient
        ``grad`` (projected by ``norm``), made unit in ``norm``."""
        if not bool(unheld.any()):
            return heading
        rows = idx[unheld]
        g = norm.project(grad[unheld]).to(torch.float64).cpu()
        b1, b2 = ADAM_BETAS
        m = b1 * self.m[rows] + (1 - b1) * g
        v = b2 * self.v[rows] + (1 - b2) * g * g
        self.m[rows], self.v[rows] = m, v
        self.t[rows] += 1
        t = per_row(self.t[rows].double(), g)
        d = -(m / (1 - b1 ** t)) / ((v / (1 - b2 ** t)).sqrt() + ADAM_EPS)
        d = norm.project(d)
        d = unit_rows(d, norm.norm(d)).to(heading.dtype).to(heading.device)
        heading = heading.clone()
        heading[unheld] = d
        return heading
