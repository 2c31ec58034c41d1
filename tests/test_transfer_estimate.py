"""meshadv.transfer.estimation: camera from a silhouette, lights from a masked image."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from meshadv.mesh import Mesh
from meshadv.render import Camera, Lights, native_available, render, render_silhouette
from meshadv.transfer.estimation import CameraEstimate, estimate_camera, estimate_lights, light_errors, masked_rmse

pytestmark = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")


def _asymmetric_mesh() -> Mesh:
    """An L-shaped block with a post: no mirror or rotational symmetry, so the view is identifiable."""
    parts = [
        trimesh.creation.box(extents=(1.2, 0.3, 0.5)),
        trimesh.creation.box(extents=(0.3, 0.8, 0.5), transform=trimesh.transformations.translation_matrix(
            (-0.45, 0.55, 0.0))),
        trimesh.creation.box(extents=(0.15, 0.15, 0.9), transform=trimesh.transformations.translation_matrix(
            (0.45, 0.1, 0.5))),
    ]
    mesh = trimesh.util.concatenate(parts)
    faces = torch.as_tensor(np.asarray(mesh.faces), dtype=torch.int64)
    return Mesh(torch.as_tensor(np.asarray(mesh.vertices), dtype=torch.float32), faces,
                torch.full((faces.shape[0], 3), 0.7))


@pytest.mark.parametrize("azimuth,elevation,distance", [(40.0, 25.0, 3.0), (235.0, 10.0, 3.4)])
def test_camera_estimation_recovers_hidden_view(azimuth: float, elevation: float, distance: float) -> None:
    mesh = _asymmetric_mesh()
    hidden = Camera.spherical(distance, azimuth, elevation)
    mask = render_silhouette(mesh.vertices, mesh.faces, hidden, 64)[0, 0]
    est = estimate_camera(mask, mesh.vertices, mesh.faces, steps=60)
    assert isinstance(est, CameraEstimate)
    errors = est.errors(distance, azimuth, elevation)
    assert errors["azimuth_error"] < 4.0, est
    assert errors["elevation_error"] < 4.0, est
    assert errors["distance_error"] < 0.05, est
    assert est.iou > 0.95


def test_camera_estimation_from_mitsuba_mask() -> None:
    pytest.importorskip("mitsuba")
    from meshadv.transfer import MitsubaCamera, render_mask

    mesh = _asymmetric_mesh()
    mask = render_mask(mesh, MitsubaCamera.spherical(3.2, 120.0, 30.0), 64)
    est = estimate_camera(mask, mesh.vertices, mesh.faces, steps=60)
    errors = est.errors(3.2, 120.0, 30.0)
    assert errors["azimuth_error"] < 4.0 and errors["elevation_error"] < 4.0, est


def test_camera_estimation_rejects_bad_masks() -> None:
    mesh = _asymmetric_mesh()
    with pytest.raises(ValueError, match="^mask is empty"):
        estimate_camera(np.zeros((32, 32)), mesh.vertices, mesh.faces)
    with pytest.raises(ValueError, match="mask"):
        estimate_camera(np.zeros((2, 2, 32, 32)), mesh.vertices, mesh.faces)


def test_light_estimation_fits_the_masked_image() -> None:
    mesh = _asymmetric_mesh()
    gen = torch.Generator().manual_seed(0)
    colors = 0.4 + 0.5 * torch.rand(mesh.faces.shape[0], 3, generator=gen)
    camera = Camera.spherical(3.0, 40.0, 25.0)
    true = Lights([[0.5, 1.0, -0.6]], [[0.6, 0.55, 0.5]], [0.3, 0.3, 0.35])
    with torch.no_grad():
        out = render(mesh.vertices, mesh.faces, colors, camera, true, 64, background=(0.0, 0.0, 0.0))
    image, mask = out.image[0], out.alpha[0, 0]
    start = Lights(torch.ones(5, 3), torch.full((5, 3), 0.06), torch.full((3,), 0.3))
    with torch.no_grad():
        before = render(mesh.vertices, mesh.faces, colors, camera, start, 64, background=(0.0, 0.0, 0.0))
    est = estimate_lights(image, mask, mesh.vertices, mesh.faces, colors, camera, num_lights=5, steps=150)
    with torch.no_grad():
        after = render(mesh.vertices, mesh.faces, colors, camera, est.lights, 64, background=(0.0, 0.0, 0.0))
    rmse_before = masked_rmse(before.image[0].numpy(), image.numpy(), mask.numpy())
    rmse_after = masked_rmse(after.image[0].numpy(), image.numpy(), mask.numpy())
    assert rmse_after < 0.03
    assert rmse_after < rmse_before / 2
    errors = light_errors(est.lights, true)
    assert errors["direction_error"] < 25.0
    assert errors["ambient_error"] < 0.15
    assert est.lights.directions.shape == (1, 5, 3)
    assert bool((est.lights.colors >= 0).all()) and bool((est.lights.ambient >= 0).all())


def test_light_errors_known_answer() -> None:
    a = Lights([[0.0, 1.0, 0.0]], [[1.0, 1.0, 1.0]], [0.2, 0.2, 0.2])
    b = Lights([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]], [[0.25, 0.25, 0.25], [0.25, 0.25, 0.25]], [0.3, 0.3, 0.3])
    errors = light_errors(a, b)
    assert errors["direction_error"] == pytest.approx(90.0, abs=1e-4)
    assert errors["intensity_error"] == pytest.approx(1.0, abs=1e-6)
    assert errors["ambient_error"] == pytest.approx(0.1, abs=1e-6)
    assert math.isclose(light_errors(a, a)["direction_error"], 0.0, abs_tol=1e-3)


def test_estimate_lights_rejects_mismatched_shapes() -> None:
    mesh = _asymmetric_mesh()
    cam = Camera.spherical(3.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="mask shape"):
        estimate_lights(torch.zeros(3, 32, 32), torch.ones(16, 16), mesh.vertices, mesh.faces, mesh.face_colors, cam)
    with pytest.raises(ValueError, match="num_lights"):
        estimate_lights(torch.zeros(3, 8, 8), torch.ones(8, 8), mesh.vertices, mesh.faces, mesh.face_colors, cam,
                        num_lights=-1)
