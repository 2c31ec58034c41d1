"""Victim outputs as the attacks handle them: a classifier's logits tensor or a detector's ``DetectorOutput``.

Both have one row per image (mesh-major: image ``k * V + v`` is mesh ``k`` from view ``v``). The attack code cuts
them into per-target rows; these helpers are the one place that knows a ``DetectorOutput``'s fields.

Example:
    >>> import torch
    >>> slice_output(torch.arange(6.0).view(3, 2), 1, 3).tolist()
    [[2.0, 3.0], [4.0, 5.0]]
"""

from __future__ import annotations

from typing import Any, List, Optional, Sequence

from torch import Tensor

__all__ = ["output_tensors", "rebuild_output", "slice_output"]


def output_tensors(output: Any) -> List[Optional[Tensor]]:
    """A victim output's tensors, one row per image: ``[logits]`` or a ``DetectorOutput``'s
    ``[boxes, objectness, class_probs]`` (``objectness`` may be ``None``).

    Raises:
        TypeError: neither a tensor nor a ``DetectorOutput``-like object.
    """
    if isinstance(output, Tensor):
        return [output]
    if all(hasattr(output, name) for name in ("boxes", "objectness", "class_probs")):
        return [output.boxes, output.objectness, output.class_probs]
    raise TypeError(f"victim output must be a Tensor or a DetectorOutput, got {type(output).__name__}")


def rebuild_output(like: Any, tensors: Sequence[Optional[Tensor]]) -> Any:
    """The output of the type of ``like`` holding ``tensors`` (inverse of :func:`output_tensors`)."""
    if isinstance(like, Tensor):
        return tensors[0]
    return type(like)(boxes=tensors[0], objectness=tensors[1], class_probs=tensors[2])


def slice_output(output: Any, start: int, stop: int) -> Any:
    """Rows ``start:stop`` of a victim output (logits tensor or ``DetectorOutput``).

    Raises:
        TypeError: neither a tensor nor a ``DetectorOutput``-like object.
    """
    return rebuild_output(output, [None if t is None else t[start:stop] for t in output_tensors(output)])
