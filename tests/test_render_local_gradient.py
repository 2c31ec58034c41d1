"""The local visibility gradient (docs/LOCAL_GRADIENT.md): NMR's sweeps truncated to the pixels nearest each edge.

* against the NumPy reference of tests/test_render_nmr_gradient.py with its ``radius`` cut, on the same scenes;
* against the rendered image itself: the gradient of one pixel within the radius is NMR's difference quotient, the
  loss change when the pixel flips over the vertex move that flips it (found by bisection on the rasterizer), and a
  pixel beyond the radius gives nothing;
* the images, the attribute gradient and the thread count: unchanged by the choice, bit for bit.
"""

from __future__ import annotations

import pytest
import torch
from test_render_nmr_gradient import check_against_reference, occluding_scene, shared_mesh_scene

from meshadv.render import Camera, Lights, native_available, rasterize, render
from meshadv.render.visibility import LOCAL_RADIUS, sweep_radius

pytestmark = pytest.mark.skipif(not native_available(), reason="meshadv._raster is not built (maturin develop)")

EPS = 1e-4  # NMR's eps, in NDC units
SIZE = 20


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_occluding_triangles_match_the_reference(seed: int) -> None:
    verts, faces, attrs = occluding_scene(seed)
    check_against_reference(verts, faces, attrs, (20, 20), seed=seed, visibility_gradient="local")


def test_batch_clipping_culling_and_orthographic_match_the_reference() -> None:
    verts, faces, attrs = occluding_scene(7, batch=2)
    check_against_reference(verts, faces, attrs, (16, 27), seed=7, visibility_gradient="local")
    verts, faces, attrs = occluding_scene(4)
    check_against_reference(verts, faces, attrs, (18, 18), near=2.2, far=4.0, seed=4, visibility_gradient="local")
    verts, faces, attrs = shared_mesh_scene()
    check_against_reference(verts, faces, attrs, (24, 24), cull=True, seed=5, visibility_gradient="local")
    verts, faces, attrs = occluding_scene(11)
    check_against_reference(verts, faces, attrs, (20, 22), near=0.0, seed=11, ortho=True,
                            visibility_gradient="local")


def _triangle() -> tuple[torch.Tensor, torch.Tensor]:
    """One triangle whose top edge (vertices 0 -> 1) crosses image column 10 at row 5.42 (a 20 x 20 image)."""
    verts = torch.tensor([[[-0.6, 0.3, 2.0], [0.6, 0.5, 2.0], [0.0, -0.7, 2.0]]])
    return verts, torch.tensor([[0, 1, 2]])


def _covered(verts: torch.Tensor, faces: torch.Tensor, pixel: tuple[int, int]) -> bool:
    out = rasterize(verts, faces, torch.ones(1, 1, 1), SIZE)
    return bool(out.face_index[0, pixel[0], pixel[1]] >= 0)


def _flip_move(verts: torch.Tensor, faces: torch.Tensor, vertex: int, pixel: tuple[int, int]) -> float:
    """The smallest upward move (NDC) of ``vertex`` that makes the triangle cover ``pixel`` (bisection)."""
    lo, hi = 0.0, 2.0
    assert not _covered(verts, faces, pixel)
    for _ in range(50):
        mid = (lo + hi) / 2
        moved = verts.clone()
        moved[0, vertex, 1] += mid
        lo, hi = (lo, mid) if _covered(moved, faces, pixel) else (mid, hi)
    return hi


def _y_gradient(verts: torch.Tensor, faces: torch.Tensor, pixel: tuple[int, int], visibility: str) -> torch.Tensor:
    """d/dy of the loss ``-I[pixel]`` (white face on black: ``delta = -1`` where the face would cover it)."""
    v = verts.clone().requires_grad_(True)
    out = rasterize(v, faces, torch.ones(1, 1, 1), SIZE, visibility_gradient=visibility)
    cot = torch.zeros_like(out.image)
    cot[0, pixel[0], pixel[1], 0] = -1.0
    (out.image * cot).sum().backward()
    assert v.grad is not None
    return v.grad[0, :, 1]


