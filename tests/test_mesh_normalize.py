"""Tests of normalisation into [-1, 1], the Z-up rotation and the inverse transform."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from meshadv.mesh import Mesh, NormalizeTransform, normalize_mesh, pascal3d_azimuth_to_renderer


def _random_mesh(seed: int = 0) -> Mesh:
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(30, 3)) * np.array([3.0, 0.5, 1.0]) + np.array([10.0, -4.0, 2.0])
    f = rng.integers(0, 30, size=(40, 3))
    return Mesh.from_numpy(v, f)


@pytest.mark.parametrize("z_up", [False, True])
def test_normalized_into_unit_cube_and_back(z_up: bool) -> None:
    mesh = _random_mesh()
    unit, tf = normalize_mesh(mesh, z_up=z_up)
    v = unit.vertices
    assert float(v.abs().max()) == pytest.approx(1.0, abs=1e-6)
    centre = (v.max(dim=0).values + v.min(dim=0).values) / 2
    assert torch.allclose(centre, torch.zeros(3), atol=1e-6)
    back = tf.to_original(v)
    assert torch.allclose(back, mesh.vertices, atol=1e-5)
    np.testing.assert_allclose(tf.from_original(mesh.vertices.numpy()), v.numpy(), atol=1e-5)
    assert torch.equal(unit.faces, mesh.faces)


def test_z_up_becomes_y_up_with_a_proper_rotation() -> None:
    mesh = _random_mesh(1)
    unit, tf = normalize_mesh(mesh, z_up=True)
    assert np.linalg.det(tf.rotation) == pytest.approx(1.0)
    top_original = int(mesh.vertices[:, 2].argmax())
    assert int(unit.vertices[:, 1].argmax()) == top_original  # the highest point stays highest
    extent_orig = (mesh.vertices.max(0).values - mesh.vertices.min(0).values).numpy()
    extent_new = (unit.vertices.max(0).values - unit.vertices.min(0).values).numpy()
    ratio = extent_new / extent_orig[[0, 2, 1]]
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-5)


def test_transform_matrix_dict_and_gradients() -> None:
    mesh = _random_mesh(2)
    unit, tf = normalize_mesh(mesh, z_up=True, extent=2.0)
    assert float(unit.vertices.abs().max()) == pytest.approx(2.0, abs=1e-5)
    homo = np.c_[mesh.vertices.numpy().astype(np.float64), np.ones(mesh.num_vertices)]
    np.testing.assert_allclose((homo @ tf.matrix().T)[:, :3], unit.vertices.numpy(), atol=1e-5)
    again = NormalizeTransform.from_dict(tf.to_dict())
    np.testing.assert_allclose(again.to_original(unit.vertices.numpy()), mesh.vertices.numpy(), atol=1e-5)
    v = unit.vertices.clone().requires_grad_(True)
    tf.to_original(v).sum().backward()
    expected = tf.rotation.sum(axis=1) / tf.scale  # d/dv of sum(R^T v / s) = row sums of R / s
    np.testing.assert_allclose(v.grad[0].numpy(), expected, rtol=1e-5)
    disp = tf.displacement_to_original(torch.ones(1, 3))
    assert torch.allclose(disp, tf.to_original(torch.ones(1, 3)) - tf.to_original(torch.zeros(1, 3)), atol=1e-5)


def test_normalize_rejects_bad_input() -> None:
    point = Mesh.from_numpy(np.ones((3, 3)), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match="^mesh has zero extent"):
        normalize_mesh(point)
    with pytest.raises(ValueError, match="extent"):
        normalize_mesh(_random_mesh(), extent=0.0)
    with pytest.raises(ValueError, match="^data must have center, scale and rotation"):
        NormalizeTransform.from_dict({"scale": 1.0})


@pytest.mark.parametrize("azimuth, elevation", [(0.0, 0.0), (30.0, 10.0), (135.0, -20.0), (300.0, 45.0)])
def test_pascal3d_viewpoint_maps_to_renderer_camera(azimuth: float, elevation: float) -> None:
    a, e = math.radians(azimuth), math.radians(elevation)
    camera_cad = np.array([math.cos(e) * math.sin(a), -math.cos(e) * math.cos(a), math.sin(e)])  # PASCAL3D+
    _, tf = normalize_mesh(_random_mesh(), z_up=True)
    camera_world = tf.rotation @ camera_cad
    az = math.radians(pascal3d_azimuth_to_renderer(azimuth))
    eye = np.array([math.cos(e) * math.sin(az), math.sin(e), -math.cos(e) * math.cos(az)])  # ARCHITECTURE.md
    np.testing.assert_allclose(camera_world, eye, atol=1e-12)
