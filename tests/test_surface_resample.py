"""MeshLab resampling of textured and vertex-coloured meshes (meshadv.mesh.surface_resample): the texture and the
colours are carried onto the new surface and its render keeps the original's look, at least twice as close as the
per-face colours a plain resampling carries."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from surface_assets import box_textured, vertex_coloured

from meshadv.mesh import builtin_mesh, resample_mesh_with_info
from meshadv.mesh.surface_mesh import SurfaceMesh
from meshadv.mesh.surface_resample import resample_surface_mesh
from meshadv.render import ViewSet, native_available, render, render_surface

pytest.importorskip("pymeshlab")
needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")

VIEWS = ViewSet.orbit([0.0, 120.0, 240.0], elevation=20.0, distance=3.0)


def _draw(s: SurfaceMesh) -> tuple[np.ndarray, np.ndarray]:
    with torch.no_grad():
        o = render_surface(s.vertices, s.faces, VIEWS.camera, VIEWS.lights, 96, texture=s.texture, uvs=s.uvs,
                           uv_faces=s.uv_faces, vertex_colors=s.vertex_colors, shading="smooth")
    return o.image.permute(0, 2, 3, 1).numpy(), o.alpha[:, 0].numpy() > 0.5


def _smooth_texture(side: int = 64) -> torch.Tensor:
    y, x = torch.meshgrid(torch.linspace(0, 1, side), torch.linspace(0, 1, side), indexing="ij")
    return torch.stack([0.5 + 0.4 * torch.sin(6 * x), 0.5 + 0.4 * torch.cos(7 * y), (x + y) / 2], -1)


@needs_native
@pytest.mark.parametrize("asset", ["textured", "painted"])
def test_a_resampled_surface_keeps_its_look(asset: str) -> None:
    surface = box_textured() if asset == "textured" else vertex_coloured()
    if asset == "textured":
        surface = surface.with_texture(_smooth_texture())
    dense, info = resample_surface_mesh(replace_shading(surface, "smooth"), target_faces=3000, texture_side=512)
    assert info.output_faces == dense.num_faces and 2000 < dense.num_faces < 4000
    assert dense.shading == "smooth" and dense.normals is None
    assert (dense.texture is not None) == (asset == "textured")
    assert (dense.vertex_colors is not None) == (asset == "painted")
    if dense.texture is not None:
        assert dense.texture.shape == (512, 512, 3)
    ref, mask = _draw(surface)
    ours, ours_mask = _draw(dense)
    plain, _ = resample_mesh_with_info(surface.mesh, target_faces=3000)  # per-face colours carried by centroid
    with torch.no_grad():
        o = render(plain.vertices, plain.faces, plain.face_colors, VIEWS.camera, VIEWS.lights, 96)
    per_face, face_mask = o.image.permute(0, 2, 3, 1).numpy(), o.alpha[:, 0].numpy() > 0.5
    inside = mask & ours_mask & face_mask
    ours_diff = np.abs(ours - ref).mean(-1)[inside].mean()
    per_face_diff = np.abs(per_face - ref).mean(-1)[inside].mean()
    assert ours_diff < 0.02
    assert ours_diff * 2 < per_face_diff


def replace_shading(surface: SurfaceMesh, shading: str) -> SurfaceMesh:
    from dataclasses import replace

    return replace(surface, shading=shading)


def test_bad_input_is_an_error_naming_the_argument() -> None:
    with pytest.raises(TypeError, match="surface must be a SurfaceMesh"):
        resample_surface_mesh(builtin_mesh("sphere"), target_faces=100)
    with pytest.raises(ValueError, match="neither texture nor vertex colours"):
        resample_surface_mesh(SurfaceMesh(builtin_mesh("sphere")), target_faces=100)
    with pytest.raises(ValueError, match="texture_side"):
        resample_surface_mesh(box_textured(), target_faces=100, texture_side=2)
