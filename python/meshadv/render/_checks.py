"""Small argument checks and coercions shared by the render modules."""

from __future__ import annotations

from typing import Any, Optional

import torch


def require_instance(value: Any, cls: type, name: str) -> None:
    """Raise ``ValueError`` naming ``name`` when ``value`` is not an instance of ``cls``.

    The project rule is that bad user input raises ``ValueError`` naming the argument (also for wrong types).
    """
    if not isinstance(value, cls):
        raise ValueError(f"{name} must be a {cls.__name__}, got {type(value).__name__}")  # noqa: TRY004


def as_float_tensor(
    value: Any, name: str, dtype: Optional[torch.dtype] = None, device: Optional[torch.device] = None
) -> torch.Tensor:
    """Convert ``value`` to a finite floating tensor, keeping autograd history when it already is a tensor.

    Raises:
        ValueError: ``value`` (named ``name`` in the message) is not numeric, or not finite.
    """
    if isinstance(value, torch.Tensor):
        t = value
        if not t.is_floating_point():
            t = t.to(dtype or torch.float32)
        elif dtype is not None and t.dtype != dtype:
            t = t.to(dtype)
        if device is not None and t.device != device:
            t = t.to(device)
    else:
        try:
            t = torch.as_tensor(value, dtype=dtype or torch.float32, device=device)
        except (TypeError, ValueError, RuntimeError) as exc:
            raise ValueError(f"{name} must be a number, a sequence of numbers or a tensor, got {value!r}") from exc
    if not torch.isfinite(t.detach()).all():
        raise ValueError(f"{name} must be finite, got {t.detach().cpu().tolist()}")
    return t
