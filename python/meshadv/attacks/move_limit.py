"""Keeping a vertex flow inside a largest-move limit: the projection the attack loop applies after every update.

A perceptibility cap with a ``max_displacement`` ceiling (:class:`meshadv.perceptibility.PerceptibilityCap`) bounds
the largest vertex move; the attack loop (:mod:`meshadv.attacks.loop`) turns that ceiling into a radius (the
ceiling times the pristine bounding-box diagonal) and, after each update of ddn and Adam alike, pulls the flow back
inside it, so that the optimiser spends its steps on meshes the cap admits instead of outside it.

* :func:`shorten_moves` is the Euclidean projection onto ``{dv : |dv_i| <= r for every vertex i}``: every vertex
  that moved farther than ``r`` is pulled back along its move to distance ``r``; the others keep theirs.
* :func:`scale_factors` gives the uniform scale of each flow that brings its largest move to ``r`` (for a flow that
  is a linear image of the parameters, such as a smoothed flow ``S^k p``, where single vertices cannot be shortened).

Both leave a flow already inside the radius as it is.

Example:
    >>> import torch
    >>> dv = torch.tensor([[[3.0, 4.0, 0.0], [0.1, 0.0, 0.0]]])   # one target, moves of 5 and 0.1
    >>> [[round(x, 3) for x in row] for row in shorten_moves(dv, 1.0)[0].tolist()]
    [[0.6, 0.8, 0.0], [0.1, 0.0, 0.0]]
    >>> [round(float(x), 3) for x in scale_factors(dv, 1.0)]
    [0.2]
"""

from __future__ import annotations

import torch
from torch import Tensor

from meshadv import _validate

__all__ = ["shorten_moves", "scale_factors", "move_lengths"]

#: Lengths below this count as zero (a zero move has no direction).
_TINY = 1e-30


def _check(flow: Tensor, radius: float) -> float:
    if not isinstance(flow, Tensor) or flow.dim() < 2 or flow.shape[-1] != 3:
        shape = tuple(flow.shape) if isinstance(flow, Tensor) else type(flow).__name__
        raise ValueError(f"flow must be a tensor of shape (..., N, 3), got {shape}")
    return _validate.positive_float("radius", radius)


def move_lengths(flow: Tensor) -> Tensor:
    """The length of every vertex's move, ``(..., N)`` of a flow ``(..., N, 3)``."""
    return flow.norm(dim=-1)


def shorten_moves(flow: Tensor, radius: float) -> Tensor:
    """``flow`` with every vertex move longer than ``radius`` pulled back along itself to length ``radius``.

    Args:
        flow: ``(..., N, 3)`` per-vertex moves.
        radius: the largest move allowed, ``> 0`` (units of the flow).

    Returns:
        A tensor like ``flow`` (a new one; ``flow`` is not changed).

    Raises:
        ValueError: a ``flow`` that is not ``(..., N, 3)`` or a ``radius`` that is not a finite number ``> 0``.
    """
    radius = _check(flow, radius)
    length = move_lengths(flow)
    factor = torch.where(length > radius, radius / length.clamp(min=_TINY), torch.ones_like(length))
    return flow * factor.unsqueeze(-1)


def scale_factors(flow: Tensor, radius: float) -> Tensor:
    """Per row of ``flow (K, N, 3)``, ``min(1, radius / its largest move)``, ``(K,)``: the uniform scale that brings
    the row inside ``radius``.

    Raises:
        ValueError: a ``flow`` that is not ``(K, N, 3)`` or a ``radius`` that is not a finite number ``> 0``.
    """
    radius = _check(flow, radius)
    if flow.dim() != 3:
        raise ValueError(f"flow must have shape (K, N, 3), got {tuple(flow.shape)}")
    peak = move_lengths(flow).amax(dim=1) if flow.shape[1] else flow.new_zeros(flow.shape[0])
    return torch.where(peak > radius, radius / peak.clamp(min=_TINY), torch.ones_like(peak))
