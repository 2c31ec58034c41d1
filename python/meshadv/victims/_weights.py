"""Reading weight files and checking devices before a victim is built, with errors that name the file.

``torch.load`` of a garbage, truncated or empty file raises ``UnpicklingError``/``EOFError``/``RuntimeError``
from deep inside torch; a file carrying a pickled object (not only tensors) is refused by ``weights_only=True``.
:func:`read_torch_state` turns each into a ``ValueError`` that names the file and says what is wrong, and
:func:`check_device` refuses ``device="cuda"`` on a machine without CUDA before any weights are read.
"""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path
from typing import Any, Union

import torch

__all__ = ["check_device", "read_torch_state"]

_EXPECTED = "expected a state_dict saved with torch.save(model.state_dict(), path)"


def check_device(device: Union[str, torch.device]) -> torch.device:
    """Return ``device`` as a ``torch.device`` after checking this machine has it.

    Raises:
        TypeError: ``device`` is not a string or ``torch.device``.
        ValueError: an unknown device string, or a CUDA/MPS device this machine does not have (naming what
            is available).
    """
    if not isinstance(device, (str, torch.device)):
        raise TypeError(f"device must be a string such as 'cpu' or 'cuda:0', got {type(device).__name__}")
    try:
        dev = torch.device(device)
    except RuntimeError as exc:
        raise ValueError(f"device {device!r} is not a torch device ({exc})") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"device {str(device)!r} was asked for but CUDA is not available here; use device='cpu'")
        count = torch.cuda.device_count()
        if dev.index is not None and dev.index >= count:
            raise ValueError(f"device {str(device)!r} does not exist: this machine has {count} CUDA device(s)")
    elif dev.type == "mps" and not (hasattr(torch.backends, "mps") and torch.backends.mps.is_available()):
        raise ValueError(f"device {str(device)!r} was asked for but MPS is not available here; use device='cpu'")
    return dev


def read_torch_state(path: Union[str, Path]) -> Any:
    """Load a file written by ``torch.save`` with ``weights_only=True`` on the CPU.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: ``path`` is not a regular file, is empty, truncated or not a torch file, or carries pickled
            objects other than tensors (refused for safety); the message names the file.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"weights file {path} does not exist")
    if not path.is_file():
        raise ValueError(f"weights {path} is not a regular file")
    size = path.stat().st_size
    if size == 0:
        raise ValueError(f"weights {path} is empty (0 bytes); download or copy it again")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        if "Unsupported global" in str(exc) or "GLOBAL" in str(exc):
            raise ValueError(
                f"weights {path} carries pickled Python objects, not only tensors; refusing to load it "
                "(weights_only=True). Re-save it with torch.save(model.state_dict(), path)"
            ) from None
        raise ValueError(
            f"weights {path} is not a torch weights file, or is corrupted (the tensor-only unpickler refused it); "
            f"{_EXPECTED}"
        ) from None
    except (EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"weights {path} is truncated ({size} bytes; {type(exc).__name__}); copy it again") from None
    except (RuntimeError, ValueError, OSError, AttributeError, KeyError, IndexError) as exc:
        if "central directory" in str(exc) or "failed reading zip archive" in str(exc):
            raise ValueError(f"weights {path} is truncated or corrupted ({size} bytes); copy it again") from None
        raise ValueError(
            f"weights {path} cannot be read as a torch file ({type(exc).__name__}: {exc}); {_EXPECTED}"
        ) from None
