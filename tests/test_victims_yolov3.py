"""Tests of the Darknet cfg/weights reader and the YOLOv3 victim: a tiny cfg with random weights saved in the
Darknet format and reloaded (identical outputs), the yolo-layer decoding against a slow reference, gradients, NMS
detections and the promised errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from meshadv.victims.victim import Detections, DetectorOutput
from meshadv.victims.darknet import (
    DarknetHeader,
    DarknetNet,
    YoloSpec,
    load_darknet_weights,
    parse_cfg,
    save_darknet_weights,
)
from meshadv.victims.registry import load_victim
from meshadv.victims.yolov3 import YOLOv3Victim, decode_yolo_layer

# Two yolo heads (16x16 and 32x32 at 64 px) with 3 of 6 anchors each and 2 classes; every supported layer type.
TINY_CFG = """
[net]
# comment
width=64
height=64
channels=3

[convolutional]
batch_normalize=1
filters=8
size=3
stride=1
pad=1
activation=leaky

[maxpool]
size=2
stride=2

[convolutional]
batch_normalize=1
filters=16
size=3
stride=2
pad=1
activation=leaky

[convolutional]
batch_normalize=1
filters=16
size=1
stride=1
pad=1
activation=leaky

[shortcut]
from=-2
activation=linear

[convolutional]
size=1
stride=1
pad=1
filters=21
activation=linear

[yolo]
mask = 3,4,5
anchors = 4,5, 8,9, 12,10, 20,30, 40,30, 50,60
classes=2
num=6

[route]
layers = -3

[upsample]
stride=2

[route]
layers = -1, 1

[maxpool]
size=2
stride=1

[convolutional]
size=1
stride=1
pad=1
filters=21
activation=linear

