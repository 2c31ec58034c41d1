"""The Blinn-Phong specular term of render_surface (smooth shading): its value where it is known in closed form, its
exact gradients to vertices, normals, colours and lights against float64 central differences, and bad arguments."""

from __future__ import annotations

from typing import Callable

import pytest
import torch

from meshadv.render import Camera, Lights, native_available, render_surface

pytestmark = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")


def _grid(n: int = 5, extent: float = 3.0) -> tuple[torch.Tensor, torch.Tensor]:
    """An n x n grid over [-extent, extent]^2 in the z = 0 plane (larger than the view: no silhouette in the image),
    float64, with small smooth heights."""
    xs = torch.linspace(-extent, extent, n, dtype=torch.float64)
    yy, xx = torch.meshgrid(xs, xs, indexing="ij")
    zz = 0.15 * torch.sin(1.3 * xx) * torch.cos(0.9 * yy)
    verts = torch.stack([xx, yy, zz], -1).reshape(-1, 3)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1
            faces += [[a, b, d], [a, d, c]]
    return verts, torch.tensor(faces)


def test_a_plane_lit_along_the_view_gets_the_full_highlight_everywhere() -> None:
    verts, faces = _grid()
    verts[:, 2] = 0.0
    camera = Camera.look_at([0.0, 0.0, 4.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], orthographic=True)
    lights = Lights([[[0.0, 0.0, 1.0]]], [[[0.5, 0.4, 0.3]]], [[0.2, 0.2, 0.2]])
    colors = torch.full((verts.shape[0], 3), 0.5, dtype=torch.float64)
    kw = dict(vertex_colors=colors, shading="smooth", background=(0.0, 0.0, 0.0))
    plain = render_surface(verts, faces, camera, lights, 16, **kw).image
    shiny = render_surface(verts, faces, camera, lights, 16, specular=0.6, shininess=7.0, **kw).image
    # h = n = the light = the view: the highlight is specular * c at every pixel, on top of Lambert
    expect = 0.5 * (0.2 + torch.tensor([0.5, 0.4, 0.3], dtype=torch.float64)) + 0.6 * torch.tensor([0.5, 0.4, 0.3])
    torch.testing.assert_close(shiny[0].permute(1, 2, 0), expect.expand(16, 16, 3).to(shiny.dtype))
    torch.testing.assert_close(plain, render_surface(verts, faces, camera, lights, 16, specular=0.0, **kw).image,
                               rtol=0, atol=0)
    assert float((shiny - plain).min()) > 0.17  # 0.6 x the weakest channel, 0.3


def _scene() -> tuple[Camera, Lights]:
    camera = Camera.look_at([0.4, -0.3, 3.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    lights = Lights(torch.tensor([[[0.3, 0.5, 1.0], [-0.6, 0.2, 0.8]]], dtype=torch.float64),
                    torch.tensor([[[0.3, 0.25, 0.2], [0.2, 0.2, 0.25]]], dtype=torch.float64),
                    torch.tensor([[0.1, 0.1, 0.1]], dtype=torch.float64))
    return camera, lights


def _loss(verts: torch.Tensor, faces: torch.Tensor, colors: torch.Tensor, normals: torch.Tensor | None,
          lights: Lights, weights: torch.Tensor) -> torch.Tensor:
    camera, _ = _scene()
    out = render_surface(verts, faces, camera, lights, 12, vertex_colors=colors, normals=normals, shading="smooth",
                         specular=0.4, shininess=5.0, edge_gradient=0.0)
    return (out.image * weights).sum()


def _central(f: Callable[[torch.Tensor], torch.Tensor], x: torch.Tensor, eps: float = 1e-3) -> torch.Tensor:
    """Central differences of ``f`` at ``x`` (eps 1e-3: the native rasterizer's single-precision steps make the
    error grow as 1/eps below that; the second-order error at 1e-3 is far below the tolerance)."""
    grad = torch.zeros_like(x)
    flat = x.detach().clone().reshape(-1)
    for i in range(flat.numel()):
        hi, lo = flat.clone(), flat.clone()
        hi[i] += eps
        lo[i] -= eps
        grad.view(-1)[i] = (f(hi.reshape(x.shape)) - f(lo.reshape(x.shape))) / (2 * eps)
    return grad


def test_specular_gradients_match_central_differences() -> None:
    verts, faces = _grid()
    _, lights = _scene()
    g = torch.Generator().manual_seed(0)
    colors = 0.2 + 0.2 * torch.rand(verts.shape[0], 3, generator=g, dtype=torch.float64)
    weights = torch.rand(1, 3, 12, 12, generator=g, dtype=torch.float64)
    normals = torch.nn.functional.normalize(torch.tensor([0.1, 0.2, 1.0], dtype=torch.float64)
                                            + 0.2 * torch.rand(verts.shape[0], 3, generator=g, dtype=torch.float64),
                                            dim=1)
    with torch.no_grad():
        image = render_surface(verts, faces, _scene()[0], lights, 12, vertex_colors=colors, shading="smooth",
                               specular=0.4, shininess=5.0).image
    assert float(image.max()) < 0.99  # no clamped pixel: the image is smooth in every input
    for name in ("vertices", "normals", "colors", "directions"):
        args = {"vertices": verts, "normals": normals, "colors": colors, "directions": lights.directions}
        x = args[name].clone().requires_grad_(True)

        def f(value: torch.Tensor, name: str = name) -> torch.Tensor:
            a = {**args, name: value}
            lit = Lights(a["directions"], lights.colors, lights.ambient)
            return _loss(a["vertices"], faces, a["colors"], a["normals"] if name == "normals" else None, lit,
                         weights)

        f(x).backward()
        with torch.no_grad():
            numeric = _central(f, x)
        torch.testing.assert_close(x.grad, numeric, rtol=1e-3, atol=5e-4, msg=name)
        assert float(x.grad.abs().max()) > 1e-3, name


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"specular": -0.1}, "specular"),
    ({"specular": float("nan")}, "specular"),
    ({"shininess": 0.5}, "shininess"),
    ({"specular": 0.5, "shading": "flat"}, "specular needs shading='smooth'"),
])
def test_bad_specular_arguments_are_errors_naming_them(kwargs: dict, message: str) -> None:
    verts, faces = _grid(3)
    camera, lights = _scene()
    with pytest.raises(ValueError, match=message):
        render_surface(verts, faces, camera, lights, 8, vertex_colors=torch.ones(9, 3, dtype=torch.float64),
                       **{"shading": "smooth", **kwargs})
