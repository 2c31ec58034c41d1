"""SSD anchors and box decoding exactly as the TensorFlow Object Detection API builds them.

``ssd_anchor_grid`` reproduces ``anchor_generators/multiple_grid_anchor_generator.create_ssd_anchors`` (the
``ssd_anchor_generator`` config block) and ``decode_boxes`` the ``FasterRcnnBoxCoder`` decoder SSD uses. Boxes here
are normalised to the network input (``[0, 1]`` on both axes, anchors may stick out of it). The aspect ratios are the
model config's ``1, 2, 0.5, 3, 0.3333``; OpenCV's text graph for the same model sizes the ``0.3333`` boxes very
slightly differently (at most 4e-4 of the image), which is why OpenCV's boxes can differ from ours by that much.

Example:
    >>> anchors = ssd_anchor_grid((19, 10, 5, 3, 2, 1))
    >>> anchors.shape
    torch.Size([1917, 4])
"""

from __future__ import annotations

import math
from typing import List, Sequence, Tuple

import torch
from torch import Tensor

__all__ = ["ssd_anchor_grid", "anchors_per_cell", "decode_boxes"]


def _layer_box_specs(
    num_layers: int,
    min_scale: float,
    max_scale: float,
    aspect_ratios: Sequence[float],
    interpolated_scale_aspect_ratio: float,
    reduce_boxes_in_lowest_layer: bool,
) -> List[List[Tuple[float, float]]]:
    """(scale, aspect ratio) of every anchor of a cell, per layer, in TensorFlow's order."""
    scales = [min_scale + (max_scale - min_scale) * i / (num_layers - 1) for i in range(num_layers)] + [1.0]
    specs = []
    for layer, (scale, scale_next) in enumerate(zip(scales[:-1], scales[1:])):
        if layer == 0 and reduce_boxes_in_lowest_layer:
            specs.append([(0.1, 1.0), (scale, 2.0), (scale, 0.5)])
            continue
        layer_specs = [(scale, float(ratio)) for ratio in aspect_ratios]
        if interpolated_scale_aspect_ratio > 0.0:
            layer_specs.append((math.sqrt(scale * scale_next), interpolated_scale_aspect_ratio))
        specs.append(layer_specs)
    return specs


def anchors_per_cell(
    num_layers: int = 6,
    aspect_ratios: Sequence[float] = (1.0, 2.0, 0.5, 3.0, 0.3333),
    reduce_boxes_in_lowest_layer: bool = True,
) -> List[int]:
    """Number of anchors per feature-map cell for each layer (``[3, 6, 6, 6, 6, 6]`` for SSD-MobileNetV2)."""
    specs = _layer_box_specs(num_layers, 0.2, 0.95, aspect_ratios, 1.0, reduce_boxes_in_lowest_layer)
    return [len(s) for s in specs]