[yolo]
mask = 0,1,2
anchors = 4,5, 8,9, 12,10, 20,30, 40,30, 50,60
classes=2
num=6
"""


def _random_net(cfg: Path, seed: int = 0) -> DarknetNet:
    torch.manual_seed(seed)
    net = DarknetNet(parse_cfg(cfg))
    with torch.no_grad():
        for param in net.parameters():
            param.normal_(0.0, 0.3)
        for conv in net.conv_layers():
            if conv.bn is not None:
                conv.bn.running_mean.normal_()
                conv.bn.running_var.uniform_(0.5, 2.0)
    return net.eval()


@pytest.fixture()
def tiny(tmp_path: Path) -> tuple:
    cfg = tmp_path / "tiny.cfg"
    cfg.write_text(TINY_CFG)
    net = _random_net(cfg)
    weights = tmp_path / "tiny.weights"
    save_darknet_weights(net, weights, DarknetHeader(0, 2, 5, 123456789012))
    return cfg, weights, net


def test_cfg_parsing(tiny: tuple) -> None:
    cfg, _, net = tiny
    sections = parse_cfg(cfg)
    assert sections[0] == {"type": "net", "width": "64", "height": "64", "channels": "3"}
    assert [s["type"] for s in sections[1:4]] == ["convolutional", "maxpool", "convolutional"]
    assert net.input_size == (64, 64)
    assert net.yolo_specs[0] == YoloSpec(anchors=((20.0, 30.0), (40.0, 30.0), (50.0, 60.0)), num_classes=2)
    raws = net(torch.rand(1, 3, 64, 64))
    assert [tuple(r.shape) for r in raws] == [(1, 21, 16, 16), (1, 21, 32, 32)]


def test_weights_file_layout(tiny: tuple) -> None:
    _, weights, net = tiny
    data = weights.read_bytes()
    assert np.frombuffer(data[:12], dtype="<i4").tolist() == [0, 2, 5]
    assert int(np.frombuffer(data[12:20], dtype="<i8")[0]) == 123456789012
    first = net.conv_layers()[0]
    floats = np.frombuffer(data[20:], dtype="<f4")
    # batch-normalised conv: beta, gamma, mean, var, then weights
    np.testing.assert_array_equal(floats[:8], first.bn.bias.detach().numpy())
    np.testing.assert_array_equal(floats[8:16], first.bn.weight.detach().numpy())
    np.testing.assert_array_equal(floats[24:32], first.bn.running_var.numpy())
    np.testing.assert_array_equal(floats[32 : 32 + 8 * 27], first.conv.weight.detach().numpy().ravel())
    expected_len = (
        20
        + 4 * sum(p.numel() for p in net.parameters())
        + 4 * sum(c.bn.running_mean.numel() * 2 for c in net.conv_layers() if c.bn is not None)
    )
    assert len(data) == expected_len


def test_round_trip_gives_identical_outputs(tiny: tuple) -> None:
    cfg, weights, net = tiny
    victim = load_victim("yolov3", weights=weights, cfg=cfg)
    assert isinstance(victim, YOLOv3Victim) and victim.kind == "detector"
    assert victim.header == DarknetHeader(0, 2, 5, 123456789012)
    assert victim.class_names == ("class_0", "class_1")
    images = torch.rand(2, 3, 64, 64)
    with torch.no_grad():
        for a, b in zip(victim.net(images), net(images)):
            torch.testing.assert_close(a, b, rtol=0, atol=0)
        out = victim(images)
    assert isinstance(out, DetectorOutput)
    assert out.boxes.shape == (2, 3 * (16 * 16 + 32 * 32), 4)
    assert out.objectness.shape == (2, 3840) and out.class_probs.shape == (2, 3840, 2)


def test_int32_seen_header_round_trip(tmp_path: Path) -> None:
    cfg = tmp_path / "tiny.cfg"
    cfg.write_text(TINY_CFG)
    net = _random_net(cfg, seed=3)
    save_darknet_weights(net, tmp_path / "old.weights", DarknetHeader(0, 1, 0, 77))
    assert len((tmp_path / "old.weights").read_bytes()) % 4 == 0
    other = _random_net(cfg, seed=4)
    header = load_darknet_weights(other, tmp_path / "old.weights")
    assert header == DarknetHeader(0, 1, 0, 77) and not header.seen_is_int64
    for a, b in zip(net.parameters(), other.parameters()):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


def _sigmoid(v: float) -> float:
    return 1.0 / (1.0 + math.exp(-v))


def test_decoding_matches_slow_reference() -> None:
    torch.manual_seed(5)
    spec = YoloSpec(anchors=((10.0, 14.0), (23.0, 27.0)), num_classes=3)
    raw = torch.randn(1, 2 * 8, 3, 4, dtype=torch.float64)
    boxes, objectness, probs = decode_yolo_layer(raw, spec, (96, 128))
    row = 0
    for cy in range(3):
        for cx in range(4):
            for a, (aw, ah) in enumerate(spec.anchors):
                t = raw[0, a * 8 : (a + 1) * 8, cy, cx].tolist()
                x = (_sigmoid(t[0]) + cx) / 4
                y = (_sigmoid(t[1]) + cy) / 3
                w = math.exp(t[2]) * aw / 128
                h = math.exp(t[3]) * ah / 96
                expected = [x - w / 2, y - h / 2, x + w / 2, y + h / 2]
                assert boxes[0, row].tolist() == pytest.approx(expected, rel=1e-12)
                assert float(objectness[0, row]) == pytest.approx(_sigmoid(t[4]), rel=1e-12)
                assert probs[0, row].tolist() == pytest.approx([_sigmoid(v) for v in t[5:]], rel=1e-12)
                row += 1


def test_gradients_reach_the_input_and_match_finite_differences(tiny: tuple) -> None:
    cfg, weights, _ = tiny
    victim = YOLOv3Victim.from_darknet(cfg, weights).double()
    torch.manual_seed(6)
    images = torch.rand(1, 3, 40, 56, dtype=torch.float64, requires_grad=True)
    w_obj = torch.rand(1, 3840, dtype=torch.float64)

    def loss_fn(x: torch.Tensor) -> torch.Tensor:
        out = victim(x)
        return (out.objectness * w_obj).sum() + out.class_probs[..., 1].max() + out.boxes.sum()

    (grad,) = torch.autograd.grad(loss_fn(images), images)
    assert grad.abs().sum() > 0
    direction = torch.randn_like(images)
    eps = 1e-7
    with torch.no_grad():
        numeric = float((loss_fn(images + eps * direction) - loss_fn(images - eps * direction)) / (2 * eps))
    assert numeric == pytest.approx(float((grad * direction).sum()), rel=1e-5)


def test_detect_returns_nms_filtered_detections(tiny: tuple) -> None:
    cfg, weights, _ = tiny
    victim = YOLOv3Victim.from_darknet(cfg, weights, class_names=["cat", "dog"])
    images = torch.rand(2, 3, 64, 64)
    dets = victim.detect(images, score_threshold=0.3, iou_threshold=0.4)
    assert len(dets) == 2 and all(isinstance(d, Detections) for d in dets)
    raw_scores = victim(images).scores()
    for b, det in enumerate(dets):
        assert len(det) > 0
        assert bool((det.scores >= 0.3).all()) and bool((det.scores[:-1] >= det.scores[1:]).all())
        assert float(det.scores[0]) == pytest.approx(float(raw_scores[b].max()))
        assert bool((det.boxes >= 0).all() and (det.boxes <= 1).all())
        assert set(det.names()) <= {"cat", "dog"}
        from torchvision.ops import box_iou

        for label in det.labels.unique():
            same = det.boxes[det.labels == label]
            iou = box_iou(same, same) - torch.eye(len(same))
            assert float(iou.max()) <= 0.4 + 1e-6
    assert victim.class_index("dog") == 1
    with pytest.raises(ValueError, match="class_name"):
        victim.class_index("bird")
    with pytest.raises(ValueError, match="score_threshold"):
        victim.detect(images, score_threshold=1.5)


def test_coco_names_default_for_80_classes(tmp_path: Path) -> None:
    cfg_text = TINY_CFG.replace("classes=2", "classes=80").replace("filters=21", "filters=255")
    cfg = tmp_path / "coco.cfg"
    cfg.write_text(cfg_text)
    net = _random_net(cfg)
    save_darknet_weights(net, tmp_path / "coco.weights")
    victim = load_victim("yolov3", weights=tmp_path / "coco.weights", cfg=cfg)
    assert len(victim.class_names) == 80 and victim.class_names[16] == "dog"


def test_errors(tmp_path: Path, tiny: tuple) -> None:
    cfg, weights, _ = tiny
    with pytest.raises(ValueError, match="weights=.*cfg="):
        load_victim("yolov3")
    with pytest.raises(FileNotFoundError, match="missing.weights"):
        load_victim("yolov3", weights=tmp_path / "missing.weights", cfg=cfg)
    with pytest.raises(FileNotFoundError, match="missing.cfg"):
        load_victim("yolov3", weights=weights, cfg=tmp_path / "missing.cfg")
    truncated = tmp_path / "truncated.weights"
    truncated.write_bytes(weights.read_bytes()[:-40])
    with pytest.raises(ValueError, match="do not match"):
        load_victim("yolov3", weights=truncated, cfg=cfg)
    bad = tmp_path / "bad.cfg"
    bad.write_text(TINY_CFG.replace("[upsample]", "[reorg]"))
    with pytest.raises(ValueError, match=r"^cfg: unsupported layer type \[reorg\]"):
        load_victim("yolov3", weights=weights, cfg=bad)
    bad.write_text("width=3\n" + TINY_CFG)
    with pytest.raises(ValueError, match="outside"):
        parse_cfg(bad)
    bad.write_text(TINY_CFG.replace("filters=21", "filters=20", 1))
    with pytest.raises(ValueError, match=r"^cfg: \[yolo\] layer 6 expects 21 input channels"):
        parse_cfg(bad) and DarknetNet(parse_cfg(bad))
