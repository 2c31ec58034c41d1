"""A contact sheet of rendering-set images: one row per class, labelled, written atomically as PNG."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Union

import numpy as np
import torch

__all__ = ["contact_sheet"]

LABEL_WIDTH = 90


def contact_sheet(rows: Mapping[str, torch.Tensor], path: Union[str, Path], tile: int = 112) -> Path:
    """Write a grid of images, row ``name`` holding ``rows[name]`` (``(N, 3, H, W)`` in ``[0, 1]``), as a PNG.

    Args:
        rows: label -> images; rows may hold different numbers of images.
        path: the PNG file (parent folders are created; written atomically).
        tile: side of each tile in pixels.

    Raises:
        ValueError: no rows, or an image batch that is not ``(N, 3, H, W)``.
    """
    from PIL import Image, ImageDraw

    from meshadv.util.png import save_png

    if not rows:
        raise ValueError("rows must not be empty")
    columns = 0
    for name, images in rows.items():
        if images.dim() != 4 or images.shape[1] != 3:
            raise ValueError(f"rows[{name!r}] must have shape (N, 3, H, W), got {tuple(images.shape)}")
        columns = max(columns, images.shape[0])
    sheet = Image.new("RGB", (LABEL_WIDTH + columns * tile, len(rows) * tile), "white")
    draw = ImageDraw.Draw(sheet)
    for r, (name, images) in enumerate(rows.items()):
        draw.text((4, r * tile + tile // 2 - 6), name, fill="black")
        for c, image in enumerate(images):
            arr = (image.detach().float().clamp(0, 1) * 255).round().to(torch.uint8).permute(1, 2, 0).numpy()
            pil = Image.fromarray(np.ascontiguousarray(arr)).resize((tile, tile), Image.BILINEAR)
            sheet.paste(pil, (LABEL_WIDTH + c * tile, r * tile))
    return save_png(sheet, path)
