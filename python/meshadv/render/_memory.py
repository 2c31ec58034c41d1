"""Memory estimates for the native render ops, checked before anything large is allocated.

A render far larger than the machine can hold would abort the whole Python process inside the native code
("memory allocation of 4294967296 bytes failed"); :func:`check_memory` raises a ``MemoryError`` with the figures
instead, while nothing has been allocated yet.
"""

from __future__ import annotations

import resource
from typing import Optional

__all__ = ["available_bytes", "check_memory", "estimate_forward_bytes"]


def estimate_forward_bytes(batch: int, height: int, width: int, channels: int, verts: int, faces: int) -> int:
    """Bytes the native forward pass allocates for ``batch`` images of ``height x width`` with ``channels``.

    Per pixel: the float64 depth buffer (8), the int32 face-index map (4), the float32 depth (4), the float32
    image (4 per channel) and one float32 copy of the image on the way back to torch; per face and vertex a
    few hundred bytes of setup.
    """
    pixels = batch * height * width
    return pixels * (16 + 8 * channels) + batch * (faces * 256 + verts * 32)


def _vm_size_bytes() -> Optional[int]:
    """The process's current virtual memory size, from ``/proc/self/status`` (None where unavailable)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _meminfo_available_bytes() -> Optional[int]:
    """``MemAvailable + SwapFree`` from ``/proc/meminfo`` (None where unavailable)."""
    fields = {}
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                key, _, rest = line.partition(":")
                if key in ("MemAvailable", "SwapFree"):
                    fields[key] = int(rest.split()[0]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    if "MemAvailable" not in fields:
        return None
    return fields["MemAvailable"] + fields.get("SwapFree", 0)


def available_bytes() -> Optional[int]:
    """Bytes a new allocation can still take: the smaller of free RAM and the address-space limit's headroom.

    Returns ``None`` when neither figure can be read (then no check is made).
    """
    limits = []
    ram = _meminfo_available_bytes()
    if ram is not None:
        limits.append(ram)
    soft, _hard = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        used = _vm_size_bytes()
        if used is not None:
            limits.append(max(soft - used, 0))
    return min(limits) if limits else None


def check_memory(needed: int, what: str) -> None:
    """Raise ``MemoryError`` when ``needed`` bytes exceed what the machine (or ``ulimit -v``) can still give.

    Raises:
        MemoryError: the message gives both figures in GiB and names ``what`` (e.g. ``"render"``).
    """
    avail = available_bytes()
    if avail is not None and needed > avail:
        raise MemoryError(
            f"{what} needs about {needed / 2**30:.2f} GiB but only {avail / 2**30:.2f} GiB is available; "
            "use a smaller image_size, antialias or batch"
        )
