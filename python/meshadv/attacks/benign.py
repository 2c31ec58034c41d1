"""The benign mesh checked before an attack: is it its own class on every view, and does a target already hold?

An attack on an object the victim already gets wrong proves nothing for an untargeted attack, and a target that holds
on the benign mesh is no attack at all. :func:`check_benign` renders the pristine mesh on the attack's views and
reports both, for the command line to warn, refuse or skip (``meshadv attack``).

Example:
    >>> check = check_benign(mesh, views, victim, [TargetedMisclassification("sofa")], source="chair")  # doctest: +SKIP
    >>> check.wrong_views, check.already_held                                                          # doctest: +SKIP
    ([3], [False])
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, List, Optional, Sequence, Tuple

from meshadv.attacks.criteria import Criterion, Misclassification
from meshadv.attacks.evaluation import evaluate
from meshadv.attacks.result import enough_views
from meshadv.render.setup import RenderSetup

__all__ = ["BenignCheck", "check_benign", "source_class_of_path"]


@dataclass(frozen=True)
class BenignCheck:
    """The pristine mesh under the victim on the attack's views.

    Attributes:
        source: the class the benign mesh should be, or ``None`` when unknown (then nothing is checked for it).
        top1: per view, the victim's top-1 class name on the benign render (empty for detectors).
        source_correct: per view, the benign render is ``source``: its top-1 is in ``source``'s class group
            (:func:`~meshadv.attacks.criteria.resolve_true_class`; classifiers with a known source), else ``None``.
        adversarial: per criterion, per view: the criterion already holds on the benign render.
        success_fraction: the attack's fraction of views that must hold.
    """

    source: Optional[str]
    top1: Tuple[str, ...]
    source_correct: Optional[Tuple[bool, ...]]
    adversarial: Tuple[Tuple[bool, ...], ...]
    success_fraction: float = 1.0
    #: the PASCAL3D+ class group ``source`` stands for (``"aeroplane"`` for ``"airliner"``), ``None`` when it
    #: stands for itself alone or is unknown.
    source_group: Optional[str] = None

    @property
    def wrong_views(self) -> List[int]:
        """The views whose benign render is not ``source`` (empty when unknown)."""
        return [] if self.source_correct is None else [v for v, ok in enumerate(self.source_correct) if not ok]

    @property
    def already_held(self) -> List[bool]:
        """Per criterion: it holds on at least ``success_fraction`` of the benign views (the attack has nothing to
        do for it)."""
        return [bool(enough_views(sum(row) / len(row), self.success_fraction)) for row in self.adversarial]

    def describe_source(self) -> str:
        """``source``, with the class group it stands for when that has another name (``"airliner (or any class
        of its group aeroplane)"``)."""
        if self.source_group is None or self.source_group == str(self.source).strip().lower():
            return str(self.source)
        return f"{self.source} (or any class of its group {self.source_group})"

    def describe_wrong(self) -> str:
        """``"views 1, 3 (top-1: studio couch, folding chair)"`` for the views whose benign render is not the
        source class."""
        views = self.wrong_views
        names = ", ".join(self.top1[v] for v in views) if self.top1 else ""
        return f"view{'s' if len(views) > 1 else ''} {', '.join(map(str, views))}" + (
            f" (top-1: {names})" if names else "")


def source_class_of_path(path: Any, classes: Sequence[str]) -> Optional[str]:
    """The class named by the folder of a mesh file (``.../pascal3d/chair/01.ply`` -> ``"chair"``) when it is one of
    ``classes``, else ``None``."""
    if path is None:
        return None
    from pathlib import Path

    parent = Path(path).parent.name.lower()
    return parent if parent in {c.lower() for c in classes} else None


def check_benign(mesh: Any, views: Any, victim: Any, criteria: Sequence[Criterion], *, source: Optional[str] = None,
                 setup: Optional[RenderSetup] = None, success_fraction: float = 1.0) -> BenignCheck:
    """Render the pristine ``mesh`` on ``views`` and score it for the victim's source class and for ``criteria``.

    Args:
        mesh: the pristine mesh.
        views: the attack's ``ViewSet``.
        victim: the victim.
        criteria: the attack's criteria.
        source: the class the mesh should be (a classifier victim's class spec, e.g. a PASCAL3D+ name), or ``None``;
            a view is right when its top-1 is in the class group of ``source``
            (:func:`~meshadv.attacks.criteria.resolve_true_class`: one ImageNet class of a PASCAL3D+ group stands for
            the whole group, a class of no group for itself alone).
        setup: the attack's render setup.
        success_fraction: the attack's fraction of views that must hold.

    Returns:
        A :class:`BenignCheck`.

    Raises:
        ValueError: a ``source`` or criterion the victim does not know.
    """
    classifier = getattr(victim, "kind", "classifier") == "classifier"
    checks = list(criteria)
    group = None
    if classifier and source is not None:
        from meshadv.victims.labels import PASCAL3D_TO_IMAGENET

        true = Misclassification(source).bind(victim)
        checks, group = [true, *checks], (true.name if true.name in PASCAL3D_TO_IMAGENET else None)
    scored = evaluate(mesh, views, victim, checks, setup=setup)
    rows = [tuple(bool(x) for x in row) for row in (scored.margins > 0).tolist()]
    names = tuple(getattr(victim, "class_names", ()) or ())
    top1: Tuple[str, ...] = ()
    if scored.top1 is not None:
        top1 = tuple(names[i] if i < len(names) else str(i) for i in scored.top1[0].tolist())
    correct = None
    if classifier and source is not None:
        correct = tuple(not x for x in rows[0])
        rows = rows[1:]
    return BenignCheck(source if classifier else None, top1, correct, tuple(rows), success_fraction, group)
