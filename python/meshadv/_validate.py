"""Argument validators shared by the whole package; each raises with the argument's name.

The project's single convention for bad user input:

* ``TypeError`` — the value has the wrong *type*: a string where a number is expected, a float where an
  integer is expected (``1.9`` is never truncated to ``1``, and ``2.0`` is not an integer either), ``bool``
  where a number is expected (``True`` is not ``1``), ``None`` where a value is required, a complex number
  or complex tensor where a real one is expected.
* ``ValueError`` — the type is right but the value is not allowed: out of range, not finite (``nan``,
  ``inf``), an empty sequence, a string that is not one of the options (with a "did you mean" suggestion).
* ``IndexError`` — an index outside ``[-length, length)``.

Every message starts with the argument's name and says what was expected and what was given, e.g.
``steps must be an integer >= 1, got 0``. This module imports nothing of ours, so any module may use it.

Example:
    >>> positive_int("steps", 10)
    10
    >>> choice("kind", "shpae", ("shape", "texture"))
    Traceback (most recent call last):
    ...
    ValueError: kind must be one of 'shape', 'texture', got 'shpae' (did you mean 'shape'?)
"""

from __future__ import annotations

import difflib
import math
import numbers
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, Optional

__all__ = [
    "MAX_SEED",
    "MAX_TEXTURE_COORDINATE",
    "MAX_THREADS",
    "boolean",
    "choice",
    "color",
    "finite_float",
    "index",
    "integer",
    "non_negative_int",
    "num_threads",
    "path",
    "positive_float",
    "positive_int",
    "seed",
    "suggest",
]

#: Largest accepted random seed: seeds must fit a signed 64-bit integer (torch, SQLite, TOML).
MAX_SEED = 2**63 - 1
#: Largest accepted thread count; more threads than this is a mistake on any machine we run on.
MAX_THREADS = 1024
#: Largest accepted magnitude of a texture coordinate: a UV a million tiles away from [0, 1] is a broken file, and
#: texel indices of much larger ones overflow.
MAX_TEXTURE_COORDINATE = 1e6


def _type_name(value: Any) -> str:
    return type(value).__name__


def _is_integer(value: Any) -> bool:
    if isinstance(value, bool) or _is_numpy_bool(value):
        return False
    if isinstance(value, numbers.Integral):
        return True
    # 0-d integer tensors/arrays (torch.tensor(3), np.array(3)) count as integers.
    shape = getattr(value, "shape", None)
    dtype = getattr(value, "dtype", None)
    if shape is not None and tuple(shape) == () and dtype is not None:
        is_fp = getattr(value, "is_floating_point", None)
        if callable(is_fp):  # torch
            return not is_fp() and not value.is_complex() and str(dtype) != "torch.bool"
        return getattr(dtype, "kind", "") in "iu" and getattr(dtype, "kind", "") != ""
    return False


def _is_numpy_bool(value: Any) -> bool:
    dtype = getattr(value, "dtype", None)
    return getattr(value, "shape", None) == () and (getattr(dtype, "kind", "") == "b" or str(dtype) == "torch.bool")


def _range_text(low: Optional[float], high: Optional[float], low_open: bool, high_open: bool) -> str:
    parts = []
    if low is not None:
        parts.append(f"{'>' if low_open else '>='} {low}")
    if high is not None:
        parts.append(f"{'<' if high_open else '<='} {high}")
    return " and ".join(parts)


def _check_range(
    name: str, value: float, what: str, low: Optional[float], high: Optional[float], low_open: bool, high_open: bool
) -> None:
    bad_low = low is not None and (value <= low if low_open else value < low)
    bad_high = high is not None and (value >= high if high_open else value > high)
    if bad_low or bad_high:
        raise ValueError(f"{name} must be {what} {_range_text(low, high, low_open, high_open)}, got {value!r}")


