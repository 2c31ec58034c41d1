"""The vertex gradients of the rasterizer's backward ("visibility gradients"), chosen by name per call.

* ``"nmr"``: the Neural Mesh Renderer's approximate rasterization gradient, every sweep running to the image border
  (docs/NMR_GRADIENT.md).
* ``"local"``: the same sweeps truncated to the pixels nearest each edge (docs/LOCAL_GRADIENT.md):
  :data:`LOCAL_RADIUS` pixels of the output image, i.e. ``LOCAL_RADIUS * antialias`` pixels of the supersampled
  raster. Its cost grows with the edges times the radius instead of the edges times the image width.

The images do not depend on the choice; only the gradient of the screen-space vertex positions does.
"""

from __future__ import annotations

from typing import Any

__all__ = ["LOCAL_RADIUS", "VISIBILITY_GRADIENTS", "check_visibility_gradient", "sweep_radius"]

#: The names :func:`check_visibility_gradient` accepts.
VISIBILITY_GRADIENTS = ("nmr", "local")

#: Output-image pixels of each sweep of the local gradient (beyond an edge, and into the face from it).
LOCAL_RADIUS = 2


def check_visibility_gradient(value: Any, name: str = "visibility_gradient") -> str:
    """``value`` if it names a visibility gradient (:data:`VISIBILITY_GRADIENTS`).

    Raises:
        ValueError: anything else, naming the argument ``name`` and the accepted values.
    """
    if not isinstance(value, str) or value not in VISIBILITY_GRADIENTS:
        raise ValueError(f"{name} must be one of {VISIBILITY_GRADIENTS}, got {value!r}")
    return value


def sweep_radius(visibility_gradient: str, antialias: int = 1) -> int | None:
    """The native backward's ``sweep_radius`` (raster pixels) for ``visibility_gradient`` on a raster supersampled
    ``antialias`` times: ``None`` (NMR's unbounded sweeps) or ``LOCAL_RADIUS * antialias``.

    Example:
        >>> sweep_radius("nmr"), sweep_radius("local", antialias=2)
        (None, 4)
    """
    return None if check_visibility_gradient(visibility_gradient) == "nmr" else LOCAL_RADIUS * antialias
