"""Textured and smooth-shaded rendering (meshadv.render.surface): against an independent NumPy reference (images and,
by float64 finite differences of it, gradients to texels, UVs, normals and vertices), the flat path as a special
case, and bad input."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import surface_reference as ref
from seamed_grid import seamed_grid
from meshadv.render import Camera, Lights, native_available, render
from meshadv.render.surface import render_surface, vertex_normals

pytestmark = pytest.mark.skipif(not native_available(), reason="the native module meshadv._raster is not built")


def _bumpy_grid(n: int = 5, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """An n x n grid with random heights up to 0.25 and a UV seam (:func:`seamed_grid.seamed_grid`)."""
    return seamed_grid(n, torch.Generator().manual_seed(seed), 0.25)


def _scene(seed: int = 0) -> dict:
    verts, faces, uvs, uv_faces = _bumpy_grid(seed=seed)
    g = torch.Generator().manual_seed(seed + 1)
    return dict(
        vertices=verts.double(),
        faces=faces,
        uvs=uvs.double(),
        uv_faces=uv_faces,
        texture=torch.rand(6, 7, 3, generator=g, dtype=torch.float64),
        camera=Camera.spherical(3.0, azimuth=20.0, elevation=25.0).to(dtype=torch.float64),
        lights=Lights(
            directions=torch.tensor([[0.3, 0.8, -1.0], [-1.0, 0.2, -0.5]], dtype=torch.float64),
            colors=torch.tensor([[0.5, 0.4, 0.3], [0.2, 0.3, 0.4]], dtype=torch.float64),
            ambient=torch.tensor([0.3, 0.3, 0.3], dtype=torch.float64),
        ),
    )


def _reference(
    s: dict, face_index: np.ndarray, size: int, wrap: str = "repeat", **override: torch.Tensor
) -> np.ndarray:
    """The NumPy reference image for scene ``s`` (float64), optionally with some tensors replaced."""
    s = {**s, **override}
    verts = s["vertices"].detach()
    screen = s["camera"].project(verts)[0].numpy()
    faces = s["faces"].numpy()
    normals = override.get("normals", vertex_normals(verts, s["faces"])[0]).detach().numpy()
    fn = np.cross(
        verts.numpy()[faces[:, 1]] - verts.numpy()[faces[:, 0]], verts.numpy()[faces[:, 2]] - verts.numpy()[faces[:, 0]]
    )
    eye = s["camera"].eye()[0].numpy()
    flip = np.where(np.einsum("ij,ij->i", fn, eye - verts.numpy()[faces[:, 0]]) < 0, -1.0, 1.0)
    lights = s["lights"]
    return ref.render(
        screen,
        faces,
        face_index,
        s["uvs"].detach().numpy(),
        s["uv_faces"].numpy(),
        s["texture"].detach().numpy(),
        normals,
        faces,
        flip,
        (lights.directions[0].detach().numpy(), lights.colors[0].detach().numpy(), lights.ambient[0].detach().numpy()),
        np.ones(3),
        wrap,
    )


def _render(s: dict, size: int, **kw: object) -> object:
    return render_surface(
        s["vertices"],
        s["faces"],
        s["camera"],
        s["lights"],
        size,
        texture=s["texture"],
        uvs=s["uvs"],
        uv_faces=s["uv_faces"],
        shading="smooth",
        **kw,
    )


@pytest.mark.parametrize("wrap", ["repeat", "clamp"])
def test_a_textured_smooth_render_matches_the_numpy_reference(wrap: str) -> None:
    s, size = _scene(), 40
    out = _render(s, size, wrap=wrap)
    fi = out.face_index[0].numpy()
    screen = s["camera"].project(s["vertices"])[0].numpy()
    brute = ref.nearest_faces(screen, s["faces"].numpy(), size, size, 0.1, 100.0)
    assert (brute == fi).mean() > 0.99  # the same faces (pixels on an edge may go either way)
    assert (fi >= 0).mean() > 0.3
    want = _reference(s, fi, size, wrap)
    got = torch.cat([out.image, out.alpha], 1)[0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(got, want, atol=2e-5)


def _fd_check(
    s: dict,
    name: str,
    size: int,
    g: np.ndarray,
    fi: np.ndarray,
    analytic: np.ndarray,
    picks: np.ndarray,
    h: float = 1e-5,
) -> None:
    """Central differences of the NumPy reference's loss ``sum(g * image)`` in float64 at entries ``picks``."""
    base = s[name].detach().clone()
    for flat in picks:
        plus, minus = base.clone(), base.clone()
        plus.view(-1)[flat] += h
        minus.view(-1)[flat] -= h
        lp = float((g * _reference(s, fi, size, **{name: plus})).sum())
        lm = float((g * _reference(s, fi, size, **{name: minus})).sum())
        fd = (lp - lm) / (2 * h)
        assert abs(fd - analytic.reshape(-1)[flat]) <= 2e-3 * max(1.0, abs(fd)), (
            name,
            flat,
            fd,
            analytic.reshape(-1)[flat],
        )


