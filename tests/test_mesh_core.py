"""Tests of the Mesh dataclass and the order-preserving clean-up."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from meshadv.mesh import Mesh, bbox_diagonal
from meshadv.mesh.cleanup import clean_arrays, degenerate_face_mask, merge_duplicate_vertices


def _tetra() -> Mesh:
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float32)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return Mesh.from_numpy(v, f, np.random.default_rng(0).random((4, 3)))


def test_mesh_fields_and_dtypes() -> None:
    m = _tetra()
    assert m.vertices.dtype == torch.float32 and m.faces.dtype == torch.int64
    assert m.face_colors.dtype == torch.float32
    assert (m.num_vertices, m.num_faces) == (4, 4)
    assert m.faces_int32.dtype == torch.int32 and torch.equal(m.faces_int32.long(), m.faces)
    assert m.bbox_diagonal() == pytest.approx(np.sqrt(3.0))
    assert torch.allclose(m.face_areas()[0], torch.tensor(0.5))


def test_one_bounding_box_diagonal_for_the_mesh_the_distances_and_the_moves() -> None:
    from meshadv.attacks.distances import displacement_stats
    from meshadv.perceptibility import vertex_moves

    v = torch.tensor([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 3.0, 6.0]])  # box 2 x 3 x 6: diagonal 7
    assert float(bbox_diagonal(v)) == pytest.approx(7.0)
    assert bbox_diagonal(v.double()).dtype == torch.float64
    assert Mesh(v, torch.tensor([[0, 1, 2]]), torch.ones(1, 3)).bbox_diagonal() == pytest.approx(7.0)
    move = torch.zeros_like(v)
    move[1, 2] = 1.4  # one vertex by a fifth of the diagonal
    assert float(vertex_moves(v + move, v)["max_displacement"][0]) == pytest.approx(0.2)
    assert float(displacement_stats(move, v)["max_displacement"]) == pytest.approx(0.2)
    for bad in (torch.zeros(0, 3), torch.zeros(4, 2)):
        with pytest.raises(ValueError, match="vertices must have shape"):
            bbox_diagonal(bad)


def test_mesh_default_color() -> None:
    m = Mesh.from_numpy(np.eye(3), np.array([[0, 1, 2]]), default_color=(0.1, 0.2, 0.3))
    assert torch.allclose(m.face_colors, torch.tensor([[0.1, 0.2, 0.3]]))


@pytest.mark.parametrize(
    "vertices, faces, colors, match",
    [
        (np.zeros((3, 2)), np.array([[0, 1, 2]]), None, "vertices"),
        (np.zeros((3, 3)), np.array([[0, 1, 3]]), None, "out of range"),
        (np.zeros((3, 3)), np.array([[0, 1, -1]]), None, "out of range"),
        (np.zeros((3, 3)), np.array([[0, 1, 2]]), np.zeros((2, 3)), "face_colors"),
    ],
)
def test_mesh_rejects_bad_fields(vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        Mesh.from_numpy(vertices, faces, colors)


def test_mesh_rejects_wrong_dtype() -> None:
    with pytest.raises(ValueError, match="faces must be int64"):
        Mesh(torch.zeros(3, 3), torch.zeros(1, 3, dtype=torch.int32), torch.zeros(1, 3))


def test_with_vertices_keeps_autograd() -> None:
    m = _tetra()
    delta = torch.zeros_like(m.vertices, requires_grad=True)
    moved = m.with_vertices(m.vertices + delta)
    moved.face_areas().sum().backward()
    assert delta.grad is not None and delta.grad.abs().sum() > 0
    # the gradient is the derivative of the total area: central differences, coordinate by coordinate
    eps = 1e-2
    numeric = torch.zeros_like(m.vertices)
    for i, j in np.ndindex(*m.vertices.shape):
        step = torch.zeros_like(m.vertices)
        step[i, j] = eps
        plus, minus = (m.with_vertices(m.vertices + s * step).face_areas().sum() for s in (1, -1))
        numeric[i, j] = (plus - minus) / (2 * eps)
    torch.testing.assert_close(delta.grad, numeric, rtol=1e-3, atol=1e-4)
    assert moved.faces is m.faces
    with pytest.raises(ValueError, match="vertices"):
        m.with_vertices(torch.zeros(5, 3))
    with pytest.raises(ValueError, match="face_colors"):
        m.with_face_colors(torch.zeros(3, 3))
    recolored = m.with_face_colors(torch.ones(4, 3))
    assert torch.equal(recolored.face_colors, torch.ones(4, 3)) and recolored.vertices is m.vertices


def test_mesh_to_and_detach() -> None:
    m = _tetra()
    assert m.to("cpu") is m
    v = m.vertices.clone().requires_grad_(True)
    assert not m.with_vertices(v).detach().vertices.requires_grad
    with pytest.raises(dataclasses.FrozenInstanceError, match="'vertices'"):
        m.vertices = torch.zeros(4, 3)  # frozen


def test_merge_duplicates_preserves_first_occurrence_order() -> None:
    v = np.array([[5, 0, 0], [1, 0, 0], [5, 0, 0], [0, 1, 0], [-0.0, 1, 0]], dtype=np.float32)
    f = np.array([[0, 1, 3], [2, 1, 4]])
    nv, nf, merged = merge_duplicate_vertices(v, f)
    assert merged == 2
    np.testing.assert_array_equal(nv, v[[0, 1, 3]])
    np.testing.assert_array_equal(nf, [[0, 1, 2], [0, 1, 2]])


def test_clean_arrays_counts_and_identity_on_clean_input() -> None:
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [9, 9, 9], [1, 0, 0]], dtype=np.float32)
    # collinear, repeated corner, merged-into-repeated, duplicate of the first in the other winding
    f = np.array([[0, 1, 2], [0, 1, 3], [0, 0, 2], [1, 5, 2], [2, 1, 0]])
    c = np.arange(15, dtype=np.float32).reshape(5, 3)
    nv, nf, nc, counts = clean_arrays(v, f, c)
    assert (counts.merged_vertices, counts.degenerate_faces, counts.unreferenced_vertices) == (1, 3, 2)
    assert counts.duplicate_faces == 1
    np.testing.assert_array_equal(nf, [[0, 1, 2]])
    np.testing.assert_array_equal(nc, c[:1])
    np.testing.assert_array_equal(nv, v[:3])
    # A clean mesh passes through unchanged, in order.
    v2, f2, c2, counts2 = clean_arrays(nv, nf, nc)
    assert counts2 == type(counts2)(0, 0, 0, 0)
    np.testing.assert_array_equal(v2, nv)
    np.testing.assert_array_equal(f2, nf)


def test_degenerate_mask_keeps_tiny_but_nonzero_faces() -> None:
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1e-6, 0], [2, 0, 0], [0, 1e-30, 0]], dtype=np.float32)
    assert not degenerate_face_mask(v, np.array([[0, 1, 2]])).any()
    # beside them, a collinear face (zero area) and a repeated corner are flagged; 1e-30 is tiny but not zero
    faces = np.array([[0, 1, 2], [0, 1, 3], [0, 0, 2], [0, 1, 4], [2, 1, 2]])
    assert degenerate_face_mask(v, faces).tolist() == [False, True, True, False, True]
