"""ViewSet: batching, records round trip, orbit and jitter."""

from __future__ import annotations

import json

import pytest
import torch

from meshadv.render import Camera, Lights, ViewSet


def test_orbit_len_index_cat() -> None:
    views = ViewSet.orbit([0.0, 90.0, 180.0, 270.0], elevation=20.0, distance=2.5)
    assert len(views) == 4 and len(views[1]) == 1 and len(views[1:3]) == 2
    torch.testing.assert_close(views[2].camera.azimuth, torch.tensor([180.0]))
    both = ViewSet.cat([views, views[0]])
    assert len(both) == 5 and len(both.lights) == 5
    torch.testing.assert_close(both.camera.eye()[4], views.camera.eye()[0])


def test_lights_broadcast_and_mismatch() -> None:
    cam = Camera.spherical(2.0, torch.tensor([0.0, 10.0, 20.0]), 0.0)
    views = ViewSet(cam, Lights.default())
    assert len(views.lights) == 3
    with pytest.raises(ValueError, match="lights batch size"):
        ViewSet(cam, Lights.default(cam[:2]))
    with pytest.raises(TypeError, match="camera"):
        ViewSet("camera", Lights.default())  # type: ignore[arg-type]


def test_records_round_trip_spherical_and_look_at() -> None:
    views = ViewSet.orbit([15.0, 120.0], elevation=[5.0, 40.0], distance=3.0, tilt=7.0)
    records = views.to_records()
    assert set(records[0]) >= {
        "distance",
        "azimuth",
        "elevation",
        "tilt",
        "viewing_angle",
        "light_directions",
        "light_colors",
        "ambient",
    }
    again = ViewSet.from_records(json.loads(json.dumps(records)))
    pts = torch.randn(5, 3)
    torch.testing.assert_close(again.camera.project(pts), views.camera.project(pts))
    torch.testing.assert_close(again.lights.directions, views.lights.directions)
    la = ViewSet(Camera.look_at(torch.tensor([1.0, 2.0, -3.0]), torch.tensor([0.1, 0.0, 0.0])), Lights.default())
    back = ViewSet.from_records(la.to_records())
    torch.testing.assert_close(back.camera.project(pts), la.camera.project(pts))
    with pytest.raises(ValueError, match="records"):
        ViewSet.from_records([])
    with pytest.raises(ValueError, match=r"^records\[0\] is missing keys"):
        ViewSet.from_records([{"distance": 1.0}])


def test_jitter_bounds_and_reproducibility() -> None:
    views = ViewSet.orbit(torch.zeros(64), elevation=10.0, distance=2.0)
    scales = {"azimuth": 5.0, "elevation": 3.0, "distance": 0.1, "light_intensity": 0.2, "light_direction": 0.1}
    j1 = views.jitter(torch.Generator().manual_seed(5), **scales)
    j2 = views.jitter(torch.Generator().manual_seed(5), **scales)
    torch.testing.assert_close(j1.camera.azimuth, j2.camera.azimuth)
    assert j1.camera.azimuth.abs().max() <= 5.0 and j1.camera.azimuth.std() > 1.0
    assert ((j1.camera.elevation - 10.0).abs() <= 3.0).all()
    assert ((j1.camera.distance / 2.0 - 1).abs() <= 0.1 + 1e-6).all()
    assert ((j1.lights.ambient / views.lights.ambient - 1).abs() <= 0.2 + 1e-6).all()
    assert not torch.equal(j1.lights.directions, views.lights.directions)
    torch.testing.assert_close(views.camera.azimuth, torch.zeros(64))  # original unchanged
    with pytest.raises(ValueError, match="azimuth"):
        views.jitter(torch.Generator(), azimuth=-1.0)


def test_jitter_keeps_gradients() -> None:
    az = torch.tensor([0.0, 30.0], requires_grad=True)
    views = ViewSet(Camera.spherical(2.0, az, 0.0), Lights.default())
    jittered = views.jitter(torch.Generator().manual_seed(0), azimuth=2.0)
    jittered.camera.eye().sum().backward()
    assert az.grad is not None and az.grad.abs().sum() > 0
    # the noise is a constant offset: the gradient is the un-jittered camera's at the jittered azimuth
    shifted = jittered.camera.azimuth.detach().requires_grad_(True)
    assert not torch.equal(shifted, az.detach())
    Camera.spherical(2.0, shifted, 0.0).eye().sum().backward()
    torch.testing.assert_close(az.grad, shifted.grad)


def test_jitter_draws_tilt_then_distance_azimuth_elevation_and_keeps_the_other_fields() -> None:
    """The camera noise, drawn in a fixed order from the generator; every other field is carried over unchanged."""

    def draws(seed: int, n: int, b: int) -> list[torch.Tensor]:
        g = torch.Generator().manual_seed(seed)
        return [torch.rand(b, generator=g) * 2 - 1 for _ in range(n)]

    sph = Camera.spherical(2.0, [10.0, 20.0, 30.0], 5.0, tilt=1.0, viewing_angle=40.0, near=0.2, far=50.0)
    got = ViewSet(sph, Lights.default(sph)).jitter(
        torch.Generator().manual_seed(3), azimuth=4.0, elevation=2.0, distance=0.1, tilt=3.0
    ).camera
    t, d, a, e = draws(3, 4, 3)
    torch.testing.assert_close(got.tilt, sph.tilt + t * 3.0)
    torch.testing.assert_close(got.distance, sph.distance * (1 + d * 0.1))
    torch.testing.assert_close(got.azimuth, sph.azimuth + a * 4.0)
    torch.testing.assert_close(got.elevation, sph.elevation + e * 2.0)
    assert got.viewing_angle is sph.viewing_angle and got.near is sph.near and got.far is sph.far
    assert got.ortho_scale is sph.ortho_scale and not got.orthographic and got.eye_position is None

    la = Camera.look_at([[1.0, 2.0, 3.0], [0.0, 1.0, 4.0]], tilt=2.0, orthographic=True, ortho_scale=1.5)
    got = ViewSet(la, Lights.default(la)).jitter(torch.Generator().manual_seed(4), tilt=5.0).camera
    (t,) = draws(4, 1, 2)
    torch.testing.assert_close(got.tilt, la.tilt + t * 5.0)
    assert got.eye_position is la.eye_position and got.at is la.at and got.up is la.up
    assert got.orthographic and got.ortho_scale is la.ortho_scale and got.distance is None
    with pytest.raises(ValueError, match="spherical camera"):
        ViewSet(la, Lights.default(la)).jitter(torch.Generator(), azimuth=1.0)


def test_render_views_names_vertices_that_are_not_a_batch() -> None:
    """One mesh's ``(N, 3)`` vertices are refused with the shape expected, not read as N meshes of one vertex."""
    from meshadv.mesh import builtin_mesh
    from meshadv.render import RenderSetup, render_views

    mesh = builtin_mesh("sphere")
    views = ViewSet.orbit([0.0, 90.0], elevation=20.0, distance=2.5)
    with pytest.raises(ValueError, match=r"vertices must be a \(K, N, 3\)"):
        render_views(mesh.vertices, mesh.faces, mesh.face_colors, views, RenderSetup(image_size=16))
    pytest.importorskip("meshadv._raster")
    images, _ = render_views(mesh.vertices[None], mesh.faces, mesh.face_colors, views, RenderSetup(image_size=16))
    assert images.shape == (2, 3, 16, 16)  # the batched form draws both views
