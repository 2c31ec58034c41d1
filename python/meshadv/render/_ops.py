"""Small tensor helpers shared by the render modules."""

from __future__ import annotations

import torch


def small_matmul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a @ b`` for a tiny inner dimension, as a sum of broadcast products.

    Batched ``torch.matmul`` with a 3-wide inner dimension can be pathologically slow on CPU (tens of ms for a few
    hundred points, dominated by threading overhead); this form is a handful of fused element-wise ops.

    Args:
        a: (B,N,k) tensor.
        b: (B,k,m) tensor (B may be 1 on either side).

    Returns:
        (B,N,m) product.
    """
    out = a[..., 0:1] * b[:, None, 0, :]
    for i in range(1, a.shape[-1]):
        out = out + a[..., i : i + 1] * b[:, None, i, :]
    return out
