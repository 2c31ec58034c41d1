"""``render`` / ``render_silhouette``: outputs, batching, anti-aliasing, validation and gradients."""

from __future__ import annotations

from typing import Callable

import pytest
import torch
import trimesh

from meshadv.render import Camera, Lights, ViewSet, native_available, render, render_silhouette

pytestmark = pytest.mark.skipif(not native_available(), reason="meshadv._raster is not built (maturin develop)")
F64 = torch.float64


def icosphere(subdivisions: int = 1, dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit icosphere by midpoint subdivision of an icosahedron (trimesh's construction)."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    return torch.tensor(sphere.vertices, dtype=dtype), torch.tensor(sphere.faces, dtype=torch.int64)


def test_outputs_are_consistent() -> None:
    verts, faces = icosphere(1)
    colors = torch.rand(faces.shape[0], 3, generator=torch.Generator().manual_seed(0))
    cam = Camera.spherical(3.0, 30.0, 20.0)
    out = render(verts * 0.6, faces, colors, cam, Lights.default(cam), 32, background=(0.2, 0.4, 0.6))
    assert out.image.shape == (1, 3, 32, 32) and out.alpha.shape == (1, 1, 32, 32)
    assert out.depth.shape == (1, 32, 32) and out.face_index.dtype == torch.int64
    covered = out.face_index >= 0
    assert 0.1 < covered.float().mean() < 0.9
    torch.testing.assert_close(out.alpha[:, 0], covered.float())
    bg = out.image.permute(0, 2, 3, 1)[~covered]
    torch.testing.assert_close(bg, torch.tensor([0.2, 0.4, 0.6]).expand_as(bg))
    assert out.image.min() >= 0 and out.image.max() <= 1
    assert (out.depth[covered] > 3.0 - 0.6 - 1e-4).all() and (out.depth[covered] < 3.0).all()  # front half only
    sil = render_silhouette(verts * 0.6, faces, cam, 32)
    torch.testing.assert_close(sil, out.alpha)


def test_shading_is_lambert_with_two_sided_normals() -> None:
    # A single quad facing the camera, seen from the front and from the back (fill_back flips the normal).
    verts = torch.tensor([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.0], [-0.5, 0.5, 0.0]])
    faces = torch.tensor([[0, 2, 1], [0, 3, 2]])  # normals -z, toward the camera at azimuth 0
    colors = torch.full((2, 3), 0.8)
    lights = Lights.single((0.0, 0.0, -1.0), (0.5, 0.25, 0.0), (0.1, 0.1, 0.1))
    front = render(verts, faces, colors, Camera.spherical(3.0, 0.0, 0.0), lights, 16)
    centre = front.image[0, :, 8, 8]
    torch.testing.assert_close(centre, torch.tensor([0.8 * 0.6, 0.8 * 0.35, 0.8 * 0.1]))
    back = render(verts, faces, colors, Camera.spherical(3.0, 180.0, 0.0), lights, 16)
    torch.testing.assert_close(back.image[0, :, 8, 8], torch.full((3,), 0.08))  # light is behind the flipped normal
    culled = render(verts, faces, colors, Camera.spherical(3.0, 180.0, 0.0), lights, 16, fill_back=False)
    assert (culled.face_index < 0).all()


def test_batch_of_views_equals_single_views() -> None:
    verts, faces = icosphere(1)
    colors = torch.rand(faces.shape[0], 3, generator=torch.Generator().manual_seed(1))
    views = ViewSet.orbit([0.0, 70.0, 200.0], elevation=[10.0, -20.0, 45.0], distance=3.0)
    views = ViewSet(Camera.cat([views.camera[:2], Camera.spherical(3.0, 200.0, 45.0, near=0.5)]), views.lights)
    batch = render(verts * 0.7, faces, colors, views.camera, views.lights, 24)
    for i in range(3):
        single = render(verts * 0.7, faces, colors, views.camera[i], views.lights[i], 24)
        torch.testing.assert_close(batch.image[i], single.image[0])
        assert torch.equal(batch.face_index[i], single.face_index[0])


def test_batch_of_meshes_with_one_camera() -> None:
    verts, faces = icosphere(1)
    meshes = torch.stack([verts * 0.5, verts * 0.8 + 0.1])
    colors = torch.rand(2, faces.shape[0], 3)
    cam = Camera.spherical(3.0, 10.0, 10.0)
    out = render(meshes, faces, colors, cam, Lights.default(), 20)
    for i in range(2):
        single = render(meshes[i], faces, colors[i], cam, Lights.default(), 20)
        torch.testing.assert_close(out.image[i], single.image[0])
    assert out.alpha[1].sum() > out.alpha[0].sum()


def test_one_mesh_in_several_colourings_renders_each_as_alone() -> None:
    # A texture attack's batch: one geometry, a colouring per target (the rasterizer draws the geometry once).
    verts, faces = icosphere(2)
    colors = torch.rand(3, faces.shape[0], 3, generator=torch.Generator().manual_seed(4)).requires_grad_(True)
    cam = Camera.spherical(3.0, 30.0, 20.0)
    cot = torch.randn(3, 3, 20, 20, generator=torch.Generator().manual_seed(5))
    out = render(verts.expand(3, -1, -1) * 0.8, faces, colors, cam, Lights.default(), 20, antialias=2)
    (out.image * cot).sum().backward()
    assert not torch.equal(out.image[0], out.image[1])
    for i in range(3):
        c = colors[i].detach().clone().requires_grad_(True)
        single = render(verts * 0.8, faces, c, cam, Lights.default(), 20, antialias=2)
        (single.image * cot[i]).sum().backward()
        assert torch.equal(out.image[i], single.image[0]) and torch.equal(out.face_index[i], single.face_index[0])
        assert torch.equal(colors.grad[i], c.grad)


def test_antialias_averages_supersamples() -> None:
    verts, faces = icosphere(1)
    cam = Camera.spherical(3.0, 0.0, 0.0)
    colors = torch.full((faces.shape[0], 3), 0.5)
    aa = render(verts * 0.6, faces, colors, cam, Lights.default(), 16, antialias=3)
    hi = render(verts * 0.6, faces, colors, cam, Lights.default(), 48)
    torch.testing.assert_close(aa.alpha, torch.nn.functional.avg_pool2d(hi.alpha, 3))
    assert ((aa.alpha > 0) & (aa.alpha < 1)).any()
    assert torch.equal(aa.face_index, hi.face_index[:, 1::3, 1::3])
    # the subsampled maps are their own int64 / float tensors, not views into the supersampled raster
    assert aa.face_index.dtype == torch.int64 and aa.face_index.is_contiguous()
    assert aa.depth.is_contiguous() and torch.equal(aa.depth, hi.depth[:, 1::3, 1::3])


def test_bad_input_raises_value_error() -> None:
    verts, faces = icosphere(0)
    colors = torch.full((20, 3), 0.5)
    cam, lights = Camera.spherical(3.0), Lights.default()
    cases = [
        ({"vertices": verts[:, :2]}, "vertices"),
        ({"vertices": verts.long()}, "vertices"),
        ({"faces": faces + 100}, "faces"),
        ({"faces": faces.float()}, "faces"),
        ({"face_colors": colors[:5]}, "face_colors"),
        ({"face_colors": colors * float("nan")}, "face_colors"),
        ({"image_size": 0}, "image_size"),
        ({"antialias": 0}, "antialias"),
        ({"background": (1.0, 1.0)}, "background"),
        (
            {
                "camera": Camera.spherical(3.0, torch.zeros(2)),
                "lights": Lights.default(Camera.spherical(3.0, [0, 0, 0])),
            },
            "batch",
        ),
        ({"vertices": verts - torch.tensor([0.0, 0.0, 10.0])}, "^camera: all geometry is behind"),
        ({"camera": Camera.spherical(3.0, far=1.0)}, "^camera: all geometry is beyond the camera's far plane"),
    ]
    for change, match in cases:
        kwargs = {
            "vertices": verts,
            "faces": faces,
            "face_colors": colors,
            "camera": cam,
            "lights": lights,
            "image_size": 16,
        }
        kwargs.update(change)
        with pytest.raises(ValueError, match=match):
            render(**kwargs)
    for change, match in [({"camera": "camera"}, "camera"), ({"lights": None}, "lights")]:
        kwargs = {"vertices": verts, "faces": faces, "face_colors": colors, "camera": cam, "lights": lights}
        kwargs.update(change)
        with pytest.raises(TypeError, match=match):
            render(**kwargs)


def fd_check(fn: Callable[..., torch.Tensor], inputs: list[torch.Tensor], eps: float, rtol: float, atol: float,
             seed: int = 0) -> None:
    """Compare autograd with central finite differences of a random linear functional of ``fn``."""
    out = fn(*inputs)
    cot = torch.randn(out.shape, generator=torch.Generator().manual_seed(seed), dtype=out.dtype)
    grads = torch.autograd.grad((out * cot).sum(), inputs)
    for x, g in zip(inputs, grads):
        fd = torch.zeros_like(x)
        flat = x.detach().reshape(-1)
        for i in range(flat.numel()):
            plus, minus = [t.detach().clone() for t in inputs], [t.detach().clone() for t in inputs]
            k = next(j for j, t in enumerate(inputs) if t is x)
            plus[k].view(-1)[i] += eps
            minus[k].view(-1)[i] -= eps
            with torch.no_grad():
                fd.view(-1)[i] = ((fn(*plus) * cot).sum() - (fn(*minus) * cot).sum()) / (2 * eps)
        torch.testing.assert_close(g, fd, rtol=rtol, atol=atol)


def test_finite_differences_colors_and_lights() -> None:
    verts, faces = icosphere(0, dtype=F64)
    cam = Camera.spherical(torch.tensor([3.0, 3.0], dtype=F64), torch.tensor([20.0, 150.0], dtype=F64), 25.0)
    gen = torch.Generator().manual_seed(4)
    colors = (torch.rand(20, 3, generator=gen, dtype=F64) * 0.5 + 0.2).requires_grad_(True)
    dirs = torch.tensor([[0.3, 1.0, -0.8], [-1.0, 0.2, 0.1]], dtype=F64, requires_grad=True)
    light_colors = torch.tensor([[0.3, 0.2, 0.25], [0.2, 0.3, 0.1]], dtype=F64, requires_grad=True)
    ambient = torch.tensor([0.3, 0.25, 0.2], dtype=F64, requires_grad=True)

    def fn(col: torch.Tensor, d: torch.Tensor, c: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        return render(verts * 0.7, faces, col, cam, Lights(d, c, a), 12).image

    fd_check(fn, [colors, dirs, light_colors, ambient], eps=1e-4, rtol=1e-3, atol=2e-4)


def test_color_gradient_through_the_clamp_is_zero_when_saturated() -> None:
    verts, faces = icosphere(0)
    colors = torch.full((20, 3), 5.0, requires_grad=True)  # every shaded colour clamps at 1
    out = render(verts * 0.7, faces, colors, Camera.spherical(3.0), Lights.default(), 12)
    assert torch.all(out.image[out.alpha.expand(-1, 3, -1, -1) > 0] == 1.0)
    out.image.sum().backward()
    assert torch.all(colors.grad == 0)


def test_camera_and_vertex_gradients_have_the_finite_difference_sign() -> None:
    verts, faces = icosphere(2)
    verts = verts * 0.6

    def coverage(distance: torch.Tensor, elevation: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
        cam = Camera.spherical(distance, 0.0, elevation)
        sil = render_silhouette(verts + shift, faces, cam, 48)
        # Weight pixels by their row so that moving the silhouette up or down changes the loss.
        rows = torch.linspace(1.0, 2.0, 48).reshape(1, 1, 48, 1)
        return (sil * rows).sum()

    d = torch.tensor(3.0, requires_grad=True)
    el = torch.tensor(0.0, requires_grad=True)
    shift = torch.zeros(3, requires_grad=True)
    loss = coverage(d, el, shift)
    loss.backward()
    with torch.no_grad():
        fd_d = (coverage(d + 0.05, el, shift) - coverage(d - 0.05, el, shift)) / 0.1
        fd_el = (coverage(d, el + 2.0, shift) - coverage(d, el - 2.0, shift)) / 4.0
        e_y = torch.tensor([0.0, 0.05, 0.0])
        fd_y = (coverage(d, el, shift + e_y) - coverage(d, el, shift - e_y)) / 0.1
    assert fd_d < 0 and d.grad < 0
    assert torch.sign(el.grad) == torch.sign(fd_el) and fd_el.abs() > 0
    assert torch.sign(shift.grad[1]) == torch.sign(fd_y) and fd_y.abs() > 0
    # No magnitude check: NMR's per-pixel term delta / distance is heavy-tailed (a pixel centre just beyond an edge
    # gives up to delta / eps), so only the direction is comparable with finite differences of a hard image.


def _edge_gradient_scene() -> tuple:
    verts, faces = icosphere(2)
    gen = torch.Generator().manual_seed(4)
    verts = verts * (0.6 + 0.05 * torch.rand(verts.shape[0], 1, generator=gen))  # a bumpy sphere: varied normals
    colors = torch.rand(faces.shape[0], 3, generator=gen)
    cam = Camera.spherical(3.0, 30.0, 20.0)
    cot = torch.randn(1, 3, 40, 40, generator=gen)
    return verts, faces, colors, cam, Lights.default(cam), cot


def _grads(edge_gradient: float) -> tuple:
    verts, faces, colors, cam, lights, cot = _edge_gradient_scene()
    v, c = verts.clone().requires_grad_(True), colors.clone().requires_grad_(True)
    out = render(v, faces, c, cam, lights, 40, edge_gradient=edge_gradient)
    (out.image * cot).sum().backward()
    return out.image.detach(), v.grad, c.grad


def test_edge_gradient_weights_only_the_rasterization_part_of_the_vertex_gradient() -> None:
    """The image and the colour gradient do not depend on ``edge_gradient``; the vertex gradient is the shading part
    plus ``w`` times NMR's rasterization part, linear in ``w``; 1 is the default render."""
    runs = {w: _grads(w) for w in (0.0, 0.4, 1.0)}
    for w in (0.0, 0.4):
        assert torch.equal(runs[w][0], runs[1.0][0])
        torch.testing.assert_close(runs[w][2], runs[1.0][2], rtol=1e-6, atol=1e-9)
    shading, full = runs[0.0][1], runs[1.0][1]
    assert float((full - shading).abs().max()) > 0.1 * float(full.abs().max()) > 0
    assert float(shading.abs().max()) > 0
    torch.testing.assert_close(runs[0.4][1], 0.6 * shading + 0.4 * full, rtol=1e-4, atol=1e-6 * float(full.abs().max()))
    verts, faces, colors, cam, lights, cot = _edge_gradient_scene()
    v = verts.clone().requires_grad_(True)
    (render(v, faces, colors, cam, lights, 40).image * cot).sum().backward()
    assert torch.equal(v.grad, full)


def test_edge_gradient_zero_is_the_derivative_with_the_fragments_held() -> None:
    """With ``edge_gradient=0`` the vertex gradient is the exact derivative of the image with every pixel's face
    held: central differences of a loss over the pixels whose face does not change under the nudge (the core
    shades in float32, so the step is 1e-3 and the tolerance 1e-3). NMR's full gradient is far from it there: it
    also credits the pixels each edge could cover."""
    verts, faces, colors, cam, lights, cot = _edge_gradient_scene()
    verts, colors, cot = verts.double(), colors.double(), cot.double()
    gen = torch.Generator().manual_seed(5)
    eps = 1e-3
    base = render(verts, faces, colors, cam, lights, 40)
    for _ in range(3):
        direction = torch.randn(verts.shape, generator=gen, dtype=F64)
        plus = render(verts + eps * direction, faces, colors, cam, lights, 40)
        minus = render(verts - eps * direction, faces, colors, cam, lights, 40)
        held = ((plus.face_index == base.face_index) & (minus.face_index == base.face_index)).unsqueeze(1)
        assert float(held.double().mean()) > 0.95
        weights = cot * held
        numeric = float(((plus.image - minus.image) * weights).sum()) / (2 * eps)
        analytic = {}
        for w in (0.0, 1.0):
            v = verts.clone().requires_grad_(True)
            (render(v, faces, colors, cam, lights, 40, edge_gradient=w).image * weights).sum().backward()
            analytic[w] = float((v.grad * direction).sum())
        assert abs(numeric) > 1.0
        assert analytic[0.0] == pytest.approx(numeric, rel=1e-3)
        assert abs(analytic[1.0] - numeric) > abs(numeric)


@pytest.mark.parametrize("value, error", [(-0.5, ValueError), (float("nan"), ValueError), (float("inf"), ValueError),
                                          ("1", TypeError), (True, TypeError)])
def test_bad_edge_gradient_is_refused_by_name(value: object, error: type) -> None:
    verts, faces, colors, cam, lights, _ = _edge_gradient_scene()
    with pytest.raises(error, match="edge_gradient"):
        render(verts, faces, colors, cam, lights, 16, edge_gradient=value)  # type: ignore[arg-type]


def test_render_setup_gives_renders_image_and_gradients() -> None:
    """``RenderSetup.render`` (every attack step) skips the depth and face-index maps but draws what ``render`` draws,
    with the same vertex gradient."""
    from meshadv.render import RenderSetup

    verts, faces = icosphere(1)
    colors = torch.rand(faces.shape[0], 3, generator=torch.Generator().manual_seed(1))
    views = ViewSet.orbit([0.0, 70.0], elevation=15.0, distance=3.0)
    cotangent = torch.randn(2, 3, 20, 20, generator=torch.Generator().manual_seed(2))
    results = []
    for use_setup in (True, False):
        v = (verts * 0.7).unsqueeze(0).requires_grad_(True)
        if use_setup:
            image, alpha = RenderSetup(image_size=20, antialias=2, background=(0.1, 0.2, 0.3)).render(
                v, faces, colors, views
            )
        else:
            out = render(v.expand(2, -1, -1), faces, colors, views.camera, views.lights, 20,
                         background=(0.1, 0.2, 0.3), antialias=2)
            image, alpha = out.image, out.alpha
        (image * cotangent).sum().backward()
        results.append((image.detach(), alpha.detach(), v.grad))
    for a, b in zip(*results):
        assert torch.equal(a, b)
    assert results[0][2].abs().sum() > 0
