"""Judging candidates with the victims: which images each victim gets right, and what it predicted."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Union

import torch

from meshadv.victims.victim import ClassifierVictim, DetectorVictim, Victim
from meshadv.attacks.criteria import Misclassification
from meshadv.victims.labels import PASCAL3D_TO_COCO

__all__ = ["Judge", "resolve_victims"]


@dataclass
class Judge:
    """One victim's verdict on images of a PASCAL3D+ class.

    Attributes:
        victim: a classifier (right when its top-1 ImageNet label is in the class's group:
            :func:`~meshadv.attacks.criteria.resolve_true_class`) or a detector (right when
            it finds the class's COCO label with a score of at least ``threshold``).
        threshold: the detector score threshold.
        imagenet_names: the 1000 ImageNet class names, for a classifier's predictions.
    """

    victim: Victim
    threshold: float
    imagenet_names: tuple[str, ...] = field(default_factory=tuple)

    def __call__(self, images: torch.Tensor, cls: str) -> tuple[list[bool], list[str]]:
        """Whether the victim gets each of ``images`` (``(B, 3, S, S)``) right as class ``cls``, and its prediction
        (an ImageNet name, or ``"<COCO name>:<score>"`` of a detector's best detection) for each.

        Raises:
            ValueError: a victim that is neither a classifier nor a detector.
        """
        with torch.no_grad():
            if isinstance(self.victim, ClassifierVictim):
                logits = self.victim(images)
                wrong = Misclassification(cls).bind(self.victim).is_adversarial(logits).tolist()
                top1 = logits.argmax(dim=1).tolist()
                return [not w for w in wrong], [self.imagenet_names[i] for i in top1]
            if isinstance(self.victim, DetectorVictim):
                label = self.victim.class_index(PASCAL3D_TO_COCO[cls])
                scores = self.victim(images).scores()
                best_score, best_label = scores.max(dim=1).values.max(dim=1)
                own = scores[:, :, label].max(dim=1).values
                passed = [float(s) >= self.threshold for s in own]
                labels = [
                    f"{self.victim.class_names[int(lab)]}:{float(s):.3f}" for s, lab in zip(best_score, best_label)
                ]
                return passed, labels
        raise ValueError(f"victims: unsupported victim kind {self.victim.kind!r}")


def resolve_victims(victims: Sequence[Union[str, Victim]]) -> list[Victim]:
    """Victim objects for ``victims`` (names are loaded with :func:`~meshadv.victims.load_victim`).

    Raises:
        ValueError: ``victims`` is a single name or victim, empty, or names a victim twice.
    """
    from meshadv.victims.registry import load_victim

    if isinstance(victims, (str, Victim)) or not victims:
        raise ValueError("victims must be a non-empty sequence of victim names or Victim objects")
    resolved = [load_victim(v) if isinstance(v, str) else v for v in victims]
    names = [v.name for v in resolved]
    if len(set(names)) != len(names):
        raise ValueError(f"victims must have distinct names, got {names}")
    return resolved