@pytest.mark.parametrize("row", [5, 5 - (LOCAL_RADIUS - 1), 5 - LOCAL_RADIUS, 1])
def test_a_pixel_s_gradient_is_nmr_s_difference_quotient_within_the_radius_and_zero_beyond(row: int) -> None:
    verts, faces = _triangle()
    pixel = (row, 10)  # the first pixel beyond the edge on column 10 is row 5 (d_out); rows above it follow
    inside = 5 - row < LOCAL_RADIUS
    nmr, local = _y_gradient(verts, faces, pixel, "nmr"), _y_gradient(verts, faces, pixel, "local")
    for vertex in (0, 1):  # the edge's two endpoints
        move = _flip_move(verts, faces, vertex, pixel)
        # The loss changes by -1 when the pixel flips: NMR's quotient delta / (move + eps).
        quotient = -1.0 / (move + EPS)
        assert float(nmr[vertex]) == pytest.approx(quotient, rel=1e-4)
        if inside:
            assert float(local[vertex]) == pytest.approx(quotient, rel=1e-4)
        else:
            assert float(local[vertex]) == 0.0
    assert float(nmr[2]) == 0.0 and float(local[2]) == 0.0  # the opposite corner does not move the edge


def _render_grads(visibility: str, num_threads: int = 0) -> tuple[torch.Tensor, ...]:
    ico = torch.tensor([[0.0, 0.9, 0.1], [0.8, -0.3, 0.2], [-0.7, -0.4, 0.3], [0.1, -0.2, -0.8], [0.0, 0.1, 0.95]])
    faces = torch.tensor([[0, 1, 4], [1, 2, 4], [2, 0, 4], [0, 3, 1], [1, 3, 2], [2, 3, 0]])
    verts = ico.clone().requires_grad_(True)
    colors = torch.rand(6, 3, generator=torch.Generator().manual_seed(1)).requires_grad_(True)
    lights = Lights.default()
    out = render(verts, faces, colors, Camera.spherical(3.0, 20.0, 15.0), lights, 48, antialias=2,
                 num_threads=num_threads, visibility_gradient=visibility)
    cot = torch.randn(out.image.shape, generator=torch.Generator().manual_seed(2))
    ((out.image * cot).sum() + out.alpha.sum()).backward()
    assert verts.grad is not None and colors.grad is not None
    return out.image.detach(), verts.grad, colors.grad


def test_the_choice_changes_only_the_vertex_gradient() -> None:
    image_n, gv_n, gc_n = _render_grads("nmr")
    image_l, gv_l, gc_l = _render_grads("local")
    assert torch.equal(image_n, image_l)
    assert torch.equal(gc_n, gc_l)  # colours: the exact attribute gradient, whichever vertex gradient
    assert gv_l.abs().sum() > 0 and not torch.equal(gv_n, gv_l)


def test_the_local_gradient_has_the_same_bits_on_one_and_two_threads() -> None:
    _, g1, _ = _render_grads("local", num_threads=1)
    _, g2, _ = _render_grads("local", num_threads=2)
    assert torch.equal(g1, g2)


def test_the_radius_follows_the_antialias_factor() -> None:
    assert sweep_radius("nmr", 3) is None
    assert sweep_radius("local") == LOCAL_RADIUS and sweep_radius("local", 3) == 3 * LOCAL_RADIUS


@pytest.mark.parametrize("bad", ["NMR", "soft", 1, None])
def test_an_unknown_visibility_gradient_is_an_error_naming_the_argument(bad: object) -> None:
    verts, faces = _triangle()
    with pytest.raises(ValueError, match="visibility_gradient"):
        rasterize(verts, faces, torch.ones(1, 1, 1), 8, visibility_gradient=bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="visibility_gradient"):
        render(verts[0], faces, torch.ones(1, 3), Camera.spherical(3.0), Lights.default(), 8,
               visibility_gradient=bad)  # type: ignore[arg-type]
