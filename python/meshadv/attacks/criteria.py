"""Attack criteria: what counts as adversarial, and the loss that drives an attack towards it.

Criteria are small immutable objects in the manner of foolbox 3. A criterion is written in user terms (class names,
ImageNet indices, PASCAL3D+ group names) and :meth:`Criterion.bind` resolves it against a victim. A bound criterion
gives, for a batch of victim outputs:

* :meth:`Criterion.loss` -- the adversarial loss per image (lower = more adversarial);
* :meth:`Criterion.margin` -- a per-image margin, positive exactly when the image is adversarial;
* :meth:`Criterion.score` -- the number reported as the "final score" (target probability, true-class probability
  or the best detection score of the hidden class).

Classes can be given as an ImageNet index (``340``), an ImageNet class name (``"zebra"``; any comma-separated synonym
of the name also matches), a PASCAL3D+ class (``"boat"`` -> every ImageNet index of the group) or a list of indices
(a custom group). A group counts as predicted when the top-1 class is one of its members.

A *true* class (the class a render should be: :class:`Misclassification`, the benign checks, untargeted transfer)
is resolved by :func:`resolve_true_class`, the one definition of "is this render its class": one ImageNet class of a
PASCAL3D+ group stands for the whole group (``"airliner"`` -> airliner and warplane), so a render whose top-1 moves
inside the group is still its class. A target stays the class it names.

Example:
    >>> crit = TargetedMisclassification("bicycle").bind(victim)    # doctest: +SKIP
    >>> crit.margin(victim(images)) > 0          # adversarial?        # doctest: +SKIP
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from typing import Any, Callable, ClassVar, Dict, List, Optional, Sequence, Tuple, Union

import torch
from torch import Tensor

from meshadv import _validate
from meshadv.attacks import losses

__all__ = [
    "ClassSpec",
    "Criterion",
    "TargetedMisclassification",
    "Misclassification",
    "Disappearance",
    "WithMargin",
    "resolve_imagenet_classes",
    "resolve_true_class",
    "as_criteria",
]

#: A class given by index, by name (ImageNet or PASCAL3D+ group), or as a group of indices.
ClassSpec = Union[int, str, Sequence[int]]

CLASSIFIER_LOSSES = ("ce", "cw")


def resolve_imagenet_classes(spec: ClassSpec, name: str = "class") -> Tuple[Tuple[int, ...], str]:
    """Resolve a class spec to ImageNet indices and a display label.

    Args:
        spec: an index, a digit string, an ImageNet class name or synonym (case-insensitive), a PASCAL3D+ class
            name (a group) or a sequence of indices.
        name: argument name used in error messages.

    Returns:
        ``(indices, label)``.

    Raises:
        ValueError: unknown name or index out of ``[0, 1000)``.
    """
    from meshadv.victims.labels import imagenet_class_names

    names = imagenet_class_names()
    if isinstance(spec, str):
        text = spec.strip()
        if not text.lstrip("-").isdigit():
            return _resolve_class_name(text, spec, name, names)
        spec = int(text)
    if isinstance(spec, (int,)) and not isinstance(spec, bool):
        idx: Tuple[int, ...] = (int(spec),)
    else:
        try:
            idx = tuple(int(i) for i in spec)  # type: ignore[union-attr]
        except TypeError:
            raise ValueError(f"{name} must be an int, a str or a sequence of ints, got {spec!r}") from None
    if not idx or min(idx) < 0 or max(idx) >= len(names):
        raise ValueError(f"{name} indices must be in [0, {len(names)}), got {list(idx)}")
    label = names[idx[0]] if len(idx) == 1 else "group(" + ",".join(str(i) for i in idx) + ")"
    return idx, label


def resolve_true_class(spec: ClassSpec, name: str = "true_class") -> Tuple[Tuple[int, ...], str]:
    """The ImageNet classes a render of true class ``spec`` counts as: the one definition of "is this render its
    class", behind every untargeted-success, benign-correct and misclassified verdict.

    * a PASCAL3D+ class name -> its group (:data:`~meshadv.victims.labels.PASCAL3D_TO_IMAGENET`), label the name;
    * one ImageNet class (index, digit string, name or synonym) that belongs to a PASCAL3D+ group -> that whole
      group, label the PASCAL3D+ name (``"airliner"``, ``895`` -> ``((404, 895), "aeroplane")``);
    * one ImageNet class of no group -> that class alone (the fallback: nothing else counts as it);
    * a sequence of indices -> exactly those (a custom group; ``[404]`` is the airliner alone).

    Args:
        spec: the true class, see :data:`ClassSpec`.
        name: argument name used in error messages.

    Returns:
        ``(indices, label)``.

    Raises:
        ValueError: unknown name or index out of ``[0, 1000)``.

    Example:
        >>> resolve_true_class("warplane")
        ((404, 895), 'aeroplane')
        >>> resolve_true_class("zebra")
        ((340,), 'zebra')
    """
    from meshadv.victims.labels import PASCAL3D_TO_IMAGENET, pascal_class_of

    idx, label = resolve_imagenet_classes(spec, name)
    single = isinstance(spec, (int, str)) and not isinstance(spec, bool)
    group = pascal_class_of(idx[0]) if single and len(idx) == 1 else None
    if group is None:
        return idx, label
    return tuple(PASCAL3D_TO_IMAGENET[group]), group


def as_criteria(criterion: Any) -> List["Criterion"]:
    """``criterion`` as a non-empty list: one :class:`Criterion`, or a sequence of them (one per target).

    Raises:
        ValueError: not a criterion nor a non-empty sequence of criteria (the message names ``criterion``).
    """
    if isinstance(criterion, Criterion):
        return [criterion]
    try:
        criteria = list(criterion)
    except TypeError:
        criteria = []
    if not criteria or not all(isinstance(c, Criterion) for c in criteria):
        raise ValueError("criterion must be a Criterion or a non-empty sequence of Criterion objects")
    return criteria


def _resolve_class_name(text: str, spec: str, name: str, names: Sequence[str]) -> Tuple[Tuple[int, ...], str]:
    """Indices and label of a class given by name (``text``, stripped ``spec``): a PASCAL3D+ class (a group), an
    ImageNet class's full name, else one of its comma-separated synonyms (case-insensitive).

    Raises:
        ValueError: no such class (naming ``name``, with the closest name when there is one).
    """
    from meshadv.victims.labels import PASCAL3D_TO_IMAGENET

    low = text.lower()
    if low in PASCAL3D_TO_IMAGENET:
        return tuple(PASCAL3D_TO_IMAGENET[low]), low
    for i, full in enumerate(names):
        if full.lower() == low:
            return (i,), full
    for i, full in enumerate(names):
        if low in (s.strip().lower() for s in full.split(",")):
            return (i,), full
    close = _validate.suggest(low, [*PASCAL3D_TO_IMAGENET, *(n.lower() for n in names)])
    raise ValueError(f"{name} {spec!r} is neither an ImageNet class name, a PASCAL3D+ class "
                     f"({', '.join(PASCAL3D_TO_IMAGENET)}) nor an index"
                     + (f"; did you mean {close!r}?" if close else ""))


class Criterion(ABC):
    """Base class of criteria. Subclasses are frozen dataclasses; :meth:`bind` returns a resolved copy.

    Attributes:
        victim_kind: the victim kind the criterion applies to (``"classifier"`` or ``"detector"``).
    """

    victim_kind: ClassVar[str] = ""

    def check_victim(self, victim: Any) -> None:
        """Raise ``ValueError`` naming ``victim`` when its kind does not suit this criterion."""
        kind = getattr(victim, "kind", None)
        if kind is None:
            raise ValueError(f"victim must be a meshadv victim (meshadv.victims.load_victim(...), or your own model in "
                             f"a ClassifierVictim / DetectorVictim subclass), got {type(victim).__name__}")
        if kind != self.victim_kind:
            raise ValueError(f"victim of kind {kind!r} cannot be attacked with {type(self).__name__}, "
                             f"which needs a {self.victim_kind}")

    @abstractmethod
    def bind(self, victim: Any) -> "Criterion":
        """Resolve class names against ``victim`` and return a bound copy.

        Raises:
            ValueError: wrong victim kind or unknown class.
        """

    @abstractmethod
    def loss(self, output: Any, *, loss: str = "ce", kappa: float = 0.0) -> Tensor:
        """Adversarial loss per image ``(B,)``, lower = more adversarial."""

    @abstractmethod
    def margin(self, output: Any) -> Tensor:
        """Per-image margin ``(B,)``: positive exactly when the image is adversarial."""

    @abstractmethod
    def score(self, output: Any) -> Tensor:
        """The reported per-image score ``(B,)``."""

    def is_adversarial(self, output: Any) -> Tensor:
        """Boolean ``(B,)``: ``margin(output) > 0``."""
        return self.margin(output) > 0

    @property
    @abstractmethod
    def label(self) -> str:
        """A short human-readable description, e.g. ``"target=bicycle"``."""

    def to_record(self) -> Dict[str, Any]:
        """JSON-able description."""
        return {"criterion": type(self).__name__, "label": self.label}


def _check_loss_name(loss: str) -> None:
    if loss not in CLASSIFIER_LOSSES:
        raise ValueError(f"loss must be one of {CLASSIFIER_LOSSES}, got {loss!r}")


def _top1_margin(logits: Tensor, classes: Tuple[int, ...]) -> Tensor:
    """Best member logit minus best non-member logit (positive when the top-1 is in ``classes``)."""
    idx = torch.as_tensor(classes, dtype=torch.long, device=logits.device)
    return logits[:, idx].max(dim=1).values - losses.best_other_logit(logits, idx)


def _require_bound(indices: Tuple[int, ...]) -> Tuple[int, ...]:
    """The resolved class indices of a classifier criterion; ``ValueError`` when ``bind`` was not called."""
    if not indices:
        raise ValueError("criterion is not bound: call criterion.bind(victim) first")
    return indices


class _ClassCriterion(Criterion):
    """What the two classifier criteria share: a class spec (field ``spec_field``) resolved by :meth:`bind` to
    ImageNet indices (``indices``) and a label (``name``), a cross-entropy or C&W loss towards or away from them, and
    the class (group) probability as the score. Subclasses are frozen dataclasses with the fields
    ``<spec_field>``, ``indices`` and ``name`` and give the margin's sign and the label."""

    victim_kind: ClassVar[str] = "classifier"
    #: The name of the class-spec field (and of the argument in error messages and records).
    spec_field: ClassVar[str] = ""
    #: How :meth:`bind` resolves the class spec, ``(spec, name) -> (indices, label)``.
    _resolve: ClassVar[Callable[..., Tuple[Tuple[int, ...], str]]] = staticmethod(resolve_imagenet_classes)
    #: The ``"ce"`` and ``"cw"`` losses of the criterion, ``(logits, classes[, kappa]) -> (B,)``.
    _cross_entropy: ClassVar[Callable[..., Tensor]]
    _cw_margin: ClassVar[Callable[..., Tensor]]
    indices: Tuple[int, ...]
    name: str

    @property
    def _spec(self) -> ClassSpec:
        return getattr(self, self.spec_field)

    def bind(self, victim: Any) -> Any:
        """Resolve the class spec against the ImageNet label set (see :class:`Criterion`)."""
        self.check_victim(victim)
        idx, label = type(self)._resolve(self._spec, self.spec_field)
        return replace(self, indices=idx, name=label)  # type: ignore[type-var]

    def _bound(self) -> Tuple[int, ...]:
        return _require_bound(self.indices)

    def loss(self, output: Tensor, *, loss: str = "ce", kappa: float = 0.0) -> Tensor:
        """The cross-entropy (``"ce"``) or C&W (``"cw"``, confidence ``kappa``) loss per image (module docstring)."""
        _check_loss_name(loss)
        if loss == "ce":
            return type(self)._cross_entropy(output, self._bound())
        return type(self)._cw_margin(output, self._bound(), kappa)

    def score(self, output: Tensor) -> Tensor:
        """Softmax probability of the class (group)."""
        idx = torch.as_tensor(self._bound(), dtype=torch.long, device=output.device)
        return torch.softmax(output, dim=1)[:, idx].sum(dim=1)

    def to_record(self) -> Dict[str, Any]:
        """JSON-able description including the resolved indices."""
        return {**super().to_record(), self.spec_field: self.name or str(self._spec), "indices": list(self.indices)}