def integer(name: str, value: Any, *, low: Optional[int] = None, high: Optional[int] = None) -> int:
    """Return ``value`` as a Python ``int`` after checking it is an integer in ``[low, high]``.

    Accepts Python and NumPy integers and 0-d integer tensors/arrays; rejects ``bool``, floats (even ``2.0``),
    strings and ``None``.

    Raises:
        TypeError: ``value`` is not an integer.
        ValueError: ``value`` is outside ``[low, high]``.
    """
    if not _is_integer(value):
        raise TypeError(f"{name} must be an integer, got {_type_name(value)} {value!r}")
    v = int(value)
    _check_range(name, v, "an integer", low, high, False, False)
    return v


def positive_int(name: str, value: Any, *, high: Optional[int] = None) -> int:
    """Return ``value`` as an ``int`` ``>= 1`` (and ``<= high`` when given).

    Raises:
        TypeError: ``value`` is not an integer.
        ValueError: ``value < 1`` or ``value > high``.
    """
    return integer(name, value, low=1, high=high)


def non_negative_int(name: str, value: Any, *, high: Optional[int] = None) -> int:
    """Return ``value`` as an ``int`` ``>= 0`` (and ``<= high`` when given).

    Raises:
        TypeError: ``value`` is not an integer.
        ValueError: ``value < 0`` or ``value > high``.
    """
    return integer(name, value, low=0, high=high)


def seed(name: str, value: Any) -> int:
    """Return a random seed as an ``int`` in ``[0, MAX_SEED]`` (a signed 64-bit integer).

    Raises:
        TypeError: ``value`` is not an integer.
        ValueError: ``value`` is negative or does not fit 64 bits.
    """
    return integer(name, value, low=0, high=MAX_SEED)


def num_threads(name: str, value: Any) -> int:
    """Return a thread count in ``[0, MAX_THREADS]``, where ``0`` means "all available cores".

    Raises:
        TypeError: ``value`` is not an integer (``"1"`` and ``1.5`` are refused).
        ValueError: ``value`` is negative or larger than ``MAX_THREADS``.
    """
    return integer(name, value, low=0, high=MAX_THREADS)


def finite_float(
    name: str,
    value: Any,
    *,
    low: Optional[float] = None,
    high: Optional[float] = None,
    low_open: bool = False,
    high_open: bool = False,
) -> float:
    """Return ``value`` as a finite Python ``float`` in the given range.

    Accepts Python/NumPy reals and 0-d real tensors/arrays; rejects ``bool``, strings, complex numbers and ``None``.
    ``low_open``/``high_open`` make the bound strict (``low_open=True`` means ``value > low``).

    Raises:
        TypeError: ``value`` is not a real number.
        ValueError: ``value`` is ``nan``/``inf`` or out of range.
    """
    if isinstance(value, bool) or _is_numpy_bool(value):
        raise TypeError(f"{name} must be a real number, got bool {value!r}")
    if isinstance(value, numbers.Real):
        v = float(value)
    elif getattr(value, "shape", None) is not None and tuple(value.shape) == () and _is_real_0d(value):
        v = float(value.item())
    else:
        raise TypeError(f"{name} must be a real number, got {_type_name(value)} {value!r}")
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v!r}")
    _check_range(name, v, "a number", low, high, low_open, high_open)
    return v


def _is_real_0d(value: Any) -> bool:
    is_complex = getattr(value, "is_complex", None)
    if callable(is_complex):  # torch
        return not is_complex()
    return getattr(getattr(value, "dtype", None), "kind", "") in "iuf" and getattr(value.dtype, "kind", "") != ""


def positive_float(name: str, value: Any, *, high: Optional[float] = None) -> float:
    """Return a finite ``float`` ``> 0`` (and ``<= high`` when given).

    Raises:
        TypeError: ``value`` is not a real number.
        ValueError: ``value`` is not finite or not ``> 0``.
    """
    return finite_float(name, value, low=0.0, low_open=True, high=high)