def test_gradients_to_texels_uvs_and_vertices_match_the_numpy_reference() -> None:
    s, size = _scene(seed=3), 24
    for key in ("vertices", "uvs", "texture"):
        s[key] = s[key].clone().requires_grad_(True)
    out = _render(s, size, edge_gradient=0.0)
    fi = out.face_index[0].numpy()
    # The cotangent only on pixels whose 3 x 3 neighbourhood shows one face: moving a vertex by h changes no
    # coverage there, so finite differences see the interior gradient alone (edge_gradient=0 removes NMR's).
    interior = np.zeros_like(fi, dtype=bool)
    pad = np.pad(fi, 1, constant_values=-2)
    interior[:] = fi >= 0
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            interior &= pad[1 + di : 1 + di + size, 1 + dj : 1 + dj + size] == fi
    assert interior.sum() > 50
    rng = np.random.default_rng(0)
    g = rng.uniform(-1, 1, (size, size, 4)) * interior[..., None]
    g[..., 3] = 0.0
    loss = (torch.cat([out.image, out.alpha], 1)[0].permute(1, 2, 0) * torch.from_numpy(g)).sum()
    loss.backward()
    for name in ("texture", "uvs", "vertices"):
        analytic = s[name].grad.numpy()
        nonzero = np.flatnonzero(np.abs(analytic) > 1e-6)
        assert nonzero.size > 0, name
        picks = rng.choice(nonzero, size=min(12, nonzero.size), replace=False)
        _fd_check(
            {k: (v.detach() if isinstance(v, torch.Tensor) else v) for k, v in s.items()},
            name,
            size,
            g,
            fi,
            analytic,
            picks,
            h=1e-6 if name == "vertices" else 1e-5,
        )


def test_gradients_to_given_normals_match_the_numpy_reference() -> None:
    s, size = _scene(seed=5), 20
    normals = vertex_normals(s["vertices"], s["faces"])[0].clone().requires_grad_(True)
    out = _render(s, size, normals=normals)
    fi = out.face_index[0].numpy()
    rng = np.random.default_rng(1)
    g = rng.uniform(-1, 1, (size, size, 4))
    (torch.cat([out.image, out.alpha], 1)[0].permute(1, 2, 0) * torch.from_numpy(g)).sum().backward()
    analytic = normals.grad.numpy()
    base = normals.detach()
    for flat in rng.choice(np.flatnonzero(np.abs(analytic) > 1e-6), size=8, replace=False):
        plus, minus = base.clone(), base.clone()
        plus.view(-1)[flat] += 1e-6
        minus.view(-1)[flat] -= 1e-6
        fd = float((g * (_reference(s, fi, size, normals=plus) - _reference(s, fi, size, normals=minus))).sum()) / 2e-6
        assert abs(fd - analytic.reshape(-1)[flat]) <= 2e-3 * max(1.0, abs(fd)), (flat, fd, analytic.reshape(-1)[flat])


def test_per_face_vertex_colours_with_flat_shading_are_the_flat_render() -> None:
    # A soup (every face its own vertices) coloured per face: the same image as the per-face path, and the same
    # vertex gradient (the interior term vanishes: the weights sum to one), up to float rounding.
    verts, faces, _, _ = _bumpy_grid(4, seed=2)
    soup = verts[faces].reshape(-1, 3).clone()
    soup_faces = torch.arange(soup.shape[0]).reshape(-1, 3)
    colors = torch.rand(faces.shape[0], 3, generator=torch.Generator().manual_seed(4))
    camera, lights = Camera.spherical(3.0, azimuth=-30.0, elevation=20.0), Lights.default()
    a = soup.clone().requires_grad_(True)
    b = soup.clone().requires_grad_(True)
    flat = render(a, soup_faces, colors, camera, lights, 48)
    surf = render_surface(
        b, soup_faces, camera, lights, 48, vertex_colors=colors.repeat_interleave(3, 0), shading="flat"
    )
    torch.testing.assert_close(surf.image, flat.image, atol=2e-6, rtol=0)
    torch.testing.assert_close(surf.alpha, flat.alpha)
    assert torch.equal(surf.face_index, flat.face_index)
    g = torch.rand(flat.image.shape, generator=torch.Generator().manual_seed(5))
    (flat.image * g).sum().backward()
    (surf.image * g).sum().backward()
    assert a.grad.abs().max() > 0
    torch.testing.assert_close(b.grad, a.grad, atol=1e-3 * float(a.grad.abs().max()), rtol=0)


