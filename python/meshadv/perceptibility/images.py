"""How alike the benign and the adversarial renders look: SSIM (Wang et al., 2004) over the object's part of each image.

:func:`render_ssim` compares pairs of renders with scikit-image's ``structural_similarity`` (its defaults: a 7 x 7
uniform window, ``K1 = 0.01``, ``K2 = 0.03``, data range 1, channels compared separately and averaged). Given the
renders' coverage masks, each pair is first cropped to the bounding box of the union of both masks (grown by
:data:`CROP_MARGIN` pixels), so a white background the object leaves untouched does not pull the value up towards 1.

Example:
    >>> import torch
    >>> a = torch.full((1, 3, 16, 16), 0.5); b = torch.full((1, 3, 16, 16), 0.25)
    >>> round(float(render_ssim(a, b)[0]), 4)            # constant images: (2ab + C1) / (a^2 + b^2 + C1)
    0.8001
"""

from __future__ import annotations

from typing import Optional

import torch
from torch import Tensor

__all__ = ["render_ssim", "CROP_MARGIN", "SSIM_WINDOW"]

#: Pixels added on every side of the masks' bounding box before comparing.
CROP_MARGIN = 4
#: Side of scikit-image's SSIM window (its default); a crop is never smaller than this.
SSIM_WINDOW = 7


def _crop_box(mask: Tensor, height: int, width: int) -> tuple[int, int, int, int]:
    """``(top, bottom, left, right)`` of the ``(H, W)`` bool ``mask``'s bounding box grown by :data:`CROP_MARGIN`
    and to at least :data:`SSIM_WINDOW` per side, inside the image; the whole image when the mask is empty."""
    rows, cols = torch.nonzero(mask.any(dim=1)).flatten(), torch.nonzero(mask.any(dim=0)).flatten()
    if rows.numel() == 0:
        return 0, height, 0, width
    box = []
    for lo, hi, size in ((int(rows[0]), int(rows[-1]) + 1, height), (int(cols[0]), int(cols[-1]) + 1, width)):
        lo, hi = max(0, lo - CROP_MARGIN), min(size, hi + CROP_MARGIN)
        while hi - lo < min(SSIM_WINDOW, size):
            lo, hi = max(0, lo - 1), min(size, hi + 1)
        box += [lo, hi]
    return box[0], box[1], box[2], box[3]


def render_ssim(benign: Tensor, adversarial: Tensor, benign_alpha: Optional[Tensor] = None,
                adversarial_alpha: Optional[Tensor] = None) -> Tensor:
    """SSIM of each benign / adversarial render pair, in ``[-1, 1]`` (1: identical).

    Args:
        benign: ``(V, 3, H, W)`` renders in ``[0, 1]`` (``H, W >= 7``).
        adversarial: ``(V, 3, H, W)`` renders of the same views.
        benign_alpha: optional ``(V, 1, H, W)`` or ``(V, H, W)`` coverage of the benign renders; with
            ``adversarial_alpha``, each pair is cropped to the union of both (see the module docstring).
        adversarial_alpha: the adversarial renders' coverage (given together with ``benign_alpha``).

    Returns:
        float64 ``(V,)``.

    Raises:
        ValueError: shapes that disagree, images smaller than the window, or only one of the masks.
    """
    from skimage.metrics import structural_similarity

    if benign.dim() != 4 or benign.shape != adversarial.shape:
        raise ValueError(f"benign {tuple(benign.shape)} and adversarial {tuple(adversarial.shape)} must both be "
                         "(V, C, H, W)")
    views, _, height, width = benign.shape
    if min(height, width) < SSIM_WINDOW:
        raise ValueError(f"renders must be at least {SSIM_WINDOW} pixels per side, got {height} x {width}")
    if (benign_alpha is None) != (adversarial_alpha is None):
        raise ValueError("give both benign_alpha and adversarial_alpha, or neither")
    union = None
    if benign_alpha is not None and adversarial_alpha is not None:
        union = (benign_alpha.reshape(views, height, width) > 0) | (adversarial_alpha.reshape(views, height, width) > 0)
    first = benign.detach().double().clamp(0, 1).cpu().numpy()
    second = adversarial.detach().double().clamp(0, 1).cpu().numpy()
    values = []
    for v in range(views):
        top, bottom, left, right = (0, height, 0, width) if union is None else _crop_box(union[v].cpu(), height, width)
        values.append(structural_similarity(first[v, :, top:bottom, left:right], second[v, :, top:bottom, left:right],
                                            data_range=1.0, channel_axis=0))
    return torch.tensor(values, dtype=torch.float64)