def boolean(name: str, value: Any) -> bool:
    """Return ``value`` as a ``bool``; only ``bool`` and NumPy/0-d tensor booleans are accepted (not ``0``/``1``).

    Raises:
        TypeError: ``value`` is not a boolean.
    """
    if isinstance(value, bool):
        return value
    if _is_numpy_bool(value):
        return bool(value)
    raise TypeError(f"{name} must be True or False, got {_type_name(value)} {value!r}")


def setting_flag(name: str, value: Any) -> bool:
    """Return a boolean setting read from a file or a stored record (a sweep file, a job spec): only ``true`` /
    ``false`` (a ``bool``), since ``"no"`` or ``0`` would read as a silent choice.

    Raises:
        ValueError: ``value`` is not a ``bool``, naming the setting ``name``.

    Example:
        >>> setting_flag("multiview.benign_correct_only", True)
        True
    """
    if not isinstance(value, bool):
        raise ValueError(f"{name} must be true or false, got {value!r}")
    return value


def suggest(word: str, options: Iterable[str]) -> Optional[str]:
    """Return the option closest to ``word`` (by ``difflib``), or ``None`` when nothing is close.

    Example:
        >>> suggest("image_sise", ["image_size", "supersample"])
        'image_size'
    """
    matches = difflib.get_close_matches(word, list(options), n=1, cutoff=0.6)
    return matches[0] if matches else None


def choice(name: str, value: Any, options: Sequence[str]) -> str:
    """Return ``value`` when it is one of the string ``options``.

    Raises:
        TypeError: ``value`` is not a string.
        ValueError: ``value`` is not one of ``options``; the message suggests the closest option.
    """
    listed = ", ".join(repr(o) for o in options)
    if not isinstance(value, str):
        raise TypeError(f"{name} must be one of {listed}, got {_type_name(value)} {value!r}")
    if value not in options:
        hint = suggest(value, options)
        extra = f" (did you mean {hint!r}?)" if hint is not None else ""
        raise ValueError(f"{name} must be one of {listed}, got {value!r}{extra}")
    return value


def index(name: str, value: Any, length: int) -> int:
    """Return ``value`` as a non-negative index into a sequence of ``length`` items (negative indices wrap).

    Raises:
        TypeError: ``value`` is not an integer.
        IndexError: ``value`` is outside ``[-length, length)``.
    """
    if not _is_integer(value):
        raise TypeError(f"{name} must be an integer index, got {_type_name(value)} {value!r}")
    i = int(value)
    if not -length <= i < length:
        raise IndexError(f"{name} {i} is out of range for length {length}")
    return i + length if i < 0 else i


def path(name: str, value: Any) -> Path:
    """Return ``value`` as a :class:`~pathlib.Path`; only ``str`` and ``os.PathLike`` of ``str`` are paths.

    Raises:
        TypeError: ``value`` is not a ``str`` or ``os.PathLike`` (a ``bytes`` path, a number, ``None``).
    """
    if isinstance(value, str) or (isinstance(value, os.PathLike) and isinstance(os.fspath(value), str)):
        return Path(value)
    raise TypeError(f"{name} must be a path (str or os.PathLike), got {_type_name(value)} {value!r}")


def color(name: str, value: Any) -> "tuple[float, float, float]":
    """Return an RGB colour as 3 floats in ``[0, 1]``.

    Raises:
        TypeError: ``value`` is not a sequence of 3 real numbers (a string such as ``"red"``, ``None``).
        ValueError: not 3 values, or a value is not finite or outside ``[0, 1]``.
    """
    if isinstance(value, (str, bytes)) or not isinstance(value, Iterable):
        raise TypeError(f"{name} must be 3 numbers in [0, 1] (RGB), got {_type_name(value)} {value!r}")
    items = list(value)
    if len(items) != 3:
        raise ValueError(f"{name} must be 3 numbers in [0, 1] (RGB), got {len(items)} values {value!r}")
    return tuple(finite_float(f"{name}[{k}]", c, low=0.0, high=1.0) for k, c in enumerate(items))  # type: ignore
