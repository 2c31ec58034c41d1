"""Tests of the torchvision victims (DenseNet-121, Inception-v3): user-supplied state_dict round trips,
preprocessing (224 / 299 px, normalisation), gradients and the promised errors."""

from __future__ import annotations

from pathlib import Path
import pytest
import torch
import torchvision

from meshadv.victims.registry import load_victim
from meshadv.victims.torchvision_models import TorchvisionVictim, read_state_dict


@pytest.fixture(scope="module")
def densenet_file(tmp_path_factory: pytest.TempPathFactory) -> tuple:
    torch.manual_seed(0)
    model = torchvision.models.densenet121(weights=None).eval()
    path = tmp_path_factory.mktemp("densenet") / "densenet121.pth"
    torch.save(model.state_dict(), path)
    return model, path


@pytest.fixture(scope="module")
def inception_file(tmp_path_factory: pytest.TempPathFactory) -> tuple:
    torch.manual_seed(1)
    model = torchvision.models.inception_v3(weights=None, aux_logits=True, init_weights=False).eval()
    path = tmp_path_factory.mktemp("inception") / "inception_v3.pth"
    torch.save(model.state_dict(), path)
    return model, path


def test_densenet_round_trip_gives_identical_outputs(densenet_file: tuple) -> None:
    model, path = densenet_file
    victim = load_victim("densenet121", weights=path)
    assert victim.kind == "classifier" and victim.input_size == (224, 224)
    images = torch.rand(2, 3, 224, 224)
    mean = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
    std = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
    with torch.no_grad():
        expected = model((images - mean) / std)
        out = victim(images)
    assert out.shape == (2, 1000)
    torch.testing.assert_close(out, expected, rtol=0, atol=0)


def test_inception_round_trip_at_299(inception_file: tuple) -> None:
    model, path = inception_file
    victim = load_victim("inception_v3", weights=path)
    assert victim.input_size == (299, 299)
    images = torch.rand(1, 3, 120, 160)
    resized = torch.nn.functional.interpolate(images, size=(299, 299), mode="bilinear", align_corners=False)
    model.transform_input = False
    with torch.no_grad():
        expected = model((resized - 0.5) / 0.5)
    torch.testing.assert_close(victim(images), expected, rtol=0, atol=0)


def test_inception_without_aux_head_and_wrapped_state_dict(tmp_path: Path) -> None:
    torch.manual_seed(2)
    model = torchvision.models.inception_v3(weights=None, aux_logits=False, init_weights=False).eval()
    wrapped = {"state_dict": {f"module.{k}": v for k, v in model.state_dict().items()}}
    torch.save(wrapped, tmp_path / "wrapped.pth")
    assert set(read_state_dict(tmp_path / "wrapped.pth")) == set(model.state_dict())
    victim = TorchvisionVictim("inception_v3", weights=tmp_path / "wrapped.pth")
    images = torch.rand(1, 3, 299, 299)
    with torch.no_grad():
        torch.testing.assert_close(victim(images), model((images - 0.5) / 0.5), rtol=0, atol=0)


def test_gradient_reaches_input_and_matches_finite_differences(densenet_file: tuple) -> None:
    """The input gradient (through the resize to 224 px, the normalisation and the network) is the derivative: a
    central difference along a random direction in float64 agrees with it."""
    _, path = densenet_file
    victim = load_victim("densenet121", weights=path)
    assert not any(p.requires_grad for p in victim.parameters())
    images = torch.rand(1, 3, 64, 64, requires_grad=True)
    victim(images)[0, 3].backward()
    assert images.grad is not None and images.grad.abs().sum() > 0
    victim = victim.double()
    seeded = [torch.Generator().manual_seed(seed) for seed in (5, 6, 7)]
    x = torch.rand(1, 3, 64, 64, dtype=torch.float64, generator=seeded[0], requires_grad=True)
    weights = torch.randn(1, 1000, dtype=torch.float64, generator=seeded[1])
    (grad,) = torch.autograd.grad((victim(x) * weights).sum(), x)
    direction = torch.randn(x.shape, dtype=torch.float64, generator=seeded[2])
    eps = 1e-8  # ReLU kinks: a larger step crosses some of them
    with torch.no_grad():
        numeric = float(((victim(x + eps * direction) - victim(x - eps * direction)) * weights).sum() / (2 * eps))
    assert numeric == pytest.approx(float((grad * direction).sum()), rel=1e-5, abs=1e-8)


def test_errors(tmp_path: Path, densenet_file: tuple) -> None:
    _, densenet_path = densenet_file
    with pytest.raises(ValueError, match="weights="):
        load_victim("densenet121")
    with pytest.raises(FileNotFoundError, match="nothing.pth"):
        load_victim("inception_v3", weights=tmp_path / "nothing.pth")
    with pytest.raises(ValueError, match="do not match"):
        load_victim("inception_v3", weights=densenet_path)
    (tmp_path / "junk.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="state_dict"):
        load_victim("densenet121", weights=tmp_path / "junk.pth")
    with pytest.raises(ValueError, match="cfg"):
        load_victim("densenet121", weights=densenet_path, cfg="x.cfg")
