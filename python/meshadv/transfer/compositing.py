"""What the attack optimised, rendered by Mitsuba: the scene under the *estimated* camera and lights, and its
composite over the background photo (the black-box pipeline's diagnostic of renderer vs parameter mismatch)."""

from __future__ import annotations

from typing import Any

import torch

from meshadv.transfer.hidden import HiddenScene
from meshadv.transfer.render import MitsubaImage
from meshadv.transfer.spec import SceneSpec, scene_spec

__all__ = ["composite", "estimated_view_spec"]


def estimated_view_spec(mesh: Any, record: dict[str, Any], hidden: HiddenScene, *, seed: int = 0) -> SceneSpec:
    """Mitsuba's scene of what the attack optimised: ``mesh`` under the *estimated* camera and lights.

    Directional lights and a constant ambient (no environment map, no base scene), direct light only
    (``max_depth = 2``), black background: composite the result over the background photo with its alpha
    (:func:`composite`). Comparing this render with meshadv's separates the renderer mismatch (anti-aliasing,
    Monte-Carlo noise, shadows, ambient occlusion) from the parameter mismatch (estimated vs true camera and lights).

    Args:
        mesh: the object (or the merged known objects) in world space.
        record: the estimated view (``ViewSet.to_records()[0]``).
        hidden: the hidden world (for the image size and samples per pixel).
        seed: Mitsuba sampler seed.

    Returns:
        The scene spec.
    """
    return scene_spec(mesh, record, lights=record, image_size=hidden.image_size, spp=hidden.spp, max_depth=2,
                      background=(0.0, 0.0, 0.0), seed=seed)


def composite(image: MitsubaImage, background: torch.Tensor) -> torch.Tensor:
    """A Mitsuba render made over black (premultiplied by its alpha) composited over a background.

    Args:
        image: the render (its ``alpha`` is the coverage).
        background: ``(3, H, W)`` tensor in ``[0, 1]``.

    Returns:
        ``(3, H, W)`` float32 ``clamp(rgb + (1 - alpha) * background, 0, 1)``.

    Raises:
        TypeError: ``background`` is not a tensor.
        ValueError: the background's shape does not match the image.
    """
    if not isinstance(background, torch.Tensor):
        raise TypeError(f"background must be a (3, H, W) torch tensor, got {type(background).__name__}")
    rgb = torch.from_numpy(image.chw())
    if tuple(background.shape) != tuple(rgb.shape):
        raise ValueError(f"background {tuple(background.shape)} must match the image {tuple(rgb.shape)}")
    alpha = torch.from_numpy(image.alpha)[None]
    return (rgb + (1.0 - alpha) * background.to(rgb.dtype)).clamp(0.0, 1.0)
