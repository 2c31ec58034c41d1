"""Differentiable input preprocessing for victims (resize + normalisation) and photo loading helpers.

Every victim owns a :class:`Preprocess` so an attack can feed it a rendered ``[0, 1]`` image of any size and receive
gradients with respect to that image.

Example:
    >>> import torch
    >>> pre = Preprocess((224, 224), mean=(0.485, 0.456, 0.406), std=(0.229, 0.224, 0.225))
    >>> pre(torch.rand(2, 3, 100, 150)).shape
    torch.Size([2, 3, 224, 224])
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from meshadv.victims.victim import check_images

__all__ = ["IMAGENET_MEAN", "IMAGENET_STD", "Preprocess", "center_crop", "image_to_tensor", "load_image"]

#: torchvision's ImageNet normalisation (applied to [0, 1] images).
IMAGENET_MEAN: tuple[float, float, float] = (0.485, 0.456, 0.406)
IMAGENET_STD: tuple[float, float, float] = (0.229, 0.224, 0.225)


class Preprocess(nn.Module):
    """Resize to ``size`` (bilinear, antialiased when shrinking) then ``(x - mean) / std`` per channel.

    Args:
        size: ``(H, W)`` the network expects.
        mean: per-channel mean (3 values) in ``[0, 1]`` units.
        std: per-channel standard deviation (3 positive values) in ``[0, 1]`` units.

    Shape:
        - input: ``(B, 3, H, W)`` floats in ``[0, 1]``.
        - output: ``(B, 3, *size)``.

    Raises:
        ValueError: ``size`` not two positive integers, ``mean``/``std`` not three values, or a non-positive ``std``.
    """

    def __init__(self, size: tuple[int, int], mean: Sequence[float], std: Sequence[float]) -> None:
        super().__init__()
        if len(size) != 2 or min(int(size[0]), int(size[1])) < 1:
            raise ValueError(f"size must be two positive integers (H, W), got {size}")
        if len(mean) != 3 or len(std) != 3:
            raise ValueError(f"mean and std must have 3 values each, got {len(mean)} and {len(std)}")
        if min(std) <= 0:
            raise ValueError(f"std must be positive, got {tuple(std)}")
        self.size = (int(size[0]), int(size[1]))
        self.register_buffer("mean", torch.tensor(mean, dtype=torch.float32).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(std, dtype=torch.float32).view(1, 3, 1, 1), persistent=False)

    def forward(self, images: Tensor) -> Tensor:
        """Resize and normalise ``images`` (differentiable)."""
        check_images(images)
        if tuple(images.shape[-2:]) != self.size:
            shrinking = images.shape[-2] > self.size[0] or images.shape[-1] > self.size[1]
            images = nn.functional.interpolate(
                images, size=self.size, mode="bilinear", align_corners=False, antialias=shrinking
            )
        return (images - self.mean.to(images.dtype)) / self.std.to(images.dtype)


def image_to_tensor(image: np.ndarray | object) -> Tensor:
    """Convert an ``(H, W, 3)`` uint8 / float array or a PIL image to a ``(1, 3, H, W)`` float tensor in ``[0, 1]``.

    Args:
        image: RGB image; uint8 values are divided by 255, floats are taken as already in ``[0, 1]``.

    Returns:
        float32 ``(1, 3, H, W)``.

    Raises:
        ValueError: not an ``(H, W, 3)`` (or ``(H, W, 4)``, alpha dropped) image.
    """
    array = np.asarray(image)
    if array.ndim != 3 or array.shape[2] not in (3, 4):
        raise ValueError(f"image must have shape (H, W, 3), got {array.shape}")
    array = array[..., :3]
    if array.dtype == np.uint8:
        array = array.astype(np.float32) / 255.0
    return torch.from_numpy(np.ascontiguousarray(array, dtype=np.float32)).permute(2, 0, 1).unsqueeze(0)


def load_image(path: str | Path) -> Tensor:
    """Read an image file (any format Pillow reads) as a ``(1, 3, H, W)`` float tensor in ``[0, 1]``.

    Args:
        path: image file.

    Raises:
        FileNotFoundError: ``path`` does not exist.
    """
    from PIL import Image

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path {path} does not exist")
    with Image.open(path) as img:
        return image_to_tensor(img.convert("RGB"))


def center_crop(images: Tensor, fraction: float = 0.875) -> Tensor:
    """Crop the central square covering ``fraction`` of the shorter side (the usual ImageNet evaluation crop).

    Args:
        images: ``(B, C, H, W)``.
        fraction: in ``(0, 1]``.

    Returns:
        ``(B, C, s, s)`` with ``s = round(fraction * min(H, W))``.

    Raises:
        ValueError: ``fraction`` outside ``(0, 1]``.
    """
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], got {fraction}")
    height, width = images.shape[-2:]
    side = max(1, round(fraction * min(height, width)))
    top = (height - side) // 2
    left = (width - side) // 2
    return images[..., top : top + side, left : left + side]