@dataclass(frozen=True)
class TargetedMisclassification(_ClassCriterion):
    """Adversarial when the top-1 class is the target (or any member of the target group).

    Losses: ``"ce"`` targeted (grouped) cross-entropy; ``"cw"`` C&W margin with confidence ``kappa``.

    Args:
        target_class: the target, see :data:`ClassSpec`.
    """

    spec_field: ClassVar[str] = "target_class"
    _cross_entropy = staticmethod(losses.targeted_cross_entropy)
    _cw_margin = staticmethod(losses.cw_targeted_margin)
    target_class: ClassSpec
    indices: Tuple[int, ...] = field(default=(), compare=False)
    name: str = field(default="", compare=False)

    def margin(self, output: Tensor) -> Tensor:
        """Best target logit minus best other logit."""
        return _top1_margin(output, self._bound())

    @property
    def label(self) -> str:
        """``"target=<name>"``."""
        return f"target={self.name or self.target_class}"


@dataclass(frozen=True)
class Misclassification(_ClassCriterion):
    """Untargeted: adversarial when the top-1 class is not the true class (nor any member of the true group).

    The true class is resolved by :func:`resolve_true_class`: one member of a PASCAL3D+ group stands for the whole
    group (``Misclassification("airliner")`` is not adversarial where the top-1 is a warplane); a class of no group
    is itself alone; ``[index]`` names one class exactly.

    Losses: ``"ce"`` minus the (grouped) cross-entropy of the true class; ``"cw"`` C&W untargeted margin.

    Args:
        true_class: the true class, see :data:`ClassSpec`.
    """

    spec_field: ClassVar[str] = "true_class"
    _resolve = staticmethod(resolve_true_class)
    _cross_entropy = staticmethod(losses.untargeted_cross_entropy)
    _cw_margin = staticmethod(losses.cw_untargeted_margin)
    true_class: ClassSpec
    indices: Tuple[int, ...] = field(default=(), compare=False)
    name: str = field(default="", compare=False)

    def margin(self, output: Tensor) -> Tensor:
        """Best other logit minus best true logit."""
        return -_top1_margin(output, self._bound())

    @property
    def label(self) -> str:
        """``"untargeted(true=<name>)"``."""
        return f"untargeted(true={self.name or self.true_class})"