def ssd_anchor_grid(
    feature_map_sizes: Sequence[int] = (19, 10, 5, 3, 2, 1),
    min_scale: float = 0.2,
    max_scale: float = 0.95,
    aspect_ratios: Sequence[float] = (1.0, 2.0, 0.5, 3.0, 0.3333),
    interpolated_scale_aspect_ratio: float = 1.0,
    reduce_boxes_in_lowest_layer: bool = True,
) -> Tensor:
    """Anchors of every layer, flattened in the order the box predictors emit them (layer, row, column, anchor).

    Layer ``k`` has scale ``s_k = min + (max - min) k / (L - 1)``; each cell gets one box per aspect ratio ``a``
    (``h = s / sqrt(a)``, ``w = s sqrt(a)``) plus one of scale ``sqrt(s_k s_{k+1})`` (``s_L = 1``). With
    ``reduce_boxes_in_lowest_layer`` the first layer has only ``(0.1, 1), (s_0, 2), (s_0, 0.5)``. Cell ``(i, j)`` of an
    ``n x n`` map is centred at ``((i + 0.5) / n, (j + 0.5) / n)``.

    Args:
        feature_map_sizes: side of each (square) feature map, finest first.
        min_scale: scale of the first layer.
        max_scale: scale of the last layer.
        aspect_ratios: width / height ratios of the regular boxes.
        interpolated_scale_aspect_ratio: aspect ratio of the extra interpolated-scale box (``<= 0``: none).
        reduce_boxes_in_lowest_layer: use the three fixed boxes on the first layer.

    Returns:
        float32 ``(A, 4)`` anchors as ``(y_center, x_center, height, width)``, normalised.

    Raises:
        ValueError: fewer than two layers, a non-positive feature map size or bad scales.
    """
    sizes = [int(s) for s in feature_map_sizes]
    if len(sizes) < 2:
        raise ValueError(f"feature_map_sizes needs at least 2 layers, got {len(sizes)}")
    if min(sizes) < 1:
        raise ValueError(f"feature_map_sizes must be positive, got {sizes}")
    if not 0.0 < min_scale <= max_scale:
        raise ValueError(
            f"min_scale and max_scale must satisfy 0 < min_scale <= max_scale, got {min_scale}, {max_scale}"
        )
    specs = _layer_box_specs(
        len(sizes), min_scale, max_scale, aspect_ratios, interpolated_scale_aspect_ratio, reduce_boxes_in_lowest_layer
    )
    layers = []
    for size, layer_specs in zip(sizes, specs):
        spec = torch.tensor(layer_specs, dtype=torch.float64)
        heights = spec[:, 0] / spec[:, 1].sqrt()
        widths = spec[:, 0] * spec[:, 1].sqrt()
        centers = (torch.arange(size, dtype=torch.float64) + 0.5) / size
        cy, cx = torch.meshgrid(centers, centers, indexing="ij")
        count = len(layer_specs)
        grid = torch.stack(
            [
                cy[..., None].expand(size, size, count),
                cx[..., None].expand(size, size, count),
                heights.expand(size, size, count),
                widths.expand(size, size, count),
            ],
            dim=-1,
        )
        layers.append(grid.reshape(-1, 4))
    return torch.cat(layers).to(torch.float32)


def decode_boxes(
    rel_codes: Tensor, anchors: Tensor, scale_factors: Tuple[float, float, float, float] = (10.0, 10.0, 5.0, 5.0)
) -> Tensor:
    """Decode SSD box regressions (TF ``FasterRcnnBoxCoder``) into corner boxes.

    ``y = ty / s_y * h_a + y_a``, ``x = tx / s_x * w_a + x_a``, ``h = exp(th / s_h) h_a``, ``w = exp(tw / s_w) w_a``.

    Args:
        rel_codes: ``(..., A, 4)`` regressions ``(ty, tx, th, tw)`` (TensorFlow's order).
        anchors: ``(A, 4)`` anchors ``(y_center, x_center, height, width)``.
        scale_factors: the coder's ``(y, x, height, width)`` scale factors.

    Returns:
        ``(..., A, 4)`` boxes ``(x1, y1, x2, y2)`` (not clipped), differentiable in ``rel_codes``.

    Raises:
        ValueError: shapes that do not match.
    """
    if rel_codes.shape[-1] != 4 or anchors.dim() != 2 or anchors.shape != rel_codes.shape[-2:]:
        raise ValueError(
            f"rel_codes (..., A, 4) and anchors (A, 4) must match, got {tuple(rel_codes.shape)} and "
            f"{tuple(anchors.shape)}"
        )
    anchors = anchors.to(rel_codes.dtype)
    ty, tx, th, tw = rel_codes.unbind(-1)
    ya, xa, ha, wa = anchors.unbind(-1)
    y_center = ty / scale_factors[0] * ha + ya
    x_center = tx / scale_factors[1] * wa + xa
    half_h = 0.5 * torch.exp(th / scale_factors[2]) * ha
    half_w = 0.5 * torch.exp(tw / scale_factors[3]) * wa
    return torch.stack([x_center - half_w, y_center - half_h, x_center + half_w, y_center + half_h], dim=-1)
