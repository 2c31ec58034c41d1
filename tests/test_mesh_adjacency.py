"""Tests of edges, neighbourhoods, face adjacency, the uniform Laplacian and mean curvature."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
import trimesh

from meshadv.mesh import (
    Mesh,
    boundary_vertex_mask,
    builtin_mesh,
    face_adjacency,
    is_watertight,
    mean_curvature,
    uniform_laplacian,
    vertex_degrees,
    vertex_edges,
    vertex_neighbors,
)


def _reference_edges(faces: np.ndarray) -> "set[tuple[int, int]]":
    return {tuple(sorted((int(a), int(b)))) for f in faces for a, b in itertools.combinations(f, 2)}


@pytest.mark.parametrize("name", ["sphere", "torus", "chair"])
def test_vertex_edges_match_reference(name: str) -> None:
    mesh = builtin_mesh(name)
    edges = vertex_edges(mesh.faces)
    assert edges.dtype == torch.int64 and edges.shape[1] == 2
    assert bool((edges[:, 0] < edges[:, 1]).all())
    assert {tuple(e) for e in edges.tolist()} == _reference_edges(mesh.faces.numpy())
    assert len(edges) == len(_reference_edges(mesh.faces.numpy()))  # unique


def test_euler_characteristic_of_closed_shapes() -> None:
    for name, chi in [("sphere", 2), ("torus", 0)]:
        mesh = builtin_mesh(name)
        assert mesh.num_vertices - len(vertex_edges(mesh.faces)) + mesh.num_faces == chi


def test_vertex_neighbors_csr() -> None:
    mesh = builtin_mesh("sphere")
    offsets, indices = vertex_neighbors(mesh.faces, mesh.num_vertices)
    assert offsets.shape == (mesh.num_vertices + 1,) and int(offsets[-1]) == len(indices)
    ref: "dict[int, set[int]]" = {}
    for a, b in _reference_edges(mesh.faces.numpy()):
        ref.setdefault(a, set()).add(b)
        ref.setdefault(b, set()).add(a)
    for i in range(mesh.num_vertices):
        neighbors = indices[offsets[i] : offsets[i + 1]].tolist()
        assert neighbors == sorted(ref[i])
    degrees = vertex_degrees(mesh.faces, mesh.num_vertices)
    assert torch.equal(degrees, offsets[1:] - offsets[:-1])
    with pytest.raises(ValueError, match="num_vertices"):
        vertex_neighbors(mesh.faces, 3)


def test_face_adjacency_including_non_manifold_edge() -> None:
    # Three faces share edge (0, 1); face 3 shares edge (1, 2) with face 0 only.
    faces = torch.tensor([[0, 1, 2], [1, 0, 3], [0, 1, 4], [2, 1, 5]])
    pairs = face_adjacency(faces).tolist()
    assert pairs == [[0, 1], [0, 2], [0, 3], [1, 2]]
    sphere = builtin_mesh("sphere")
    adj = face_adjacency(sphere.faces)
    assert len(adj) == len(vertex_edges(sphere.faces))  # closed manifold: one pair per edge
    counts = torch.bincount(adj.reshape(-1), minlength=sphere.num_faces)
    assert bool((counts == 3).all())


def test_boundary_and_watertight() -> None:
    faces = torch.tensor([[0, 1, 2], [0, 2, 3]])
    assert not is_watertight(faces)
    assert boundary_vertex_mask(faces, 5).tolist() == [True, True, True, True, False]
    assert is_watertight(builtin_mesh("sphere").faces)


def test_faces_validation() -> None:
    with pytest.raises(ValueError, match="faces"):
        vertex_edges(torch.zeros(3, 2, dtype=torch.int64))
    with pytest.raises(ValueError, match="^faces must hold integers"):
        vertex_edges(torch.zeros(3, 3))


def test_uniform_laplacian_values_and_gradient() -> None:
    edges = torch.tensor([[0, 1], [0, 2], [1, 2]])
    v = torch.tensor([[0.0, 0, 0], [3.0, 0, 0], [0.0, 3, 0], [7.0, 7, 7]], dtype=torch.float64)
    lap = uniform_laplacian(v, edges)
    assert torch.allclose(lap[0], torch.tensor([1.5, 1.5, 0.0], dtype=torch.float64))
    assert torch.equal(lap[3], torch.zeros(3, dtype=torch.float64))  # isolated vertex
    batched = uniform_laplacian(torch.stack([v, 2 * v]), edges)
    assert torch.allclose(batched[1], 2 * lap)
    x = torch.randn(4, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: uniform_laplacian(t, edges), (x,))
    # A translation has zero Laplacian on connected vertices.
    shifted = uniform_laplacian(v + torch.tensor([1.0, -2.0, 3.0], dtype=torch.float64), edges)
    assert torch.allclose(shifted, lap)


@pytest.mark.parametrize("radius", [0.5, 2.0])
def test_mean_curvature_of_sphere(radius: float) -> None:
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    mesh = Mesh.from_numpy(sphere.vertices, sphere.faces)
    h = mean_curvature(mesh)
    assert h.shape == (mesh.num_vertices,) and h.dtype == torch.float32
    np.testing.assert_allclose(h.numpy(), 1.0 / radius, rtol=0.03)


def test_mean_curvature_of_torus_matches_analytic() -> None:
    major, minor = 1.0, 0.3
    torus = trimesh.creation.torus(major_radius=major, minor_radius=minor, major_sections=128, minor_sections=48)
    h = mean_curvature(Mesh.from_numpy(torus.vertices, torus.faces)).numpy()
    rho = np.linalg.norm(torus.vertices[:, :2], axis=1)
    cos_t = (rho - major) / minor  # cosine of the angle around the tube, 1 on the outer equator
    expected = (major + 2 * minor * cos_t) / (2 * minor * (major + minor * cos_t))
    np.testing.assert_allclose(h, expected, rtol=0.01)
    assert h.max() / h.min() > 2.0  # the test would catch a constant answer


def test_mean_curvature_is_zero_on_a_plane_interior() -> None:
    grid = trimesh.creation.box(extents=(2, 2, 2)).subdivide().subdivide()
    mesh = Mesh.from_numpy(grid.vertices, grid.faces)
    h = mean_curvature(mesh).numpy()
    v = mesh.vertices.numpy()
    interior = (np.abs(v) < 0.99).sum(axis=1) == 2  # inside a cube face, away from its edges
    assert interior.sum() > 10
    np.testing.assert_allclose(h[interior], 0.0, atol=1e-4)
    assert h[~interior].max() > 1.0  # the cube's edges and corners are curved


def test_mean_curvature_ignores_winding_and_handles_degenerate_faces() -> None:
    sphere = builtin_mesh("sphere")
    faces = sphere.faces.clone()
    faces[::2] = faces[::2].flip(1)  # inconsistent winding, like PASCAL3D+
    h_ref = mean_curvature(sphere)
    h_flip = mean_curvature(Mesh(sphere.vertices, faces, sphere.face_colors))
    assert torch.allclose(h_ref, h_flip, rtol=1e-5)
    v = torch.cat([sphere.vertices, sphere.vertices[:1]])  # a sliver face with a duplicated vertex
    f = torch.cat([sphere.faces, torch.tensor([[0, 1, sphere.num_vertices]])])
    h = mean_curvature(Mesh(v, f, torch.zeros(len(f), 3)))
    assert torch.isfinite(h).all()
