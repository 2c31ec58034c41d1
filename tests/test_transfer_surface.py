"""Mitsuba transfer of textured meshes: the bitmap texture, its UVs and (smooth) the same vertex normals give a
Mitsuba render that agrees with render_surface's as the conversion check measures it for per-face colours."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from meshadv.mesh.structure import Mesh
from meshadv.mesh.surface_mesh import SurfaceMesh
from meshadv.render import native_available
from meshadv.transfer.mitsuba_check import conversion_check, head_light_record

pytest.importorskip("mitsuba", reason="mitsuba is not installed (pip install 'meshadv[transfer]')")
pytestmark = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")


def _checker_sphere(rings: int = 16, segments: int = 32) -> SurfaceMesh:
    """A UV sphere (a seam column of vertices at u = 0 and 1) with a 32 x 64 checker texture."""
    verts, uvs = [], []
    for r in range(rings + 1):
        th = np.pi * r / rings
        for s in range(segments + 1):
            ph = 2 * np.pi * s / segments
            verts.append([np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)])
            uvs.append([s / segments, 1 - r / rings])
    faces = []
    for r in range(rings):
        for s in range(segments):
            a = r * (segments + 1) + s
            b, c, d = a + 1, a + segments + 1, a + segments + 2
            if r > 0:
                faces.append([a, c, d])
            if r < rings - 1:
                faces.append([a, d, b])
    i, j = np.meshgrid(np.arange(32), np.arange(64), indexing="ij")
    texture = np.where((i // 8 + j // 8) % 2 == 0, 0.9, 0.2)[..., None] * np.array([1.0, 0.6, 0.3])
    f = torch.tensor(faces)
    return SurfaceMesh(
        Mesh(torch.tensor(verts, dtype=torch.float32), f, torch.full((len(faces), 3), 0.5)),
        torch.tensor(uvs, dtype=torch.float32),
        f,
        torch.tensor(texture, dtype=torch.float32),
    )


@pytest.mark.parametrize("shading", ["flat", "smooth"])
def test_a_textured_sphere_renders_alike_in_mitsuba_and_meshadv(shading: str) -> None:
    sphere = _checker_sphere()
    check = conversion_check(
        sphere, head_light_record(3.5, 30.0, 20.0, 0.5, 0.5), image_size=64, spp=64, shading=shading
    )
    assert check.mask_iou > 0.98
    assert check.interior_pixels > 1500
    assert check.mean_abs_difference < 0.03
    assert check.p95_abs_difference < 0.08
    # The checker shows in both (not a flat colour), and in the same place: a texture flipped in v or mirrored in
    # u on one side would put dark squares on light ones.
    ours, theirs = check.meshadv_image.mean(-1), check.mitsuba_image.mean(-1)
    assert ours.std() > 0.1 and theirs.std() > 0.1
    assert np.corrcoef(ours.ravel(), theirs.ravel())[0, 1] > 0.9
    assert np.corrcoef(ours[::-1].ravel(), theirs.ravel())[0, 1] < 0.8
