"""Tests of meshadv.victims.preprocess and the base classes' shared pieces (DetectorOutput, NMS post-processing)."""

from __future__ import annotations

from pathlib import Path
import numpy as np
import pytest
import torch

from meshadv.victims.victim import DetectorOutput, check_images, postprocess_detections
from meshadv.victims.preprocess import Preprocess, center_crop, image_to_tensor, load_image


def test_preprocess_resizes_and_normalises() -> None:
    pre = Preprocess((8, 6), mean=(0.1, 0.2, 0.3), std=(0.5, 0.25, 2.0))
    constant = torch.full((2, 3, 17, 5), 0.6)
    out = pre(constant)
    assert out.shape == (2, 3, 8, 6)
    expected = torch.tensor([(0.6 - 0.1) / 0.5, (0.6 - 0.2) / 0.25, (0.6 - 0.3) / 2.0])
    torch.testing.assert_close(out.mean(dim=(0, 2, 3)), expected)
    same_size = torch.rand(1, 3, 8, 6)
    torch.testing.assert_close(pre(same_size), (same_size - pre.mean) / pre.std)


def test_preprocess_gradient_matches_finite_differences() -> None:
    pre = Preprocess((4, 6), mean=(0.5, 0.5, 0.5), std=(0.2, 0.3, 0.4)).double()
    for shape in [(1, 3, 7, 9), (1, 3, 3, 2)]:  # shrinking (antialiased) and enlarging
        images = torch.rand(*shape, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(pre, (images,))


def test_preprocess_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="size"):
        Preprocess((0, 5), (0, 0, 0), (1, 1, 1))
    with pytest.raises(ValueError, match="std"):
        Preprocess((5, 5), (0, 0, 0), (1, 0, 1))
    with pytest.raises(ValueError, match="images"):
        Preprocess((5, 5), (0, 0, 0), (1, 1, 1))(torch.rand(3, 5, 5))
    with pytest.raises(ValueError, match="images"):
        check_images(np.zeros((1, 3, 4, 4)))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="images"):
        check_images(torch.zeros(1, 3, 4, 4, dtype=torch.uint8))


def test_image_helpers(tmp_path: Path) -> None:
    from PIL import Image

    array = (np.arange(5 * 7 * 3) % 256).astype(np.uint8).reshape(5, 7, 3)
    tensor = image_to_tensor(array)
    assert tensor.shape == (1, 3, 5, 7)
    torch.testing.assert_close(tensor[0, :, 2, 3], torch.from_numpy(array[2, 3].astype(np.float32) / 255.0))
    Image.fromarray(array).save(tmp_path / "a.png")
    torch.testing.assert_close(load_image(tmp_path / "a.png"), tensor)
    with pytest.raises(FileNotFoundError, match="^path .*missing.png"):
        load_image(tmp_path / "missing.png")
    crop = center_crop(torch.rand(1, 3, 10, 20), 0.5)
    assert crop.shape == (1, 3, 5, 5)
    with pytest.raises(ValueError, match="fraction"):
        center_crop(tensor, 0.0)


def _iou(a: torch.Tensor, b: torch.Tensor) -> float:
    lt = torch.maximum(a[:2], b[:2])
    rb = torch.minimum(a[2:], b[2:])
    inter = (rb - lt).clamp(min=0).prod()
    area = (a[2:] - a[:2]).prod() + (b[2:] - b[:2]).prod() - inter
    return float(inter / area)


def test_detector_output_scores_and_validation() -> None:
    boxes = torch.rand(2, 5, 4)
    probs = torch.rand(2, 5, 3)
    obj = torch.rand(2, 5)
    torch.testing.assert_close(DetectorOutput(boxes, obj, probs).scores(), obj[..., None] * probs)
    torch.testing.assert_close(DetectorOutput(boxes, None, probs).scores(), probs)
    with pytest.raises(ValueError, match="objectness"):
        DetectorOutput(boxes, torch.rand(2, 4), probs)
    with pytest.raises(ValueError, match="class_probs"):
        DetectorOutput(boxes, None, torch.rand(2, 4, 3))


def test_postprocess_thresholds_and_applies_classwise_nms() -> None:
    boxes = torch.tensor([[[0.1, 0.1, 0.5, 0.5], [0.12, 0.1, 0.52, 0.5], [0.6, 0.6, 0.9, 0.9], [0.0, 0.0, 1.0, 1.0]]])
    probs = torch.tensor([[[0.9, 0.0], [0.8, 0.7], [0.0, 0.6], [0.2, 0.1]]])
    (dets,) = postprocess_detections(DetectorOutput(boxes, None, probs), ("cat", "dog"), 0.5, 0.5)
    # box 1 is suppressed as a cat by box 0, but kept as a dog; box 3 is below the threshold
    assert dets.names() == ["cat", "dog", "dog"]
    torch.testing.assert_close(dets.scores, torch.tensor([0.9, 0.7, 0.6]))
    assert _iou(dets.boxes[0], dets.boxes[1]) > 0.5
    records = dets.to_records()
    assert records[0]["label"] == "cat" and len(records[0]["box"]) == 4
    (none,) = postprocess_detections(DetectorOutput(boxes, None, probs), ("cat", "dog"), 0.95, 0.5)
    assert len(none) == 0
