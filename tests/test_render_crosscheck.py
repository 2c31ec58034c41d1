"""Cross-checks: rasterizer vs the exact BVH ray cast, and the Python pipeline vs the Rust ``render_full``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from meshadv.render import Camera, Lights, native_available, raycast, rasterize, render

pytestmark = pytest.mark.skipif(not native_available(), reason="meshadv._raster is not built (maturin develop)")


def torus(
    rings: int = 24, segments: int = 16, r_major: float = 0.6, r_minor: float = 0.25
) -> tuple[torch.Tensor, torch.Tensor]:
    """A torus (self-occluding) with consistent winding."""
    u = torch.arange(rings) * (2 * math.pi / rings)
    v = torch.arange(segments) * (2 * math.pi / segments)
    uu, vv = torch.meshgrid(u, v, indexing="ij")
    verts = torch.stack(
        [
            (r_major + r_minor * torch.cos(vv)) * torch.cos(uu),
            r_minor * torch.sin(vv),
            (r_major + r_minor * torch.cos(vv)) * torch.sin(uu),
        ],
        -1,
    ).reshape(-1, 3)
    faces = []
    for i in range(rings):
        for j in range(segments):
            a, b = i * segments + j, ((i + 1) % rings) * segments + j
            c, d = i * segments + (j + 1) % segments, ((i + 1) % rings) * segments + (j + 1) % segments
            faces += [[a, b, d], [a, d, c]]
    return verts.float(), torch.tensor(faces)


def shared_mesh(shared_data: Path, name: str = "pascal3d/chair/01.ply") -> tuple[torch.Tensor, torch.Tensor]:
    trimesh = pytest.importorskip("trimesh")
    path = shared_data / name
    if not path.exists():
        pytest.skip(f"{path} not found")
    mesh = trimesh.load(path, process=False, force="mesh")
    verts = torch.tensor(np.asarray(mesh.vertices), dtype=torch.float32)
    verts = verts - (verts.max(0).values + verts.min(0).values) / 2
    verts = verts / verts.abs().max()
    return verts[:, [0, 2, 1]] * torch.tensor([1.0, 1.0, -1.0]), torch.tensor(np.asarray(mesh.faces), dtype=torch.int64)


def agreement(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a == b).float().mean())


CAMERAS = [
    {"distance": 2.5, "azimuth": 30.0, "elevation": 25.0},
    {"distance": 3.0, "azimuth": -100.0, "elevation": -40.0, "tilt": 20.0, "viewing_angle": 40.0},
    {"distance": 2.5, "azimuth": 60.0, "elevation": 70.0, "near": 2.3, "far": 2.9},
    {"distance": 4.0, "azimuth": 10.0, "elevation": 5.0, "orthographic": True, "ortho_scale": 1.1},
]


@pytest.mark.parametrize("cam_kwargs", CAMERAS)
def test_rasterizer_agrees_with_ray_cast(cam_kwargs: dict) -> None:
    verts, faces = torus()
    cam = Camera.spherical(**cam_kwargs)
    screen = cam.project(verts)
    out = rasterize(
        screen,
        faces,
        torch.ones(1, faces.shape[0], 1),
        (40, 48),
        None,
        float(cam.near),
        float(cam.far),
        orthographic=cam.orthographic,
    )
    ray = raycast(verts, faces, cam, (40, 48))
    assert (out.face_index >= 0).float().mean() > 0.05
    assert agreement(out.face_index, ray.face_index) > 0.995
    same = (out.face_index == ray.face_index) & (out.face_index >= 0)
    torch.testing.assert_close(out.depth[same], ray.depth[same], rtol=1e-4, atol=1e-5)


def test_rasterizer_agrees_with_ray_cast_on_a_real_mesh(shared_data: Path) -> None:
    verts, faces = shared_mesh(shared_data)
    cam = Camera.spherical(2.2, 35.0, 20.0)
    out = rasterize(cam.project(verts), faces, torch.ones(1, faces.shape[0], 1), 96)
    ray = raycast(verts, faces, cam, 96)
    assert (out.face_index >= 0).float().mean() > 0.05
    assert agreement(out.face_index, ray.face_index) > 0.99


RENDER_CASES = [
    ({"distance": 2.5, "azimuth": 30.0, "elevation": 25.0}, {}),
    (
        {"distance": 3.0, "azimuth": 200.0, "elevation": -30.0, "tilt": 35.0, "viewing_angle": 45.0},
        {"fill_back": False},
    ),
    ({"distance": 4.0, "azimuth": 80.0, "elevation": 10.0, "orthographic": True, "ortho_scale": 1.2}, {}),
    ({"distance": 2.2, "azimuth": 0.0, "elevation": 90.0}, {}),
]


@pytest.mark.parametrize(("cam_kwargs", "extra"), RENDER_CASES)
def test_python_pipeline_matches_rust_render_full(cam_kwargs: dict, extra: dict) -> None:
    import meshadv._raster as native

    verts, faces = torus()
    verts = verts + torch.tensor([0.05, 0.1, -0.05])
    colors = torch.rand(faces.shape[0], 3, generator=torch.Generator().manual_seed(0))
    dirs = torch.tensor([[0.3, 1.0, -0.5], [-1.0, -0.2, 0.4]])
    light_colors = torch.tensor([[0.5, 0.4, 0.3], [0.2, 0.3, 0.6]])
    ambient = torch.tensor([0.3, 0.35, 0.4])
    background = torch.tensor([0.1, 0.5, 0.9])
    fill_back = extra.get("fill_back", True)
    height, width = 36, 44
    cam = Camera.spherical(**cam_kwargs)
    out = render(
        verts,
        faces,
        colors,
        cam,
        Lights(dirs, light_colors, ambient),
        (height, width),
        background=background,
        fill_back=fill_back,
    )
    params = {"tilt": 0.0, "viewing_angle": 30.0, "near": 0.1, "far": 100.0, "orthographic": False, "ortho_scale": 1.0}
    params.update({k: v for k, v in cam_kwargs.items() if k not in ("distance", "azimuth", "elevation")})
    image, alpha, depth, face_index = native.render_full(
        verts.numpy(),
        faces.int().numpy(),
        colors.numpy(),
        height,
        width,
        cam_kwargs["distance"],
        cam_kwargs["azimuth"],
        cam_kwargs["elevation"],
        light_directions=dirs.numpy(),
        light_colors=light_colors.numpy(),
        ambient=ambient.numpy(),
        background=background.numpy(),
        fill_back=fill_back,
        **params,
    )
    rust_index = torch.from_numpy(face_index).long()
    assert (rust_index >= 0).float().mean() > 0.05
    assert agreement(out.face_index[0], rust_index) > 0.998
    same = out.face_index[0] == rust_index
    torch.testing.assert_close(out.image[0].permute(1, 2, 0)[same], torch.from_numpy(image)[same], atol=2e-5, rtol=0)
    torch.testing.assert_close(out.alpha[0, 0][same], torch.from_numpy(alpha)[same])
    torch.testing.assert_close(out.depth[0][same], torch.from_numpy(depth)[same], rtol=1e-5, atol=1e-5)
