"""End-to-end optimisation through the renderer: silhouette fitting of vertices and camera pose recovery."""

from __future__ import annotations


import pytest
import torch
import trimesh

from meshadv.render import Camera, native_available, render_silhouette

pytestmark = pytest.mark.skipif(not native_available(), reason="meshadv._raster is not built (maturin develop)")


def icosphere(subdivisions: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit icosphere by midpoint subdivision of an icosahedron (trimesh's construction)."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    return torch.tensor(sphere.vertices, dtype=torch.float32), torch.tensor(sphere.faces, dtype=torch.int64)


def boxes(*specs: tuple[tuple[float, float, float], tuple[float, float, float]]) -> tuple[torch.Tensor, torch.Tensor]:
    """Union (as separate shells) of axis-aligned boxes given as (centre, half extents)."""
    corners = torch.tensor([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=torch.float32)
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    verts, faces = [], []
    for i, (centre, half) in enumerate(specs):
        verts.append(corners * torch.tensor(half) + torch.tensor(centre))
        for a, b, c, d in quads:
            faces += [[8 * i + a, 8 * i + b, 8 * i + c], [8 * i + a, 8 * i + c, 8 * i + d]]
    return torch.cat(verts), torch.tensor(faces)


def iou_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """1 - soft IoU, NMR's silhouette loss."""
    inter = (pred * target).sum()
    union = (pred + target - pred * target).sum()
    return 1 - inter / union


def test_sphere_deforms_to_fit_target_silhouettes() -> None:
    verts, faces = icosphere(2)
    base = verts * 0.5
    target_verts = verts * torch.tensor([0.35, 0.6, 0.45]) + torch.tensor([0.12, -0.08, 0.05])
    cams = Camera.spherical(2.732, torch.arange(0.0, 360.0, 45.0), torch.tensor([15.0, -15.0] * 4))
    target = render_silhouette(target_verts, faces, cams, 48)
    disp = torch.zeros_like(base, requires_grad=True)
    opt = torch.optim.Adam([disp], lr=0.01)
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=60, gamma=0.3)
    losses = []
    for _ in range(120):
        opt.zero_grad()
        loss = iou_loss(render_silhouette(base + disp, faces, cams, 48), target)
        loss.backward()
        opt.step()
        sched.step()
        losses.append(float(loss.detach()))
    final = float(iou_loss(render_silhouette(base + disp.detach(), faces, cams, 48), target))
    assert final <= 0.1 * losses[0], f"loss {losses[0]:.4f} -> {final:.4f}"


@pytest.mark.parametrize(("az0", "el0"), [(42.0, 10.0), (18.0, 33.0)])
def test_camera_pose_is_recovered_from_a_mask(az0: float, el0: float) -> None:
    # An asymmetric "chair": seat, back and one leg, so the silhouette pins down the pose.
    verts, faces = boxes(
        ((0.0, 0.0, 0.0), (0.4, 0.05, 0.35)),
        ((0.0, 0.4, 0.3), (0.4, 0.35, 0.05)),
        ((0.3, -0.3, -0.25), (0.05, 0.3, 0.05)),
    )
    az_true, el_true = 30.0, 20.0
    target = render_silhouette(verts, faces, Camera.spherical(2.5, az_true, el_true), 64, antialias=2)
    az = torch.tensor(az0, requires_grad=True)
    el = torch.tensor(el0, requires_grad=True)
    opt = torch.optim.Adam([az, el], lr=1.0)
    for step in range(80):
        if step == 50:
            for group in opt.param_groups:
                group["lr"] = 0.3
        opt.zero_grad()
        pred = render_silhouette(verts, faces, Camera.spherical(2.5, az, el), 64, antialias=2)
        loss = ((pred - target) ** 2).sum()
        loss.backward()
        opt.step()
    az_fit, el_fit = float(az.detach()), float(el.detach())
    assert abs(az_fit - az_true) < 2.0 and abs(el_fit - el_true) < 2.0, (az_fit, el_fit)
