"""Draw detections on an image and save it as PNG (atomically)."""

from __future__ import annotations

import torch
from PIL import Image, ImageDraw

from meshadv.util.png import to_uint8_hwc
from meshadv.victims.victim import Detections

_PALETTE = [(230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180), (70, 240, 240)]


def to_pil(image: torch.Tensor) -> Image.Image:
    """Convert a (3, H, W) or (1, 3, H, W) tensor in [0, 1] to a PIL RGB image."""
    if image.dim() == 4 and image.shape[0] != 1:
        raise ValueError(f"image must hold a single image, got batch {image.shape[0]}")
    return Image.fromarray(to_uint8_hwc(image))


def draw_detections(image: torch.Tensor, detections: Detections) -> Image.Image:
    """Return ``image`` as a PIL image with each detection's box and ``label score`` drawn on it."""
    pil = to_pil(image)
    draw = ImageDraw.Draw(pil)
    width, height = pil.size
    for k, (box, score, label) in enumerate(
        zip(detections.boxes.tolist(), detections.scores.tolist(), detections.names())
    ):
        color = _PALETTE[k % len(_PALETTE)]
        x1, y1, x2, y2 = box[0] * width, box[1] * height, box[2] * width, box[3] * height
        draw.rectangle([x1, y1, x2, y2], outline=color, width=2)
        draw.text((x1 + 3, y1 + 2), f"{label} {score:.2f}", fill=color)
    return pil
