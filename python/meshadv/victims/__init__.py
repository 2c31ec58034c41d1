"""Victim models for MeshAdv: ImageNet classifiers and COCO detectors behind one interface.

Every victim takes rendered images ``(B, 3, H, W)`` in ``[0, 1]`` of any size, preprocesses them differentiably and is
frozen in eval mode. Load one by name with :func:`load_victim`; list names with :func:`available_victims`.
"""

from __future__ import annotations

from meshadv.victims.victim import (
    ClassifierVictim,
    Detections,
    DetectorOutput,
    DetectorVictim,
    Victim,
)
from meshadv.victims.labels import (
    PASCAL3D_TO_IMAGENET,
    classify_pascal,
    coco_class_names,
    group_logits,
    group_scores,
    imagenet_class_names,
)
from meshadv.victims.registry import available_victims, load_victim

__all__ = [
    "PASCAL3D_TO_IMAGENET",
    "ClassifierVictim",
    "Detections",
    "DetectorOutput",
    "DetectorVictim",
    "Victim",
    "available_victims",
    "classify_pascal",
    "coco_class_names",
    "group_logits",
    "group_scores",
    "imagenet_class_names",
    "load_victim",
]
