"""Tests of meshadv.victims.labels: class-name lists, PASCAL3D+ groups and the grouped-logit helpers."""

from __future__ import annotations

from pathlib import Path
import pytest
import torch

from meshadv.victims.labels import (
    PASCAL3D_CLASSES,
    PASCAL3D_TO_COCO,
    PASCAL3D_TO_IMAGENET,
    classify_pascal,
    coco91_class_names,
    coco_class_names,
    group_logits,
    group_scores,
    imagenet_class_names,
    imagenet_index,
)

EXPECTED_GROUP_NAMES = {
    "aeroplane": {"airliner", "warplane"},
    "bottle": {"beer bottle", "wine bottle", "water bottle", "pop bottle"},
    "chair": {"folding chair", "rocking chair", "barber chair", "throne"},
    "diningtable": {"dining table"},
    "sofa": {"studio couch"},
}


def test_imagenet_names_are_the_1000_classes_in_order() -> None:
    names = imagenet_class_names()
    assert len(names) == 1000
    assert len(set(names)) >= 998  # ImageNet has two duplicated names (crane, maillot)
    assert names[0] == "tench" and names[281] == "tabby" and names[967] == "espresso"


def test_coco_names_match_darknet_order(shared_data: Path) -> None:
    names = coco_class_names()
    assert len(names) == 80 and len(coco91_class_names()) == 91
    darknet = [n for n in (shared_data / "photos" / "coco.names").read_text().splitlines() if n]
    renamed = {
        "motorbike": "motorcycle",
        "aeroplane": "airplane",
        "sofa": "couch",
        "pottedplant": "potted plant",
        "diningtable": "dining table",
        "tvmonitor": "tv",
    }
    assert [renamed.get(n, n) for n in darknet] == list(names)


def test_pascal_groups_hold_the_documented_imagenet_classes() -> None:
    names = imagenet_class_names()
    assert tuple(PASCAL3D_TO_IMAGENET) == PASCAL3D_CLASSES
    for cls, expected in EXPECTED_GROUP_NAMES.items():
        assert {names[i] for i in PASCAL3D_TO_IMAGENET[cls]} == expected
    assert {"canoe", "liner", "speedboat"} <= {names[i] for i in PASCAL3D_TO_IMAGENET["boat"]}
    assert {"mountain bike", "bicycle-built-for-two"} == {names[i] for i in PASCAL3D_TO_IMAGENET["bicycle"]}
    all_idx = [i for idx in PASCAL3D_TO_IMAGENET.values() for i in idx]
    assert len(all_idx) == len(set(all_idx)), "groups must not overlap"
    assert set(PASCAL3D_TO_COCO.values()) <= set(coco_class_names())


def test_imagenet_index() -> None:
    assert imagenet_index("studio couch") == 831
    with pytest.raises(ValueError, match="name"):
        imagenet_index("not a class")


def test_group_logits_is_logsumexp_of_the_group() -> None:
    torch.manual_seed(0)
    logits = torch.randn(3, 1000, dtype=torch.float64)
    out = group_logits(logits)
    assert out.shape == (3, 7)
    for g, idx in enumerate(PASCAL3D_TO_IMAGENET.values()):
        expected = torch.log(torch.exp(logits[:, idx]).sum(dim=1))
        torch.testing.assert_close(out[:, g], expected)
    custom = group_logits(logits, [[1], [2, 3]])
    torch.testing.assert_close(custom[:, 0], logits[:, 1])


def test_group_scores_are_probability_masses() -> None:
    torch.manual_seed(1)
    logits = torch.randn(2, 1000, dtype=torch.float64)
    probs = torch.softmax(logits, dim=1)
    scores = group_scores(logits, {"a": [5, 6], "b": list(range(1000))})
    torch.testing.assert_close(scores[:, 0], probs[:, 5] + probs[:, 6])
    torch.testing.assert_close(scores[:, 1], torch.ones(2, dtype=torch.float64))


def test_group_logits_gradient_matches_finite_differences() -> None:
    torch.manual_seed(2)
    logits = torch.randn(2, 20, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: group_scores(x, [[0, 3, 4], [7]]), (logits,))


def test_group_helpers_reject_bad_input() -> None:
    with pytest.raises(ValueError, match="logits"):
        group_logits(torch.zeros(1000))
    with pytest.raises(ValueError, match="groups"):
        group_logits(torch.zeros(1, 10), [[3, 12]])
    with pytest.raises(ValueError, match="groups"):
        group_logits(torch.zeros(1, 10), [[]])


def test_classify_pascal() -> None:
    logits = torch.zeros(3, 1000)
    logits[0, 831] = 5.0  # studio couch
    logits[1, 559] = 5.0  # folding chair
    logits[2, 0] = 5.0  # tench
    assert classify_pascal(logits) == ["sofa", "chair", None]
    assert classify_pascal(logits[1]) == "chair"
    with pytest.raises(ValueError, match="logits"):
        classify_pascal(torch.zeros(2, 10))
