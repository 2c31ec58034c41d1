"""Victims run on their own device and hand results back on the images' device (``Victim.__call__``).

No GPU here: the CPU path is checked to copy nothing and to keep every tensor (output, input gradient) on the CPU;
the moving path is checked with a victim whose reported device differs from the images' (a stand-in "device" that
is the CPU itself), so that every copy and the way back are exercised; ``device="cuda"`` without CUDA must fail
before weights are read (tests/test_victims_weights.py).
"""

from __future__ import annotations

import pytest
import torch
from torch import Tensor, nn

from meshadv.victims.victim import ClassifierVictim, DetectorOutput, DetectorVictim


class _Tiny(ClassifierVictim):
    """A 1000-way linear classifier on 8x8 images that records the inputs its forward saw."""

    def __init__(self) -> None:
        super().__init__("tiny", (8, 8))
        self.linear = nn.Linear(3 * 8 * 8, 1000)
        self.seen: list[Tensor] = []

    def forward(self, images: Tensor) -> Tensor:
        self.seen.append(images)
        return self.linear(self.resize(images).flatten(1))


class _TinyDetector(DetectorVictim):
    """Two boxes per image from a linear layer."""

    def __init__(self) -> None:
        super().__init__("tiny_det", (8, 8), ("a", "b"))
        self.linear = nn.Linear(3 * 8 * 8, 2 * 7)

    def forward(self, images: Tensor) -> DetectorOutput:
        y = self.linear(self.resize(images).flatten(1)).view(-1, 2, 7)
        return DetectorOutput(boxes=y[..., :4], objectness=y[..., 4].sigmoid(), class_probs=y[..., 5:].softmax(-1))


def test_a_cpu_victim_copies_nothing_and_keeps_everything_on_the_cpu() -> None:
    victim = _Tiny()
    assert victim.device == torch.device("cpu")
    images = torch.rand(2, 3, 16, 16, requires_grad=True)
    logits = victim(images)
    assert victim.seen[0] is images, "no copy when the images are on the victim's device"
    logits[:, 3].sum().backward()
    assert logits.device.type == "cpu" and images.grad is not None and images.grad.device.type == "cpu"
    assert images.grad.abs().sum() > 0


@pytest.mark.parametrize("detector", [False, True])
def test_a_victim_on_another_device_gets_a_copy_and_returns_to_the_images_device(
    monkeypatch: pytest.MonkeyPatch, detector: bool
) -> None:
    victim = _TinyDetector() if detector else _Tiny()
    images = torch.rand(2, 3, 16, 16, requires_grad=True)
    reference = victim(images)
    want = reference.class_probs if detector else reference
    want_grad = torch.autograd.grad(want[:, 0].sum(), images)[0]
    # Pretend the network lives elsewhere: the images must then be copied (a new tensor) and the outputs and the
    # input gradient come back to the images' device with the same values.
    moved: list[torch.device] = []
    original_to = Tensor.to

    def spy_to(self: Tensor, *args: object, **kwargs: object) -> Tensor:
        out = original_to(self, *args, **kwargs)
        moved.append(out.device)
        return out

    monkeypatch.setattr(type(victim), "device", property(lambda self: torch.device("meta")))
    monkeypatch.setattr(Tensor, "to", lambda self, *a, **k: spy_to(self, "cpu"))
    out = victim(images)
    got = out.class_probs if detector else out
    got_grad = torch.autograd.grad(got[:, 0].sum(), images)[0]
    assert len(moved) == (4 if detector else 2), "images there, each output back"
    assert got.device == images.device and got_grad.device == images.device
    torch.testing.assert_close(got, want)
    torch.testing.assert_close(got_grad, want_grad)