@dataclass(frozen=True)
class Disappearance(Criterion):
    """Detector criterion: adversarial when no box of the hidden class(es) scores ``threshold`` or more.

    The loss is the paper's disappearance loss ``max_{z,b} score_{y'}(z, b)`` (objectness x class probability
    where the model has an objectness, the class probability otherwise).

    Args:
        class_name: a detector class name (e.g. ``"dining table"``), a sequence of names, or ``"all"`` to hide
            every detection.
        threshold: the detection score threshold the victim reports at.
    """

    victim_kind: ClassVar[str] = "detector"
    class_name: Union[str, Sequence[str]] = "all"
    threshold: float = 0.5
    indices: Optional[Tuple[int, ...]] = field(default=None, compare=False)
    bound: bool = field(default=False, compare=False)

    def __post_init__(self) -> None:
        _validate.finite_float("threshold", self.threshold)  # TypeError for a non-number
        if not 0.0 < float(self.threshold) <= 1.0:
            raise ValueError(f"threshold must be in (0, 1], got {self.threshold}")

    def bind(self, victim: Any) -> "Disappearance":
        """Resolve class names against the detector's ``class_names``."""
        self.check_victim(victim)
        if isinstance(self.class_name, str) and self.class_name == "all":
            return replace(self, indices=None, bound=True)
        names = [self.class_name] if isinstance(self.class_name, str) else list(self.class_name)
        if not names:
            raise ValueError("class_name must name at least one class (or be 'all')")
        idx = []
        for n in names:
            if hasattr(victim, "class_index"):
                idx.append(int(victim.class_index(n)))
            elif n in victim.class_names:
                idx.append(list(victim.class_names).index(n))
            else:
                raise ValueError(f"class_name {n!r} is not a class of the victim")
        return replace(self, indices=tuple(idx), bound=True)

    def _scores(self, output: Any) -> Tensor:
        if not self.bound:
            raise ValueError("criterion is not bound: call criterion.bind(victim) first")
        scores = output.scores() if hasattr(output, "scores") else output
        return losses.disappearance_loss(scores, self.indices)

    def loss(self, output: Any, *, loss: str = "ce", kappa: float = 0.0) -> Tensor:
        """The disappearance loss (``loss`` and ``kappa`` are ignored: detectors have one loss)."""
        return self._scores(output)

    def margin(self, output: Any) -> Tensor:
        """``threshold - max score``."""
        return float(self.threshold) - self._scores(output)

    def score(self, output: Any) -> Tensor:
        """The best score of the hidden class(es)."""
        return self._scores(output)

    @property
    def label(self) -> str:
        """``"disappear(<names>)"``."""
        names = self.class_name if isinstance(self.class_name, str) else ",".join(self.class_name)
        return f"disappear({names})"

    def to_record(self) -> Dict[str, Any]:
        """JSON-able description."""
        return {**super().to_record(), "class_name": self.class_name, "threshold": float(self.threshold),
                "indices": None if self.indices is None else list(self.indices)}


