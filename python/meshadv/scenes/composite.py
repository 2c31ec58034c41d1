"""Render an object over a real photograph: alpha compositing and a simple sky-light estimate from the photo."""

from __future__ import annotations

from pathlib import Path
from typing import Tuple, Union

import numpy as np
import torch
from PIL import Image


def load_photo(path: Union[str, Path], size: Tuple[int, int] | None = None) -> torch.Tensor:
    """Load an RGB photograph as a (1, 3, H, W) float tensor in [0, 1].

    Args:
        path: image file (JPEG, PNG, ...).
        size: optional (width, height) to resize to (bilinear).

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: the file is not a readable image.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"photo not found: {path}")
    try:
        with Image.open(path) as img:
            img = img.convert("RGB")
            if size is not None:
                img = img.resize(size, Image.BILINEAR)
            array = np.asarray(img, dtype=np.float32) / 255.0
    except OSError as exc:
        raise ValueError(f"photo {path} is not a readable image: {exc}") from exc
    return torch.from_numpy(array).permute(2, 0, 1).unsqueeze(0).contiguous()


def composite_over_photo(image: torch.Tensor, alpha: torch.Tensor, photo: torch.Tensor) -> torch.Tensor:
    """Alpha-composite a render over a photo: ``alpha * image + (1 - alpha) * photo``.

    Pixels where ``alpha == 0`` are exactly the photo's. Gradients flow into ``image`` and ``alpha``.

    Shape:
        image: (B, 3, H, W); alpha: (B, 1, H, W); photo: (1 or B, 3, H, W). Returns (B, 3, H, W).
    """
    if image.dim() != 4 or image.shape[1] != 3:
        raise ValueError(f"image must have shape (B, 3, H, W), got {tuple(image.shape)}")
    if alpha.shape != (image.shape[0], 1, image.shape[2], image.shape[3]):
        raise ValueError(
            f"alpha must have shape {(image.shape[0], 1) + tuple(image.shape[2:])}, got {tuple(alpha.shape)}"
        )
    if photo.dim() != 4 or photo.shape[1:] != image.shape[1:]:
        raise ValueError(f"photo must have shape (1|B, 3, H, W) = {tuple(image.shape[1:])}, got {tuple(photo.shape)}")
    photo = photo.to(image.dtype)
    return torch.where(alpha > 0, alpha * image + (1.0 - alpha) * photo, photo)


def estimate_sky_light(photo: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Estimate an outdoor light from a photo: a sky direction, a sun colour and an ambient colour.

    A deliberately simple heuristic: the light comes from above and slightly behind the camera
    (direction (0.3, 1, 0.5) toward the light); its colour is the mean of the brightest 5% of the upper half of
    the photo (the sky), and the ambient is half the photo's mean colour. Good enough to shade an inserted object
    plausibly; pass explicit lights when the scene is known.

    Returns:
        (direction (3,), light colour (3,), ambient (3,)), float32 tensors.
    """
    if photo.dim() != 4 or photo.shape[:2] != (1, 3):
        raise ValueError(f"photo must have shape (1, 3, H, W), got {tuple(photo.shape)}")
    upper = photo[0, :, : photo.shape[2] // 2].reshape(3, -1)
    brightness = upper.mean(0)
    k = max(1, int(0.05 * brightness.numel()))
    top = torch.topk(brightness, k).indices
    sun = upper[:, top].mean(1).clamp(0.2, 1.0)
    ambient = 0.5 * photo[0].reshape(3, -1).mean(1)
    direction = torch.tensor([0.3, 1.0, 0.5])
    return direction / direction.norm(), sun.float(), ambient.float()