def test_the_local_visibility_gradient_of_a_flat_image_is_the_flat_local_one() -> None:
    verts, faces, _, _ = _bumpy_grid(4, seed=6)
    soup = verts[faces].reshape(-1, 3).clone()
    soup_faces = torch.arange(soup.shape[0]).reshape(-1, 3)
    colors = torch.rand(faces.shape[0], 3, generator=torch.Generator().manual_seed(8))
    camera, lights = Camera.spherical(3.0, azimuth=40.0, elevation=10.0), Lights.default()
    grads = []
    for surface in (False, True):
        v = soup.clone().requires_grad_(True)
        if surface:
            out = render_surface(
                v,
                soup_faces,
                camera,
                lights,
                40,
                vertex_colors=colors.repeat_interleave(3, 0),
                shading="flat",
                visibility_gradient="local",
                edge_gradient=0.5,
            )
        else:
            out = render(v, soup_faces, colors, camera, lights, 40, visibility_gradient="local", edge_gradient=0.5)
        out.image.sum().backward()
        grads.append(v.grad)
    assert grads[0].abs().max() > 0
    torch.testing.assert_close(grads[1], grads[0], atol=1e-3 * float(grads[0].abs().max()), rtol=0)


def test_the_texture_gradient_is_the_same_for_any_thread_count() -> None:
    s = _scene(seed=7)
    grads = []
    for threads in (1, 3):
        tex = s["texture"].float().clone().requires_grad_(True)
        out = render_surface(
            s["vertices"].float(),
            s["faces"],
            s["camera"].to(dtype=torch.float32),
            s["lights"].to(dtype=torch.float32),
            32,
            texture=tex,
            uvs=s["uvs"].float(),
            uv_faces=s["uv_faces"],
            num_threads=threads,
            antialias=2,
        )
        out.image.sum().backward()
        grads.append(tex.grad)
    assert torch.equal(grads[0], grads[1])


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (dict(texture=torch.zeros(0, 4, 3)), "texture"),
        (dict(texture=torch.full((4, 4, 3), float("nan"))), "texture contains NaN"),
        (dict(texture=torch.zeros(4, 4)), "texture must have shape"),
        (dict(uvs=torch.full((25, 2), float("nan"))), "uvs contains NaN"),
        (dict(uvs=torch.full((25, 2), 1e30)), r"uvs must lie within \+-1e\+06"),
        (dict(uvs=torch.zeros(3, 2)), "uv_faces holds rows"),
        (dict(uv_faces=torch.zeros(5, 3, dtype=torch.long)), "uv_faces must have shape"),
        (dict(shading="phong"), "shading"),
        (dict(wrap="mirror"), "wrap"),
        (dict(visibility_gradient="soft"), "visibility_gradient"),
        (dict(vertex_colors=torch.zeros(7, 3)), "vertex_colors must have one row per vertex"),
        (dict(normals=torch.zeros(3, 3), normal_faces=None), "normals must have one row per vertex"),
    ],
)
def test_bad_surface_input_is_an_error_naming_the_field(change: dict, message: str) -> None:
    s = _scene()
    args = dict(texture=s["texture"], uvs=s["uvs"], uv_faces=s["uv_faces"])
    args.update(change)
    with pytest.raises(ValueError, match=message):
        render_surface(s["vertices"], s["faces"], s["camera"], s["lights"], 16, **args)


def test_the_native_texture_backward_checks_the_forwards_planes_and_inputs() -> None:
    import meshadv._raster as native

    verts = np.array([[[-0.8, -0.8, 2.0], [0.8, -0.8, 2.0], [-0.8, 0.8, 2.0]]], dtype=np.float32)
    faces = np.array([[0, 1, 2]], dtype=np.int32)
    uvs = np.array([[[0.1, 0.2], [0.9, 0.3], [0.4, 0.8]]], dtype=np.float32)
    texture = np.random.default_rng(0).random((1, 4, 5, 3), dtype=np.float32)
    face_index = native.rasterize_forward(
        verts, faces, np.zeros((1, 1, 1), np.float32), np.zeros(1, np.float32), 8, 8, 0.1, 10.0, False
    )[1]
    image, planes = native.sample_uv_texture(verts, faces, face_index, faces, uvs, texture, 0.1, 10.0)
    assert image.shape == (1, 8, 8, 3) and image.any()
    grad = np.ones_like(image)
    gt, guv, gv = native.sample_uv_texture_backward(planes, face_index, texture, grad)
    assert gt.shape == texture.shape and guv.shape == uvs.shape and gv.shape == verts.shape
    # Each drawn pixel's bilinear weights sum to 1: the texel gradient of an all-ones cotangent sums to the
    # drawn pixels times the channels.
    assert np.isclose(gt.sum(), 3 * (face_index >= 0).sum(), rtol=1e-5)
    with pytest.raises(TypeError, match="planes"):
        native.sample_uv_texture_backward(object(), face_index, texture, grad)
    with pytest.raises(ValueError, match="texture"):
        native.sample_uv_texture_backward(planes, face_index, texture[:, :3].copy(), grad)
    with pytest.raises(ValueError, match="face_index"):
        native.sample_uv_texture_backward(planes, face_index[:, :4].copy(), texture, grad[:, :4].copy())
