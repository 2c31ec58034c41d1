"""Save an image as an 8-bit RGB PNG, atomically (:mod:`meshadv.util.atomic`); read and add a PNG's text chunks.

Accepts what the package produces: a ``(3, H, W)`` or ``(1, 3, H, W)`` torch tensor in ``[0, 1]``, a ``(H, W, 3)``
float array in ``[0, 1]`` or uint8 array, or a PIL image. Floats are clipped to ``[0, 1]`` and rounded to the
nearest 8-bit value.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, Mapping, Union

import numpy as np

from meshadv.util.atomic import atomic_path

__all__ = ["to_uint8_hwc", "save_png", "png_text", "add_png_text"]


def to_uint8_hwc(image: Any) -> np.ndarray:
    """The image as a ``(H, W, 3)`` uint8 array (see the module docstring for accepted inputs).

    Raises:
        ValueError: a shape that is not one RGB image.
    """
    if hasattr(image, "detach"):  # torch tensor, channels first
        if image.dim() == 4 and image.shape[0] == 1:
            image = image[0]
        if image.dim() != 3 or image.shape[0] != 3:
            raise ValueError(f"image must have shape (3, H, W), got {tuple(image.shape)}")
        image = image.detach().float().cpu().permute(1, 2, 0).numpy()
    array = np.asarray(image)
    if array.ndim != 3 or array.shape[2] != 3:
        raise ValueError(f"image must have shape (H, W, 3), got {array.shape}")
    if array.dtype != np.uint8:
        array = np.round(np.clip(np.nan_to_num(array.astype(np.float64)), 0.0, 1.0) * 255.0).astype(np.uint8)
    return np.ascontiguousarray(array)


def save_png(image: Any, path: Union[str, Path]) -> Path:
    """Write ``image`` to ``path`` as PNG atomically (creating the folder); returns the path.

    Raises:
        ValueError: not one RGB image.
    """
    from PIL import Image

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    pil = image if isinstance(image, Image.Image) else Image.fromarray(to_uint8_hwc(image))
    with atomic_path(path, suffix=".png") as tmp:
        pil.save(tmp, format="PNG")
    return path


def png_text(path: Union[str, Path]) -> Dict[str, str]:
    """The text chunks of the PNG at ``path`` (``{}`` when there is no such file or it is not a PNG)."""
    from PIL import Image

    try:
        with Image.open(path) as img:
            return dict(getattr(img, "text", {}) or {}) if img.format == "PNG" else {}
    except (OSError, ValueError):
        return {}


def add_png_text(path: Union[str, Path], items: Mapping[str, str]) -> Path:
    """Rewrite the PNG at ``path`` atomically with the text chunks ``items`` (replacing those of the same keys, the
    others kept; the pixels are unchanged); returns the path."""
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    path = Path(path)
    with Image.open(path) as img:
        img.load()
        info = PngInfo()
        for key, value in {**dict(getattr(img, "text", {}) or {}), **dict(items)}.items():
            info.add_text(key, value)
        with atomic_path(path, suffix=".png") as tmp:
            img.save(tmp, format="PNG", pnginfo=info)
    return path
