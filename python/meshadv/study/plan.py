"""The participant plan: which images each participant sees, in which order, with the answers in which order.

Balanced, seeded assignment: the study images (adversarial renders and controls) are put in a seeded random order
``π``; the sequence ``π`` repeated ``per_image`` times is cut into consecutive blocks of near-equal length, at most
``max_trials - attention_checks`` and at most the number of images, one block per participant. Every image then gets
exactly ``per_image`` answers and no participant sees an image twice (a block shorter than ``len(π)`` cannot hold two
copies of one image). Each participant's trials are shuffled, the attention checks inserted at random places, and the
two answers of each trial put in a random order with the true class first in half of the trials (so both orders
occur for every participant with two trials or more).

Example:
    >>> plan = make_plan(["a", "b", "c"], per_image=2, max_trials=2, seed=0)
    >>> len(plan.participants), sorted(sum((p.image_ids() for p in plan.participants), []))
    (3, ['a', 'a', 'b', 'b', 'c', 'c'])
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field
from typing import Any, Dict, List, Sequence

__all__ = ["Trial", "ParticipantPlan", "StudyPlan", "make_plan"]


@dataclass(frozen=True)
class Trial:
    """One trial: an image and its two answers, left and right.

    Attributes:
        image_id: the stimulus.
        true_first: ``True`` when the true class is the left answer.
    """

    image_id: str
    true_first: bool


@dataclass(frozen=True)
class ParticipantPlan:
    """The trials of one participant, in order.

    Attributes:
        participant: index in the plan (``?participant=N`` in the page's URL).
        trials: the trials, attention checks included.
    """

    participant: int
    trials: List[Trial]

    def image_ids(self, include_attention: bool = False) -> List[str]:
        """The image ids of the trials (attention checks only when ``include_attention``)."""
        return [t.image_id for t in self.trials if include_attention or not t.image_id.startswith("attention_")]


@dataclass(frozen=True)
class StudyPlan:
    """Every participant's trials and the settings that made them.

    Attributes:
        participants: one :class:`ParticipantPlan` per participant.
        per_image: answers each study image gets.
        max_trials: most trials per participant (attention checks included).
        seed: the seed.
        settings: further settings recorded with the plan.
    """

    participants: List[ParticipantPlan]
    per_image: int
    max_trials: int
    seed: int
    settings: Dict[str, Any] = field(default_factory=dict)

    def to_record(self) -> Dict[str, Any]:
        """The plan as JSON-able data (the page reads this)."""
        return {
            "per_image": self.per_image,
            "max_trials": self.max_trials,
            "seed": self.seed,
            "settings": dict(self.settings),
            "participants": [
                {"participant": p.participant,
                 "trials": [{"image_id": t.image_id, "true_first": t.true_first} for t in p.trials]}
                for p in self.participants
            ],
        }


def _block_sizes(total: int, cap: int) -> List[int]:
    """``total`` split into the fewest blocks of at most ``cap``, sizes differing by at most one."""
    count = math.ceil(total / cap)
    base, extra = divmod(total, count)
    return [base + (1 if i < extra else 0) for i in range(count)]


def make_plan(image_ids: Sequence[str], *, per_image: int = 5, max_trials: int = 50,
              attention_ids: Sequence[str] = (), seed: int = 0) -> StudyPlan:
    """Assign images to participants (see the module docstring).

    Args:
        image_ids: the study images (adversarial and controls), unique.
        per_image: answers per image (>= 1).
        max_trials: most trials per participant, attention checks included (> ``len(attention_ids)``).
        attention_ids: attention-check images; every participant sees each of them once.
        seed: seed of every random choice.

    Returns:
        The plan.

    Raises:
        ValueError: no images, duplicate ids, ``per_image < 1`` or ``max_trials`` too small for the attention checks.
    """
    ids = list(image_ids)
    checks = list(attention_ids)
    if not ids:
        raise ValueError("image_ids must not be empty")
    if len(set(ids)) != len(ids) or len(set(checks)) != len(checks) or set(ids) & set(checks):
        raise ValueError("image_ids and attention_ids must be unique")
    if per_image < 1:
        raise ValueError(f"per_image must be >= 1, got {per_image}")
    if max_trials <= len(checks):
        raise ValueError(f"max_trials must be > the number of attention checks ({len(checks)}), got {max_trials}")
    rng = random.Random(seed)
    order = ids[:]
    rng.shuffle(order)
    sequence = order * per_image
    cap = min(max_trials - len(checks), len(order))
    participants: List[ParticipantPlan] = []
    start = 0
    for index, size in enumerate(_block_sizes(len(sequence), cap)):
        block = sequence[start:start + size]
        start += size
        rng.shuffle(block)
        for check in checks:
            block.insert(rng.randint(0, len(block)), check)
        firsts = [i < (len(block) + rng.randint(0, 1)) // 2 for i in range(len(block))]
        rng.shuffle(firsts)
        participants.append(ParticipantPlan(index, [Trial(i, f) for i, f in zip(block, firsts)]))
    return StudyPlan(participants, per_image, max_trials, seed)
