"""The antialias box filter of the renderer (render/renderer.py ``_downsample``: the native kernels for float32,
``avg_pool2d`` otherwise): torch's ``avg_pool2d`` bit for bit forward and backward, and renders unchanged."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from meshadv.render import native_available
from meshadv.render.renderer import _BoxDownsample, _downsample


needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")


@needs_native
@pytest.mark.parametrize("k", [2, 3, 4, 5])
@pytest.mark.parametrize("channels", [1, 3, 4])
def test_box_filter_equals_avg_pool2d_forward_and_backward(k: int, channels: int) -> None:
    gen = torch.Generator().manual_seed(k)
    # Values of many magnitudes, so that the order of the additions shows in the bits.
    image = torch.rand(3, 5 * k, 7 * k, channels, generator=gen) * 10.0 ** torch.randint(-6, 7, (1,), generator=gen)
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


@needs_native
def test_the_native_spread_is_the_adjoint_of_the_filter_for_any_thread_count() -> None:
    # <filter(x), g> == <x, spread(g)> in float64 arithmetic, and the thread count does not change a bit.
    gen = torch.Generator().manual_seed(7)
    x = torch.rand(2, 12, 9, 4, generator=gen)
    g = torch.randn(2, 4, 4, 3, generator=gen)
    y = _BoxDownsample.apply(x, 3, 1)
    xr = x.clone().requires_grad_(True)
    _BoxDownsample.apply(xr, 3, 2).backward(g)
    assert torch.equal(_BoxDownsample.apply(x, 3, 2), y)
    lhs = float((y.double() * g.double()).sum())
    rhs = float((x.double() * xr.grad.double()).sum())
    assert abs(lhs - rhs) <= 1e-6 * (1.0 + abs(lhs))


def test_float64_images_go_through_avg_pool2d_with_its_gradient() -> None:
    image = torch.rand(2, 6, 4, 3, dtype=torch.float64, requires_grad=True)
    assert torch.equal(_downsample(image, 2), F.avg_pool2d(image.permute(0, 3, 1, 2), 2, 2))
    assert torch.autograd.gradcheck(lambda t: _downsample(t, 2), (image,))


@needs_native
@pytest.mark.parametrize(
    ("shape", "k", "arg"),
    [
        ((1, 5, 4, 1), 2, "image"),
        ((1, 2, 0, 1), 2, "image"),
        ((1, 2, 2, 0), 2, "image"),
        ((1, 4, 4, 1), 0, "k"),
        ((1, 4, 4, 1), 65, "k"),
        ((1, 4, 4, 1), -2, "k"),
    ],
)
def test_bad_box_filter_input_names_the_argument(shape: tuple[int, ...], k: int, arg: str) -> None:
    from meshadv.render.rasterize import _native

    with pytest.raises(ValueError, match=f"^{arg}:"):
        _native().box_downsample(np.zeros(shape, dtype=np.float32), k)
    if arg == "k" or 0 in shape:  # (a cotangent of any non-empty size can be spread)
        with pytest.raises(ValueError, match="^k:" if arg == "k" else "^grad:"):
            _native().box_spread(np.zeros(shape, dtype=np.float32), k)
    with pytest.raises(ValueError, match="^grad:"):
        _native().box_spread(np.zeros((1, 4, 4), dtype=np.float32), 2)


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
            module._downsample = lambda t, k, num_threads=0: F.avg_pool2d(  # type: ignore[assignment]
                t.permute(0, 3, 1, 2), k, k
            )
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