@dataclass(frozen=True)
class WithMargin(Criterion):
    """``base`` with a confidence margin: adversarial when ``base.margin(output) > required``.

    The loss is ``base``'s (so the attack keeps pushing past the margin with ``loss="ce"``; with ``loss="cw"`` give
    ``kappa >= required``), the score is ``base``'s.

    Args:
        base: the criterion to strengthen (any :class:`~meshadv.attacks.criteria.Criterion`).
        required: the margin it must hold with, ``>= 0`` (0 = ``base`` itself). Classifier criteria measure their
            margin in logits (best target logit minus best other logit), :class:`~meshadv.attacks.Disappearance` in
            detection score (``threshold - best score``).

    Raises:
        ValueError: ``base`` is not a criterion, or ``required`` is negative or not finite.

    Example:
        >>> from meshadv.attacks import Misclassification
        >>> crit = WithMargin(Misclassification("aeroplane"), 3.0)
        >>> crit.label
        'untargeted(true=aeroplane)+margin3'
    """

    base: Criterion
    required: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.base, Criterion):
            raise ValueError(f"base must be a Criterion, got {type(self.base).__name__}")
        if not (isinstance(self.required, (int, float)) and math.isfinite(self.required) and self.required >= 0):
            raise ValueError(f"required must be a finite number >= 0, got {self.required!r}")
        object.__setattr__(self, "required", float(self.required))

    @property
    def victim_kind(self) -> str:  # type: ignore[override]
        """The wrapped criterion's victim kind."""
        return self.base.victim_kind

    def bind(self, victim: Any) -> "WithMargin":
        """Bind the wrapped criterion to ``victim`` (see :meth:`Criterion.bind`)."""
        return replace(self, base=self.base.bind(victim))

    def loss(self, output: Any, *, loss: str = "ce", kappa: float = 0.0) -> Tensor:
        """The wrapped criterion's loss."""
        return self.base.loss(output, loss=loss, kappa=kappa)

    def margin(self, output: Any) -> Tensor:
        """``base.margin(output) - required``."""
        return self.base.margin(output) - self.required

    def score(self, output: Any) -> Tensor:
        """The wrapped criterion's score."""
        return self.base.score(output)

    @property
    def label(self) -> str:
        """``"<base label>+margin<required>"``."""
        return f"{self.base.label}+margin{self.required:g}"

    def to_record(self) -> Dict[str, Any]:
        """JSON-able description: the wrapped criterion's record plus ``required_margin``."""
        return {**self.base.to_record(), "criterion": f"WithMargin({type(self.base).__name__})",
                "label": self.label, "required_margin": self.required}
