"""Tiny differentiable stand-in victims shared by the tests (no weights, exact and fast)."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from meshadv.victims.victim import ClassifierVictim, DetectorOutput, DetectorVictim


class DarkBlobDetector(DetectorVictim):
    """Stand-in detector: a 4x4 grid of cells; a cell's 'blob' score is sigmoid(20 (darkness - 0.3)).

    Darkness is 1 - mean intensity of the cell, so a dark object on a white background is detected where it is.
    The second class 'light' scores bright cells and is never hidden in the tests.
    """

    def __init__(self) -> None:
        super().__init__("dark_blob", (64, 64), ("blob", "light"))

    def forward(self, images: torch.Tensor) -> DetectorOutput:
        x = self.resize(images).mean(dim=1, keepdim=True)
        cells = F.avg_pool2d(x, 16).flatten(1)  # (B, 16)
        dark = torch.sigmoid(20 * ((1 - cells) - 0.3))
        light = torch.sigmoid(20 * (cells - 0.95))
        b = images.shape[0]
        ij = torch.stack(torch.meshgrid(torch.arange(4.0), torch.arange(4.0), indexing="ij"), -1).reshape(16, 2)
        boxes = torch.cat([ij[:, [1, 0]] / 4, (ij[:, [1, 0]] + 1) / 4], dim=1).expand(b, 16, 4)
        return DetectorOutput(boxes=boxes, objectness=None, class_probs=torch.stack([dark, light], dim=-1))


class PooledLinearClassifier(ClassifierVictim):
    """Stand-in ImageNet classifier: a fixed random linear map (seed 0) of the 4x4 average-pooled image.

    Differentiable, deterministic and weight-free, so the attack loop is covered on a bare machine; the logits depend
    smoothly on colours and on where the object covers the image.
    """

    def __init__(self) -> None:
        super().__init__("pooled_linear", (32, 32))
        generator = torch.Generator().manual_seed(0)
        self.register_buffer("weight", torch.randn(1000, 48, generator=generator))
        self.register_buffer("bias", torch.randn(1000, generator=generator) * 0.1)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        x = F.avg_pool2d(self.resize(images), 8).flatten(1)  # (B, 48)
        return x @ self.weight.t() + self.bias


class ColourClassifier(ClassifierVictim):
    """Stand-in ImageNet classifier that reads colour: the logit of ``classes[c]`` is 10 x the mean of channel ``c``
    (red, green, blue), every other logit 0. A flat red image is ``classes[0]``, a flat green one ``classes[1]``, a
    flat blue one ``classes[2]``: the top-1 of a test's images is chosen by their colour.
    """

    def __init__(self, classes: tuple = (404, 895, 340)) -> None:
        super().__init__("colour", (8, 8))
        self.classes = tuple(int(c) for c in classes)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        means = self.resize(images).mean(dim=(2, 3))  # (B, 3)
        logits = torch.zeros(images.shape[0], 1000, dtype=means.dtype, device=means.device)
        return logits.index_copy(1, torch.tensor(self.classes, device=means.device), 10 * means)
