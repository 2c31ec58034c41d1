"""Pick the best Mitsuba 3 variant that works on this machine.

Mitsuba's ``scalar_rgb`` variant always works on a CPU. ``llvm_ad_rgb`` is much faster (vectorised, JIT-compiled) but
needs a recent LLVM shared library: with an old one (LLVM 15 on Debian 12) the *first render* aborts the whole process
rather than raising. A variant is therefore probed by rendering a tiny scene in a child process; the answer is
remembered for the life of the process.

The environment variable ``MESHADV_MITSUBA_VARIANT`` forces a variant (it is still probed).
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
from typing import Optional, Sequence

#: Environment variable that forces a Mitsuba variant.
VARIANT_ENV_VAR = "MESHADV_MITSUBA_VARIANT"

#: Variants tried in order of preference (fastest first). ``scalar_rgb`` is the safe fallback.
PREFERRED_VARIANTS: tuple[str, ...] = ("llvm_ad_rgb", "scalar_rgb")

_PROBE_SCRIPT = """
import sys
import mitsuba as mi
mi.set_variant(sys.argv[1])
scene = mi.load_dict({
    "type": "scene",
    "integrator": {"type": "path", "max_depth": 2},
    "sensor": {"type": "perspective", "fov": 40,
               "film": {"type": "hdrfilm", "width": 8, "height": 8}},
    "shape": {"type": "sphere", "center": [0, 0, 4], "radius": 1.0},
    "light": {"type": "constant"},
})
image = mi.render(scene, spp=1)
assert image.shape[0] == 8
print("ok")
"""


def mitsuba_available() -> bool:
    """Whether the ``mitsuba`` package is installed (looked up with ``importlib``, without importing it)."""
    try:
        import importlib.util

        return importlib.util.find_spec("mitsuba") is not None
    except (ImportError, ValueError):
        return False


@functools.lru_cache(maxsize=None)
def probe_variant(variant: str, timeout: float = 120.0) -> bool:
    """Render a tiny scene with ``variant`` in a child process and report whether it worked.

    Args:
        variant: a Mitsuba variant name such as ``"llvm_ad_rgb"``.
        timeout: seconds before the probe is considered failed.

    Returns:
        True when the child rendered and exited cleanly; False when it failed, crashed (e.g. aborted by an old
        LLVM) or timed out.

    Raises:
        ValueError: ``variant`` is empty.
    """
    if not variant:
        raise ValueError("variant must be a non-empty Mitsuba variant name")
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _PROBE_SCRIPT, variant],
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    except subprocess.TimeoutExpired:
        return False
    return proc.returncode == 0 and "ok" in proc.stdout


def best_variant(preferred: Optional[Sequence[str]] = None) -> str:
    """Return the fastest Mitsuba CPU variant that renders on this machine.

    ``$MESHADV_MITSUBA_VARIANT`` (when set) is tried first. Each candidate is probed in a child process
    (see :func:`probe_variant`), so a variant that aborts the process is skipped safely.

    Args:
        preferred: candidate variants in order of preference; default :data:`PREFERRED_VARIANTS`.

    Returns:
        The chosen variant name, e.g. ``"llvm_ad_rgb"``, or ``"scalar_rgb"`` as the fallback.

    Raises:
        ImportError: mitsuba is not installed, or none of the candidates works.

    Example:
        >>> best_variant()  # doctest: +SKIP
        'llvm_ad_rgb'
    """
    if not mitsuba_available():
        raise ImportError("mitsuba is not installed: pip install 'meshadv[transfer]' (mitsuba>=3.5)")
    candidates = list(preferred) if preferred is not None else list(PREFERRED_VARIANTS)
    forced = os.environ.get(VARIANT_ENV_VAR)
    if forced:
        candidates.insert(0, forced)
    tried = []
    for variant in dict.fromkeys(candidates):
        if probe_variant(variant):
            return variant
        tried.append(variant)
    raise ImportError(f"no working Mitsuba variant among {tried}")
