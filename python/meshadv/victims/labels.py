"""Class names (ImageNet-1k, COCO) and the PASCAL3D+ -> ImageNet class groups used to score classifiers.

A rendering of a PASCAL3D+ class ``c`` counts as classified as ``c`` when the top-1 ImageNet label lies in
``PASCAL3D_TO_IMAGENET[c]``, and a true class given as one member of a group stands for its whole group (an
airliner seen as a warplane is still an aeroplane): :func:`meshadv.attacks.criteria.resolve_true_class` is that
rule, and every "is this render its class" verdict goes through it. The groups (ImageNet index: name):

- aeroplane: 404 airliner, 895 warplane
- bicycle: 444 bicycle-built-for-two, 671 mountain bike
- boat: 472 canoe, 484 catamaran, 510 container ship, 554 fireboat, 576 gondola, 625 lifeboat, 628 liner,
  724 pirate (ship), 780 schooner, 814 speedboat, 871 trimaran, 914 yawl
- bottle: 440 beer bottle, 737 pop bottle, 898 water bottle, 907 wine bottle
- chair: 423 barber chair, 559 folding chair, 765 rocking chair, 857 throne
- diningtable: 532 dining table
- sofa: 831 studio couch

The name lists ship inside the package (``victims/data/*.txt``), generated from torchvision's weight metadata
(``ResNet50_Weights.IMAGENET1K_V2.meta["categories"]`` and ``FasterRCNN_ResNet50_FPN_Weights.COCO_V1``), so nothing is
downloaded.

Example:
    >>> PASCAL3D_TO_IMAGENET["bottle"]
    [440, 737, 898, 907]
    >>> imagenet_class_names()[440]
    'beer bottle'
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import cache
from importlib import resources

import torch
from torch import Tensor

from meshadv.data import PASCAL3D_CLASSES

__all__ = [
    "PASCAL3D_CLASSES",
    "PASCAL3D_TO_COCO",
    "PASCAL3D_TO_IMAGENET",
    "classify_pascal",
    "coco91_class_names",
    "coco_class_names",
    "group_logits",
    "group_scores",
    "imagenet_class_names",
    "imagenet_index",
    "pascal_class_of",
]


#: PASCAL3D+ class -> ImageNet-1k indices of the classes that count as that class (sorted).
PASCAL3D_TO_IMAGENET: dict[str, list[int]] = {
    "aeroplane": [404, 895],
    "bicycle": [444, 671],
    "boat": [472, 484, 510, 554, 576, 625, 628, 724, 780, 814, 871, 914],
    "bottle": [440, 737, 898, 907],
    "chair": [423, 559, 765, 857],
    "diningtable": [532],
    "sofa": [831],
}

#: PASCAL3D+ class -> COCO (80-class) name, for detectors.
PASCAL3D_TO_COCO: dict[str, str] = {
    "aeroplane": "airplane",
    "bicycle": "bicycle",
    "boat": "boat",
    "bottle": "bottle",
    "chair": "chair",
    "diningtable": "dining table",
    "sofa": "couch",
}


@cache
def _pascal_of_index() -> dict[int, str]:
    return {i: name for name, idx in PASCAL3D_TO_IMAGENET.items() for i in idx}


def pascal_class_of(index: int) -> str | None:
    """The PASCAL3D+ class whose ImageNet group holds ImageNet class ``index``, or ``None`` when no group does.

    Example:
        >>> pascal_class_of(895), pascal_class_of(340)
        ('aeroplane', None)
    """
    return _pascal_of_index().get(int(index))


def _read_names(filename: str) -> tuple[str, ...]:
    text = resources.files("meshadv.victims").joinpath("data").joinpath(filename).read_text(encoding="utf-8")
    return tuple(line for line in text.splitlines() if line)


@cache
def imagenet_class_names() -> tuple[str, ...]:
    """The 1000 ImageNet-1k class names in the standard (logit) order."""
    return _read_names("imagenet_classes.txt")


@cache
def coco91_class_names() -> tuple[str, ...]:
    """The 91 COCO category slots by category id: index 0 is ``"__background__"``, unused ids are ``"N/A"``."""
    return _read_names("coco91_classes.txt")


@cache
def coco_class_names() -> tuple[str, ...]:
    """The 80 COCO class names in category-id order (the order YOLO and Darknet's ``coco.names`` use)."""
    return tuple(name for name in coco91_class_names() if name not in ("N/A", "__background__"))


def imagenet_index(name: str) -> int:
    """ImageNet index of a class name (exact match).

    Raises:
        ValueError: ``name`` is not an ImageNet class name.
    """
    try:
        return imagenet_class_names().index(name)
    except ValueError:
        raise ValueError(f"name {name!r} is not an ImageNet-1k class name") from None


def _group_indices(groups: Mapping[str, Sequence[int]] | Sequence[Sequence[int]] | None) -> list[list[int]]:
    if groups is None:
        groups = PASCAL3D_TO_IMAGENET
    if isinstance(groups, Mapping):
        groups = list(groups.values())
    out = []
    for group in groups:
        idx = [int(i) for i in group]
        if not idx:
            raise ValueError("groups must not contain an empty group")
        out.append(idx)
    if not out:
        raise ValueError("groups must contain at least one group")
    return out


def group_logits(logits: Tensor, groups: Mapping[str, Sequence[int]] | Sequence[Sequence[int]] | None = None) -> Tensor:
    """Log-sum-exp of each group's ImageNet logits: a logit for "any class of the group" (differentiable).

    ``cross_entropy(group_logits(logits, groups), target_group)`` is the grouped targeted cross-entropy.

    Args:
        logits: ``(B, C)`` classifier logits.
        groups: a mapping name -> indices (order of the values is used) or a list of index lists; default
            :data:`PASCAL3D_TO_IMAGENET` (7 groups in :data:`PASCAL3D_CLASSES` order).

    Returns:
        ``(B, G)``.

    Raises:
        ValueError: ``logits`` not 2-D, an empty group, or an index outside ``[0, C)``.
    """
    if logits.dim() != 2:
        raise ValueError(f"logits must have shape (B, C), got {tuple(logits.shape)}")
    idx = _group_indices(groups)
    num_classes = logits.shape[1]
    for group in idx:
        if min(group) < 0 or max(group) >= num_classes:
            raise ValueError(f"groups index out of range [0, {num_classes}): {group}")
    return torch.stack([torch.logsumexp(logits[:, group], dim=1) for group in idx], dim=1)


def group_scores(logits: Tensor, groups: Mapping[str, Sequence[int]] | Sequence[Sequence[int]] | None = None) -> Tensor:
    """Softmax probability mass of each group, ``sum_{i in group} softmax(logits)_i`` (differentiable).

    Args:
        logits: ``(B, C)`` classifier logits.
        groups: as in :func:`group_logits`.

    Returns:
        ``(B, G)`` in ``[0, 1]``.
    """
    return torch.exp(group_logits(logits, groups) - torch.logsumexp(logits, dim=1, keepdim=True))


def classify_pascal(logits: Tensor) -> str | None | list[str | None]:
    """The PASCAL3D+ class whose ImageNet group holds the top-1 label, or ``None`` when no group does.

    Args:
        logits: ``(1000,)`` for one image, or ``(B, 1000)`` for a batch.

    Returns:
        A class name or ``None`` for a 1-D input; a list of them for a 2-D input.

    Raises:
        ValueError: ``logits`` is not 1-D or 2-D with 1000 classes.
    """
    if logits.dim() not in (1, 2) or logits.shape[-1] != 1000:
        raise ValueError(f"logits must have shape (1000,) or (B, 1000), got {tuple(logits.shape)}")
    top1 = logits.detach().argmax(dim=-1)
    if logits.dim() == 1:
        return pascal_class_of(int(top1))
    return [pascal_class_of(i) for i in top1.tolist()]
