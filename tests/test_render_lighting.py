"""Face normals, two-sided orientation, Lambert shading and its gradients."""

from __future__ import annotations

import pytest
import torch

from meshadv.render import Camera, Lights, ViewSet, face_normals, orient_normals, shade

F64 = torch.float64


def tetra(dtype: torch.dtype = F64) -> tuple[torch.Tensor, torch.Tensor]:
    verts = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], dtype=dtype)
    faces = torch.tensor([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return verts, faces


def test_face_normals_known_values() -> None:
    verts, faces = tetra()
    n = face_normals(verts, faces)[0]
    torch.testing.assert_close(n[0], torch.tensor([0.0, 0.0, -1.0], dtype=F64))
    torch.testing.assert_close(n[1], torch.tensor([0.0, -1.0, 0.0], dtype=F64))
    torch.testing.assert_close(n[3], torch.full((3,), 3**-0.5, dtype=F64))
    degenerate = face_normals(torch.zeros(3, 3, requires_grad=True), torch.tensor([[0, 1, 2]]))
    assert torch.isfinite(degenerate).all() and degenerate.abs().sum() == 0


def test_orient_normals_faces_camera() -> None:
    verts, faces = tetra()
    cam = Camera.spherical(torch.tensor(5.0, dtype=F64), 0.0, 0.0)  # eye at -z
    n = orient_normals(face_normals(verts, faces), verts, faces, cam)[0]
    to_eye = cam.eye()[0] - verts[faces].mean(1)
    assert ((n * to_eye).sum(-1) >= 0).all()
    ortho = Camera.spherical(torch.tensor(5.0, dtype=F64), 0.0, 0.0, orthographic=True)
    n2 = orient_normals(face_normals(verts, faces), verts, faces, ortho)[0]
    assert (n2 @ ortho.view_direction()[0] <= 0).all()


def test_shade_matches_hand_computation() -> None:
    verts = torch.tensor([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]], dtype=F64)  # normal (0, 0, -1)
    faces = torch.tensor([[0, 1, 2]])
    lights = Lights(
        torch.tensor([[0.0, 0.0, -2.0], [1.0, 0.0, -1.0], [0.0, 0.0, 1.0]], dtype=F64),
        torch.tensor([[0.2, 0.3, 0.4], [0.5, 0.5, 0.5], [9.0, 9.0, 9.0]], dtype=F64),
        torch.tensor([0.1, 0.0, 0.2], dtype=F64),
    )
    color = torch.tensor([[0.5, 1.0, 0.8]], dtype=F64)
    cam = Camera.spherical(torch.tensor(3.0, dtype=F64), 0.0, 0.0)
    s = torch.tensor([0.1, 0.0, 0.2], dtype=F64) + torch.tensor([0.2, 0.3, 0.4], dtype=F64) + 0.5 * 2**-0.5
    torch.testing.assert_close(shade(verts, faces, color, lights, cam)[0, 0], (color[0] * s).clamp(0, 1))
    # Seen from behind the normal flips and the third light (behind) lights the face, saturating the clamp.
    back = Camera.spherical(torch.tensor(3.0, dtype=F64), 180.0, 0.0)
    torch.testing.assert_close(
        shade(verts, faces, color, lights, back)[0, 0], (color[0] * (lights.ambient[0] + 9.0)).clamp(0, 1)
    )
    # One-sided: no flip, the light from behind does not count.
    torch.testing.assert_close(
        shade(verts, faces, color, lights, back, two_sided=False)[0, 0], (color[0] * s).clamp(0, 1)
    )


def random_lights(batch: int, k: int, requires_grad: bool = True) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(1)
    d = torch.randn(batch, k, 3, dtype=F64, generator=gen)
    c = torch.rand(batch, k, 3, dtype=F64, generator=gen) * 0.4
    a = torch.rand(batch, 3, dtype=F64, generator=gen) * 0.3
    return tuple(t.requires_grad_(requires_grad) for t in (d, c, a))


def test_gradcheck_shading_wrt_colors_and_lights() -> None:
    verts, faces = tetra()
    verts = verts * 0.7 + 0.05
    cam = Camera.spherical(torch.tensor([3.0, 3.0], dtype=F64), torch.tensor([20.0, 200.0], dtype=F64), 30.0)
    d, c, a = random_lights(2, 2)
    # Reflectances away from the clamp kinks; one saturated entry checks the clamp's zero gradient.
    colors = torch.rand(2, 4, 3, dtype=F64) * 0.5 + 0.2
    colors[0, 0, 0] = 5.0
    colors.requires_grad_(True)

    def fn(col: torch.Tensor, dirs: torch.Tensor, cols: torch.Tensor, amb: torch.Tensor) -> torch.Tensor:
        return shade(verts, faces, col, Lights(dirs, cols, amb), cam)

    assert torch.autograd.gradcheck(fn, [colors, d, c, a])
    out = fn(colors, d, c, a)
    assert out[0, 0, 0] == 1.0
    (grad,) = torch.autograd.grad(out[0, 0, 0], colors)
    assert grad[0, 0, 0] == 0.0


def test_gradcheck_shading_wrt_vertices() -> None:
    verts, faces = tetra()
    verts = (verts * 0.8 + torch.randn(4, 3, dtype=F64) * 0.05).requires_grad_(True)
    cam = Camera.spherical(torch.tensor(3.0, dtype=F64), 25.0, 15.0)
    d, c, a = random_lights(1, 3, requires_grad=False)
    colors = torch.full((4, 3), 0.4, dtype=F64)
    assert torch.autograd.gradcheck(lambda v: shade(v, faces, colors, Lights(d, c, a), cam), [verts])


def test_lights_constructors_and_validation() -> None:
    lights = Lights.default()
    assert lights.directions.shape == (1, 1, 3) and lights.ambient.shape == (1, 3)
    cam = Camera.spherical(2.0, torch.tensor([0.0, 90.0]), 0.0)
    head = Lights.default(cam)
    assert len(head) == 2
    torch.testing.assert_close(
        head.directions[1, 0] / head.directions[1, 0].norm(), torch.tensor([1.0, 0.0, 0.0]), atol=1e-6, rtol=0
    )
    single = Lights.single((0.0, 1.0, 0.0), (1.0, 1.0, 1.0), (0.0, 0.0, 0.0))
    assert single.num_lights == 1
    none = Lights(torch.zeros(0, 3), torch.zeros(0, 3), torch.ones(3))
    assert none.num_lights == 0
    assert len(Lights.cat([head, head[0]])) == 3
    with pytest.raises(ValueError, match="directions"):
        Lights(torch.zeros(1, 3), torch.ones(1, 3), torch.ones(3))
    with pytest.raises(ValueError, match="ambient"):
        Lights(torch.ones(1, 3), torch.ones(1, 3), torch.ones(4))
    with pytest.raises(ValueError, match="^directions and colors must hold the same number"):
        Lights(torch.ones(2, 3), torch.ones(1, 3), torch.ones(3))
    with pytest.raises(ValueError, match="batch"):
        Lights(torch.ones(2, 1, 3), torch.ones(3, 1, 3), torch.ones(3))
    with pytest.raises(ValueError, match="colors"):
        Lights(torch.ones(1, 3), torch.full((1, 3), float("nan")), torch.ones(3))
    with pytest.raises(ValueError, match="camera"):
        verts, faces = tetra()
        shade(verts, faces, torch.ones(4, 3, dtype=F64), Lights.default(), None)


def test_list_indexing_of_lights_and_views() -> None:
    assert len(Lights.default()[[0]]) == 1
    views = ViewSet.orbit([0.0, 90.0, 180.0])
    assert len(views[[0, 2]]) == 2 and len(views[torch.tensor([True, False, True])]) == 2
    with pytest.raises(TypeError, match="lights index must hold integers"):
        Lights.default()[[0.5]]
    with pytest.raises(IndexError, match="camera index \\[5\\] out of range"):
        views[[5]]
    with pytest.raises(ValueError, match="selects no items"):
        views[[]]


def test_lights_refuse_complex_and_empty_batches() -> None:
    with pytest.raises(TypeError, match="^direction must be real"):
        Lights.single(direction=torch.tensor([0.0, 0.0, -1.0 + 1.0j]))
    with pytest.raises(ValueError, match=r"^lights must hold at least one light set \(batch size 0\)"):
        Lights(torch.ones(0, 1, 3), torch.ones(0, 1, 3), torch.ones(0, 3))


def test_huge_light_direction_is_normalised_without_overflow() -> None:
    verts = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    faces = torch.tensor([[0, 1, 2]])
    colors = torch.ones(1, 3)
    unit = shade(verts, faces, colors, Lights.single(direction=(0.0, 0.0, -1.0)), two_sided=False)
    huge = shade(verts, faces, colors, Lights.single(direction=(0.0, 0.0, -1e30)), two_sided=False)
    torch.testing.assert_close(huge, unit)
