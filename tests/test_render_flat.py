"""The native flat render (render/flat.py) against the PyTorch composition it replaces for float32 CPU meshes.

``render`` sends float32 CPU inputs through one native op (projection, shading, raster, box filter and their
adjoint); the composition of ``Camera.project``, ``shade`` and ``rasterize`` stays the path of other dtypes and
devices. Both must give the same images bit for bit, the same vertex and colour gradients bit for bit (one copy of
the vertices per view), and camera and light gradients equal to float rounding; the light gradients are also checked
against finite differences.
"""

from __future__ import annotations

import math
from typing import Any

import pytest
import torch

import meshadv.render.renderer as renderer
from meshadv.render import Camera, Lights, native_available, render

pytestmark = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")


def _sphere(level: int = 2) -> tuple[torch.Tensor, torch.Tensor]:
    """An icosphere of radius 0.5 with a bump, so that faces have varied normals and shading."""
    t = (1 + math.sqrt(5)) / 2
    verts = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
             [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    faces = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
             [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11],
             [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    v = [torch.tensor(p, dtype=torch.float64) for p in verts]
    for _ in range(level):
        cache: dict = {}
        new_faces = []

        def mid(a: int, b: int) -> int:
            key = (min(a, b), max(a, b))
            if key not in cache:
                v.append((v[a] + v[b]) / 2)
                cache[key] = len(v) - 1
            return cache[key]

        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new_faces += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        faces = new_faces
    pts = torch.stack(v)
    bump = 0.5 + 0.05 * torch.sin(5 * pts[:, 0]) * torch.cos(3 * pts[:, 1])
    pts = pts / pts.norm(dim=1, keepdim=True) * bump.unsqueeze(1)
    return pts.float(), torch.tensor(faces)


def _render_both(**case: Any) -> dict[str, Any]:
    """Renders ``case`` through the native flat op and through the PyTorch composition; returns outputs and grads."""
    verts, faces = _sphere()
    gen = torch.Generator().manual_seed(0)
    colors = torch.rand(faces.shape[0], 3, generator=gen) * 1.2  # some clamp at 1
    views = case.pop("views", 1)
    per_view = case.pop("per_view", False)
    results = {}
    for path in ("flat", "torch"):
        original = renderer.supports_flat_render
        if path == "torch":
            renderer.supports_flat_render = lambda *args: False  # type: ignore[assignment]
        try:
            v = (verts.expand(views, -1, -1).clone() if per_view else verts.clone()).requires_grad_(True)
            c = colors.clone().requires_grad_(True)
            az = torch.tensor([30.0, 110.0, 250.0][:views], requires_grad=True)
            el = torch.tensor(25.0, requires_grad=True)
            dist = torch.tensor(2.6, requires_grad=True)
            cam = Camera.spherical(dist, az, el, viewing_angle=30.0, orthographic=case.get("ortho", False),
                                   ortho_scale=0.8)
            direction = torch.tensor([0.3, 1.0, -0.6], requires_grad=True)
            light = torch.tensor([0.5, 0.4, 0.45], requires_grad=True)
            ambient = torch.tensor([0.5, 0.45, 0.4], requires_grad=True)
            lights = Lights.single(direction, light, ambient)
            out = render(v, faces, c, cam, lights, 40, antialias=case.get("antialias", 1), num_threads=1,
                         fill_back=case.get("fill_back", True), edge_gradient=case.get("edge", 1.0),
                         visibility_gradient=case.get("visibility", "nmr"))
            g = torch.Generator().manual_seed(1)
            loss = (out.image * torch.randn(out.image.shape, generator=g)).sum()
            loss = loss + (out.alpha * torch.randn(out.alpha.shape, generator=g)).sum()
            loss.backward()
            results[path] = {"out": out, "v": v.grad, "c": c.grad, "az": az.grad, "el": el.grad, "dist": dist.grad,
                             "direction": direction.grad, "light": light.grad, "ambient": ambient.grad}
        finally:
            renderer.supports_flat_render = original  # type: ignore[assignment]
    return results


CASES = [
    {},
    {"antialias": 2, "visibility": "local"},
    {"ortho": True},
    {"fill_back": False, "antialias": 3},
    {"views": 3, "per_view": True, "edge": 0.3},
]


@pytest.mark.parametrize("case", CASES, ids=lambda c: ",".join(f"{k}={v}" for k, v in c.items()) or "default")
def test_native_flat_render_matches_the_pytorch_composition(case: dict) -> None:
    res = _render_both(**dict(case))
    flat, ref = res["flat"], res["torch"]
    for name in ("image", "alpha", "depth", "face_index"):
        assert torch.equal(getattr(flat["out"], name), getattr(ref["out"], name)), name
    assert flat["out"].image.shape == ref["out"].image.shape
    assert flat["v"].abs().max() > 0 and flat["c"].abs().max() > 0
    assert torch.equal(flat["v"], ref["v"]), float((flat["v"] - ref["v"]).abs().max())
    assert torch.equal(flat["c"], ref["c"])
    for name in ("az", "el", "direction", "light", "ambient"):
        scale = float(ref[name].abs().max())
        assert scale > 0, name
        torch.testing.assert_close(flat[name], ref[name], rtol=0, atol=1e-4 * scale, msg=name)


def test_shared_vertices_over_views_match_to_rounding() -> None:
    res = _render_both(views=3)
    flat, ref = res["flat"], res["torch"]
    assert torch.equal(flat["out"].image, ref["out"].image)
    torch.testing.assert_close(flat["v"], ref["v"], rtol=0, atol=1e-5 * float(ref["v"].abs().max()))


def test_light_gradients_match_finite_differences() -> None:
    """The image depends smoothly on the lights (no visibility change): central differences in float64 of the
    float32 render agree with the native adjoint."""
    verts, faces = _sphere(1)
    colors = torch.rand(faces.shape[0], 3, generator=torch.Generator().manual_seed(2)) * 0.9
    cam = Camera.spherical(2.6, 40.0, 20.0)
    cot = torch.randn(1, 3, 24, 24, generator=torch.Generator().manual_seed(3))

    def loss(direction: torch.Tensor, light: torch.Tensor, ambient: torch.Tensor) -> torch.Tensor:
        out = render(verts, faces, colors, cam, Lights.single(direction, light, ambient), 24, num_threads=1)
        return (out.image.double() * cot).sum()

    params = [torch.tensor([0.3, 1.0, -0.6]), torch.tensor([0.5, 0.4, 0.45]), torch.tensor([0.3, 0.25, 0.2])]
    leaves = [p.clone().requires_grad_(True) for p in params]
    loss(*leaves).backward()
    for i, leaf in enumerate(leaves):
        for j in range(3):
            h = 1e-2
            plus = [p.clone() for p in params]
            minus = [p.clone() for p in params]
            plus[i][j] += h
            minus[i][j] -= h
            fd = (loss(*plus) - loss(*minus)).item() / (2 * h)
            assert leaf.grad[j].item() == pytest.approx(fd, rel=2e-2, abs=2e-2), (i, j)


def test_the_native_op_serves_float32_and_the_composition_float64(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[str] = []
    original = renderer.flat_render
    monkeypatch.setattr(renderer, "flat_render", lambda *a, **k: calls.append("flat") or original(*a, **k))
    verts, faces = _sphere(1)
    cam, lights = Camera.spherical(2.6, 40.0, 20.0), Lights.default()
    colors = torch.full((faces.shape[0], 3), 0.6)
    flat = render(verts, faces, colors, cam, lights, 16)
    assert calls == ["flat"]
    double = render(verts.double(), faces, colors.double(), cam.to(dtype=torch.float64),
                    lights.to(dtype=torch.float64), 16)
    assert calls == ["flat"] and double.image.dtype == torch.float64
    torch.testing.assert_close(double.image.float(), flat.image, rtol=0, atol=1e-5)
    # Views of different clip ranges take the composition (one rasterize call per range).
    two = Camera.spherical(2.6, [40.0, 50.0], 20.0, far=[100.0, 50.0])
    out = render(verts, faces, colors, two, lights, 16)
    assert calls == ["flat"] and out.image.shape == (2, 3, 16, 16)


def test_any_thread_count_gives_the_same_bits() -> None:
    verts, faces = _sphere(1)
    colors = torch.rand(faces.shape[0], 3, generator=torch.Generator().manual_seed(4))
    cam = Camera.spherical(2.6, [10.0, 130.0, 250.0], 20.0)
    grads = []
    for threads in (1, 2, 3):
        v = verts.expand(3, -1, -1).clone().requires_grad_(True)
        c = colors.clone().requires_grad_(True)
        out = render(v, faces, c, cam, Lights.default(cam), 32, antialias=2, num_threads=threads)
        (out.image.sum() + out.alpha.mean()).backward()
        grads.append((out.image, v.grad, c.grad))
    for other in grads[1:]:
        assert all(torch.equal(a, b) for a, b in zip(grads[0], other))


def test_the_native_op_names_a_bad_argument() -> None:
    import numpy as np

    from meshadv.render.rasterize import _native

    verts, faces = _sphere(0)
    f32 = np.float32
    args = {
        "verts": verts.unsqueeze(0).numpy(), "faces": faces.int().numpy(),
        "face_colors": np.full((1, faces.shape[0], 3), 0.5, f32), "rotation": np.eye(3, dtype=f32)[None],
        "eye": np.array([[0.0, 0.0, -3.0]], f32), "scale": np.array([0.27], f32),
        "light_directions": np.array([[[0.0, 0.0, -1.0]]], f32), "light_colors": np.full((1, 1, 3), 0.5, f32),
        "ambient": np.full((1, 3), 0.5, f32), "background": np.ones(3, f32),
    }
    scalars = (1, 16, 16, 1, 0.1, 100.0, True, False)
    image = _native().flat_render_forward(*args.values(), *scalars)[0]
    assert image.shape == (1, 16, 16, 4) and image[..., 3].max() == 1.0
    for name, bad, match in [
        ("face_colors", np.full((1, faces.shape[0] + 1, 3), 0.5, f32), "face_colors"),
        ("scale", np.array([0.0], f32), "scale"),
        ("eye", np.array([[0.0, np.nan, -3.0]], f32), "eye"),
        ("eye", np.array([[0.0, 0.0, 300.0]], f32), "camera: all geometry is behind"),
    ]:
        with pytest.raises(ValueError, match=match):
            _native().flat_render_forward(*{**args, name: bad}.values(), *scalars)
    with pytest.raises(TypeError, match="verts"):
        _native().flat_render_forward(*{**args, "verts": args["verts"].astype(np.float64)}.values(), *scalars)
