"""Small argument checks and coercions shared by the render modules."""

from __future__ import annotations

from typing import Any, Optional

import numpy as np
import torch

from .. import _validate


def require_instance(value: Any, cls: type, name: str) -> None:
    """Raise ``TypeError`` naming ``name`` when ``value`` is not an instance of ``cls``.

    The project rule (see :mod:`meshadv._validate`): wrong types raise ``TypeError``, bad values ``ValueError``.
    """
    if not isinstance(value, cls):
        raise TypeError(f"{name} must be a {cls.__name__}, got {type(value).__name__}")


def check_faces(faces: Any, num_vertices: int) -> torch.Tensor:
    """Check that ``faces`` is a non-empty ``(M, 3)`` integer tensor of indices into ``num_vertices`` vertices.

    Returns:
        ``faces`` itself (any integer dtype; callers convert it).

    Raises:
        TypeError: ``faces`` is not a tensor.
        ValueError: not an integer dtype, not of shape ``(M, 3)``, no faces, or an index outside
            ``[0, num_vertices)``; each message starts with ``faces``.
    """
    require_instance(faces, torch.Tensor, "faces")
    if faces.is_floating_point() or faces.is_complex() or faces.dtype == torch.bool:
        raise ValueError(f"faces must be an integer tensor, got {faces.dtype}")
    if faces.dim() != 2 or faces.shape[1] != 3:
        raise ValueError(f"faces must have shape (M,3), got {tuple(faces.shape)}")
    if faces.shape[0] == 0:
        raise ValueError("faces is empty (M = 0 triangles)")
    n = num_vertices
    fmin, fmax = int(faces.min()), int(faces.max())
    if fmin < 0 or fmax >= n:
        raise ValueError(f"faces holds vertex indices in [{fmin}, {fmax}] but must be in [0, {n - 1}] (N = {n})")
    return faces


def _is_complex(value: Any) -> bool:
    """True when ``value`` (a number, array or nested sequence) holds complex numbers."""
    if isinstance(value, complex):
        return True
    try:
        return bool(np.iscomplexobj(value))
    except (TypeError, ValueError, RuntimeError):
        return False


def as_float_tensor(
    value: Any, name: str, dtype: Optional[torch.dtype] = None, device: Optional[torch.device] = None
) -> torch.Tensor:
    """Convert ``value`` to a finite floating tensor, keeping autograd history when it already is a tensor.

    Raises:
        TypeError: ``value`` (named ``name`` in the message) is not numeric, or is complex.
        ValueError: ``value`` is not finite.
    """
    if isinstance(value, torch.Tensor):
        if value.is_complex():
            raise TypeError(f"{name} must be real, got a complex tensor ({value.dtype})")
        t = value
        if not t.is_floating_point():
            t = t.to(dtype or torch.float32)
        elif dtype is not None and t.dtype != dtype:
            t = t.to(dtype)
        if device is not None and t.device != device:
            t = t.to(device)
    else:
        if value is None or isinstance(value, (str, bytes)):
            raise TypeError(f"{name} must be a number, a sequence of numbers or a tensor, got {value!r}")
        if _is_complex(value):
            raise TypeError(f"{name} must be real, got complex values {value!r}")
        try:
            t = torch.as_tensor(value, dtype=dtype or torch.float32, device=device)
        except (TypeError, ValueError, RuntimeError) as exc:
            raise TypeError(f"{name} must be a number, a sequence of numbers or a tensor, got {value!r}") from exc
    if not torch.isfinite(t.detach()).all():
        raise ValueError(f"{name} must be finite, got {t.detach().cpu().tolist()}")
    return t


def batch_selector(index: Any, batch: int, what: str, device: torch.device) -> slice | torch.Tensor:
    """Turn a batch index (int, slice, sequence of ints, integer or boolean tensor) into a slice or long tensor.

    An integer keeps a batch of one (a slice). The result never selects zero items.

    Raises:
        TypeError: ``index`` is not an int, slice, sequence of ints or integer/boolean tensor (e.g. floats).
        IndexError: an index is outside ``[-batch, batch)`` or a boolean mask has the wrong length.
        ValueError: the selection is empty.
    """
    if _validate_is_int(index):
        i = _validate.index(f"{what} index", index, batch)
        return slice(i, i + 1)
    if isinstance(index, slice):
        if len(range(*index.indices(batch))) == 0:
            raise ValueError(f"{what} index {index} selects no items of a batch of {batch}")
        return index
    if isinstance(index, (str, bytes)) or index is None:
        raise TypeError(f"{what} index must be an int, a slice or a sequence of ints, got {index!r}")
    try:
        t = index if isinstance(index, torch.Tensor) else torch.as_tensor(index)
    except (TypeError, ValueError, RuntimeError) as exc:
        raise TypeError(f"{what} index must be an int, a slice or a sequence of ints, got {index!r}") from exc
    if t.numel() == 0:
        raise ValueError(f"{what} index selects no items (an empty selection)")
    if t.dtype == torch.bool:
        if t.shape != (batch,):
            raise IndexError(f"{what} boolean mask must have shape ({batch},), got {tuple(t.shape)}")
        t = torch.nonzero(t).flatten()
    elif t.is_floating_point() or t.is_complex():
        raise TypeError(f"{what} index must hold integers, got {t.dtype}")
    t = t.reshape(-1).to(torch.long)
    if t.numel() == 0:
        raise ValueError(f"{what} index selects no items (an empty selection)")
    if bool(((t < -batch) | (t >= batch)).any()):
        raise IndexError(f"{what} index {t.tolist()} out of range for batch size {batch}")
    return torch.remainder(t, batch).to(device)


def _validate_is_int(value: Any) -> bool:
    """True for Python/NumPy integers (not bool)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)
