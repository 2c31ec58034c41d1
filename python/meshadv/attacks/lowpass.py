"""A low-pass gradient preconditioner: the identity forward, neighbour-smoothed gradients backward.

:func:`lowpass_gradient` leaves its input unchanged and replaces the gradient that flows back through it by ``k``
rounds of neighbour averaging over a graph (:func:`meshadv.attacks.flow.smooth_flow`, ``S g = g + 0.5 L g``): any
update rule that steps along the gradient (Adam, ``method="ddn"``) then moves smooth patches of neighbouring
elements together instead of single ones. :class:`~meshadv.attacks.TextureAttack`'s ``gradient_smoothing`` uses it on
the face colours with the faces that share an edge as neighbours, so a texture change is a smooth colour field over
the surface rather than the shading of single facets. The objective itself is unchanged; only the direction the
optimiser follows is (a preconditioner, as ``method="ddn"``'s ``smoothness`` is for the shape flow).

Example:
    >>> import torch
    >>> x = torch.zeros(3, 1, requires_grad=True)
    >>> edges = torch.tensor([[0, 1], [1, 2]])
    >>> (lowpass_gradient(x, edges, 1) * torch.tensor([[1.0], [0.0], [0.0]])).sum().backward()
    >>> x.grad.flatten().tolist()
    [0.5, 0.25, 0.0]
"""

from __future__ import annotations

from typing import Any, Optional, Tuple

import torch
from torch import Tensor

from meshadv.attacks.flow import smooth_flow

__all__ = ["lowpass_gradient"]


class _LowPassGradient(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, x: Tensor, edges: Tensor, rounds: int) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(edges)
        ctx.rounds = rounds
        return x.view_as(x)

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> Tuple[Optional[Tensor], None, None]:  # type: ignore[override]
        (edges,) = ctx.saved_tensors
        return smooth_flow(grad, edges, ctx.rounds), None, None


def lowpass_gradient(x: Tensor, edges: Tensor, rounds: int) -> Tensor:
    """``x`` itself forward; backward, the gradient smoothed by ``rounds`` rounds of neighbour averaging over
    ``edges`` (``rounds = 0``: ``x`` returned as is).

    Args:
        x: float ``(N, C)`` or ``(B, N, C)``.
        edges: int ``(E, 2)`` undirected pairs of neighbouring elements of ``x``'s ``N`` axis.
        rounds: rounds of averaging, ``>= 0``.

    Raises:
        ValueError: what :func:`~meshadv.attacks.flow.smooth_flow` rejects (shapes, indices, negative rounds).
    """
    smooth_flow(x.detach(), edges, 0)  # validates the shapes and indices
    if isinstance(rounds, bool) or int(rounds) != rounds or rounds < 0:
        raise ValueError(f"rounds must be an integer >= 0, got {rounds!r}")
    if rounds == 0:
        return x
    return _LowPassGradient.apply(x, edges.long(), int(rounds))
