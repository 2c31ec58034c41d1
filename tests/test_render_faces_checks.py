"""The face-index checks every render entry point shares (rasterize, render, render_silhouette, raycast)."""

from __future__ import annotations

from typing import Any, Callable

import pytest
import torch

from meshadv.render import Camera, Lights, native_available, rasterize, raycast, render, render_silhouette

pytestmark = pytest.mark.skipif(not native_available(), reason="meshadv._raster is not built (maturin develop)")

_VERTS = torch.tensor([[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [0.0, 1.0, 1.0]])
_CAMERA = Camera.spherical(4.0)


def _rasterize(faces: Any) -> object:
    return rasterize(_VERTS, faces, torch.ones(1, 1), 8)


def _render(faces: Any) -> object:
    return render(_VERTS, faces, torch.ones(1, 3), _CAMERA, Lights.default(), 8)


def _silhouette(faces: Any) -> object:
    return render_silhouette(_VERTS, faces, _CAMERA, 8)


def _raycast(faces: Any) -> object:
    return raycast(_VERTS, faces, _CAMERA, 8)


@pytest.mark.parametrize("entry", [_rasterize, _render, _silhouette, _raycast])
def test_bad_faces_are_named_the_same_way_by_every_entry_point(entry: Callable[[Any], object]) -> None:
    entry(torch.tensor([[0, 1, 2]]))  # the good case runs
    entry(torch.tensor([[0, 1, 2]], dtype=torch.int32))
    with pytest.raises(TypeError, match="^faces must be a Tensor"):
        entry([[0, 1, 2]])
    for dtype in (torch.float32, torch.bool, torch.complex64):
        with pytest.raises(ValueError, match="^faces must be an integer tensor"):
            entry(torch.zeros(1, 3, dtype=dtype))
    for shape in ((3,), (1, 2), (1, 3, 1)):
        with pytest.raises(ValueError, match=r"^faces must have shape \(M,3\)"):
            entry(torch.zeros(shape, dtype=torch.long))
    with pytest.raises(ValueError, match=r"^faces is empty \(M = 0 triangles\)"):
        entry(torch.zeros(0, 3, dtype=torch.long))
    with pytest.raises(ValueError, match=r"^faces holds vertex indices in \[0, 3\] but must be in \[0, 2\] \(N = 3\)"):
        entry(torch.tensor([[0, 1, 3]]))
    with pytest.raises(ValueError, match=r"^faces holds vertex indices in \[-1, 2\]"):
        entry(torch.tensor([[0, -1, 2]]))
