"""How the transfer pipelines read a victim: the classifier criteria of a case, Mitsuba images as one batch, top-1
class names, a class's best detection score. Shared by the controlled and the black-box transfer.
"""

from __future__ import annotations

from typing import Any, Optional, Sequence

import numpy as np
import torch

from meshadv.attacks import Misclassification, TargetedMisclassification
from meshadv.transfer.mitsuba_process import MitsubaImage

__all__ = ["class_names", "classifier_criteria", "detection_scores", "images_tensor", "top1_names"]


def classifier_criteria(victim: Any, true_class: str, target: Optional[str]) -> tuple[Any, Optional[Any]]:
    """The untargeted criterion of ``true_class`` and, when ``target`` is given, the targeted one, bound to
    ``victim`` (a classifier). The untargeted one holds where the top-1 leaves ``true_class``'s class group
    (:func:`~meshadv.attacks.criteria.resolve_true_class`: ``"airliner"`` and ``"aeroplane"`` alike are the
    airliner and the warplane), the one definition of "is this render its class" behind every untargeted and
    benign-control verdict of the transfer.

    Raises:
        ValueError: ``victim`` is not a classifier, or a class it does not know.
    """
    untargeted = Misclassification(true_class).bind(victim)
    targeted = TargetedMisclassification(target).bind(victim) if target else None
    return untargeted, targeted


def images_tensor(images: Sequence[MitsubaImage]) -> torch.Tensor:
    """Mitsuba renders as one float32 victim batch ``(N, 3, H, W)``."""
    return torch.from_numpy(np.stack([im.chw() for im in images])).float()


def class_names(victim: Any, indices: Sequence[int]) -> list[str]:
    """The victim's names of class ``indices`` (``str(index)`` where the victim has no name for it)."""
    names = list(getattr(victim, "class_names", []) or [])
    return [names[i] if i < len(names) else str(i) for i in indices]


def top1_names(victim: Any, logits: torch.Tensor) -> list[str]:
    """The name of the top-1 class of every row of ``logits`` ``(N, C)``."""
    return class_names(victim, logits.argmax(dim=1).tolist())


def detection_scores(victim: Any, images: torch.Tensor, class_name: str) -> list[float]:
    """Best score of ``class_name`` among a detector's outputs, per image (0 when absent).

    Args:
        victim: a detector victim.
        images: ``(N, 3, H, W)`` images in ``[0, 1]``.
        class_name: a name of ``victim.class_names``.

    Returns:
        ``N`` scores.

    Raises:
        ValueError: ``class_name`` is not one of the victim's classes.
    """
    k = victim.class_index(class_name)
    with torch.no_grad():
        out = victim(images)
        scores = out.scores()
    return [float(v) for v in scores[..., k].amax(dim=-1).tolist()]
