"""Allocator policy for the ``meshadv`` command: keep large freed blocks in the process instead of unmapping them.

An attack step allocates the same large buffers every step (the victim's activations, the renderer's images and
cotangents, tens of MB each). glibc serves blocks above its mmap threshold with a fresh ``mmap`` and unmaps them on
``free``, and trims the heap top back to the kernel, so every step may fault the same memory in again (system
time; ``benchmarks/RESULTS.md``, "Attack step split"). :func:`tune_allocator` raises the mmap threshold to glibc's
maximum (32 MiB on 64-bit) and turns trimming off, the same as
``GLIBC_TUNABLES=glibc.malloc.mmap_threshold=33554432:glibc.malloc.trim_threshold=...``. The price is that the
process keeps its peak heap until it exits.

It is a process-wide policy, so the library never applies it on import: the ``meshadv`` command does, first thing,
and a program of your own may call :func:`tune_allocator`. ``MESHADV_MALLOC_TUNING=0`` turns it off. On a C
library other than glibc (musl, macOS, Windows) it does nothing.

Imports nothing of meshadv (a leaf module) and does not import torch.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import platform

__all__ = ["TUNING_ENV_VAR", "MMAP_THRESHOLD", "tune_allocator"]

#: Set to ``0`` to leave the C allocator's defaults alone.
TUNING_ENV_VAR = "MESHADV_MALLOC_TUNING"
#: The mmap threshold set (bytes): glibc's largest accepted value on 64-bit (``DEFAULT_MMAP_THRESHOLD_MAX``).
MMAP_THRESHOLD = 32 * 1024 * 1024

_M_TRIM_THRESHOLD = -1  # glibc <malloc.h>
_M_MMAP_THRESHOLD = -3
_NO_TRIM = 2**31 - 1  # the largest int: mallopt takes an int


def tune_allocator() -> bool:
    """Raise glibc's mmap threshold and turn heap trimming off for this process (see the module docstring).

    Returns:
        True when both settings were applied; False when turned off by ``$MESHADV_MALLOC_TUNING=0``, when the C
        library is not glibc, or when glibc refused a setting.
    """
    if os.environ.get(TUNING_ENV_VAR, "").strip() == "0":
        return False
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, _NO_TRIM))
