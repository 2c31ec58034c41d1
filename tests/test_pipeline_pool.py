"""The antialias box filter of the renderer (render/renderer.py ``_BoxDownsample``): torch's ``avg_pool2d`` bit for
bit, its gradient numerically, and renders unchanged."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from meshadv.render import native_available
from meshadv.render.renderer import _BoxDownsample, _downsample


@pytest.mark.parametrize("k", [2, 3, 4])
@pytest.mark.parametrize("channels", [1, 4])
def test_box_filter_equals_avg_pool2d_forward_and_backward(k: int, channels: int) -> None:
    gen = torch.Generator().manual_seed(k)
    image = torch.rand(3, 5 * k, 7 * k, channels, generator=gen)
    a = image.clone().requires_grad_(True)
    b = image.clone().requires_grad_(True)
    ref = F.avg_pool2d(a.permute(0, 3, 1, 2), k, k)
    out = _downsample(b, k)
    assert out.shape == ref.shape == (3, channels, 5, 7)
    assert out.stride() == ref.stride()  # the victim sees the same (channels-last) layout
    assert torch.equal(out, ref)
    grad = torch.randn(ref.shape, generator=gen)
    ref.backward(grad)
    out.backward(grad)
    assert b.grad.is_contiguous()
    assert torch.equal(b.grad, a.grad)


def test_box_filter_gradcheck() -> None:
    image = torch.rand(2, 6, 4, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: _BoxDownsample.apply(t, 2), (image,))
    assert torch.autograd.gradcheck(lambda t: _BoxDownsample.apply(t, 3), (torch.rand(1, 6, 9, 2, dtype=torch.float64,
                                                                                        requires_grad=True),))


def test_box_filter_identity_at_k1() -> None:
    image = torch.rand(2, 4, 5, 3)
    assert torch.equal(_downsample(image, 1), image.permute(0, 3, 1, 2))


@pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")
def test_antialiased_render_equals_avg_pool_of_the_supersampled_raster() -> None:
    """``render(antialias=2)`` is the 2x2 average of the raster at twice the size, values and vertex gradients."""
    from meshadv.mesh import builtin_mesh
    from meshadv.render import ViewSet, render
    from meshadv.render import renderer as module

    mesh = builtin_mesh("chair")
    views = ViewSet.orbit([30.0, 100.0], elevation=20.0, distance=2.6)
    results = []
    for pool in ("box", "avg_pool2d"):
        verts = mesh.vertices.clone().requires_grad_(True)
        original = module._downsample
        if pool == "avg_pool2d":
            module._downsample = lambda t, k: F.avg_pool2d(t.permute(0, 3, 1, 2), k, k)  # type: ignore[assignment]
        try:
            out = render(verts, mesh.faces, mesh.face_colors, views.camera, views.lights, 40, antialias=2)
        finally:
            module._downsample = original  # type: ignore[assignment]
        (out.image * torch.linspace(0, 1, 40)).sum().backward()
        results.append((out.image.detach(), out.alpha.detach(), verts.grad))
    (img_a, alpha_a, grad_a), (img_b, alpha_b, grad_b) = results
    assert torch.equal(img_a, img_b) and torch.equal(alpha_a, alpha_b)
    assert float(grad_b.abs().max()) > 0
    assert torch.equal(grad_a, grad_b)
