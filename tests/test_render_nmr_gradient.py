"""The Rust rasterizer against slow pure-NumPy references written here from the specification.

* forward: pixel-centre coverage, perspective-correct depth, nearest face wins (docs/ARCHITECTURE.md);
* backward: NMR's approximate vertex gradient exactly as docs/NMR_GRADIENT.md defines it, and the exact attribute
  gradient, compared with random cotangents on small images with occlusion.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from meshadv.render import native_available, rasterize
from meshadv.render.visibility import sweep_radius

pytestmark = pytest.mark.skipif(not native_available(), reason="meshadv._raster is not built (maturin develop)")

EPS = 1e-4  # NMR's eps, in NDC units


# ----------------------------------------------------------------------------- reference (NumPy, float64)
class RefFace:
    """Pixel-space set-up of one face of one batch element."""

    def __init__(self, verts: np.ndarray, face: np.ndarray, height: int, width: int, ortho: bool) -> None:
        p = verts[face].astype(np.float64)
        self.u = (p[:, 0] * width + width - 1) / 2
        self.v = (height - 1 - p[:, 1] * height) / 2
        self.z = p[:, 2]
        self.ortho = ortho
        self.signed_area = (self.u[1] - self.u[0]) * (self.v[2] - self.v[0]) - (self.v[1] - self.v[0]) * (
            self.u[2] - self.u[0]
        )

    def active(self, cull: bool) -> bool:
        if self.signed_area == 0 or not math.isfinite(self.signed_area):
            return False
        if not self.ortho and bool((self.z <= 0).any()):
            return False
        return not (cull and self.signed_area < 0)

    def weights(self, col: float, row: float) -> np.ndarray:
        u, v = self.u, self.v
        w = np.empty(3)
        for k in range(3):
            a, c = (k + 1) % 3, (k + 2) % 3
            w[k] = (u[c] - u[a]) * (row - v[a]) - (v[c] - v[a]) * (col - u[a])
        return w / self.signed_area

    def depth(self, row: int, col: int) -> float | None:
        w = self.weights(col, row)
        if self.ortho:
            z = float(w @ self.z)
            return z if math.isfinite(z) else None
        iz = float(w @ (1.0 / self.z))
        return 1.0 / iz if iz > 0 and math.isfinite(iz) else None


def ref_forward(
    verts: np.ndarray,
    faces: np.ndarray,
    height: int,
    width: int,
    near: float,
    far: float,
    cull: bool = False,
    ortho: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Face index, depth and a mask of pixels whose coverage is ambiguous (a centre within 1e-6 px of an edge)."""
    index = np.full((height, width), -1, dtype=np.int64)
    depth = np.full((height, width), far, dtype=np.float64)
    ambiguous = np.zeros((height, width), dtype=bool)
    setups = [RefFace(verts, f, height, width, ortho) for f in faces]
    for i in range(height):
        for j in range(width):
            for f, s in enumerate(setups):
                if not s.active(cull):
                    continue
                w = s.weights(j, i)
                edge_px = (
                    np.abs(w * s.signed_area)
                    / np.hypot(np.diff(np.r_[s.u, s.u[0]]), np.diff(np.r_[s.v, s.v[0]]))[[1, 2, 0]]
                )
                if (edge_px < 1e-6).any():
                    ambiguous[i, j] = True
                if (w < 0).any():
                    continue
                z = s.depth(i, j)
                if z is None or not near <= z <= far:
                    continue
                if z < depth[i, j] or index[i, j] == -1:
                    index[i, j], depth[i, j] = f, z
    return index, depth, ambiguous


def ref_backward(
    verts: np.ndarray,
    faces: np.ndarray,
    attrs: np.ndarray,
    index: np.ndarray,
    image: np.ndarray,
    grad_image: np.ndarray,
    near: float,
    far: float,
    cull: bool = False,
    ortho: bool = False,
    radius: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """docs/NMR_GRADIENT.md for one batch element: (grad_verts (N,3), grad_attrs (M,C)); with ``radius`` the local
    gradient of docs/LOCAL_GRADIENT.md (each sweep cut to the pixels within ``radius - 1`` of its first pixel)."""
    height, width = index.shape
    setups = [RefFace(verts, f, height, width, ortho) for f in faces]
    grad_attrs = np.zeros(attrs.shape, dtype=np.float64)
    for i in range(height):
        for j in range(width):
            if index[i, j] >= 0:
                grad_attrs[index[i, j]] += grad_image[i, j]
    grad_verts = np.zeros((verts.shape[0], 3), dtype=np.float64)

    def covers(f: int, row: int, col: int) -> bool:
        z = setups[f].depth(row, col)
        if z is None or not near <= z <= far:
            return False
        g = index[row, col]
        if g == -1:
            return True
        zp = setups[g].depth(row, col)
        return zp is None or z < zp or (z == zp and f < g)

    for f, s in enumerate(setups):
        if not s.active(cull):
            continue
        g = np.zeros((3, 2))  # corner k, axis (0 = x, 1 = y)
        for e in range(3):
            a, c, o = e, (e + 1) % 3, (e + 2) % 3
            for axis in ("U", "V"):
                if axis == "U":
                    p, q, n_lines, n_along, out_axis = s.u, s.v, width, height, 1

                    def pix(d0: int, d: int) -> tuple[int, int]:
                        return d, d0

                    def to_ndc(disp: float) -> float:
                        return -2.0 * disp / height
                else:
                    p, q, n_lines, n_along, out_axis = s.v, s.u, height, width, 0

                    def pix(d0: int, d: int) -> tuple[int, int]:
                        return d0, d

                    def to_ndc(disp: float) -> float:
                        return 2.0 * disp / width

                if p[a] == p[c]:
                    continue
                q_line = q[a] + (q[c] - q[a]) / (p[c] - p[a]) * (p[o] - p[a])
                direction = -1 if q[o] > q_line else 1
                lo = max(math.ceil(min(p[a], p[c])), 0)
                hi = min(math.floor(max(p[a], p[c])), n_lines - 1)
                for d0 in range(lo, hi + 1):
                    cross = q[a] + (q[c] - q[a]) / (p[c] - p[a]) * (d0 - p[a])
                    d_in = math.floor(cross) if direction > 0 else math.ceil(cross)
                    d_out = d_in + direction
                    if not (0 <= d_in <= n_along - 1 and 0 <= d_out <= n_along - 1):
                        continue

                    def contribute(d: int, delta: float, d0: int = d0, cross: float = cross) -> None:
                        t = d - cross
                        for corner, denom in ((a, p[c] - d0), (c, d0 - p[a])):
                            if denom == 0:
                                continue
                            dist = to_ndc((p[c] - p[a]) / denom * t)
                            dist = dist + EPS if dist > 0 else dist - EPS
                            g[corner, out_axis] += delta / dist

                    if index[pix(d0, d_in)] == f:
                        border = n_along - 1 if direction > 0 else 0
                        for d in range(d_out, border + direction, direction):
                            if radius is not None and abs(d - d_out) >= radius:
                                break
                            row, col = pix(d0, d)
                            if index[row, col] == f or not covers(f, row, col):
                                continue
                            delta = float(grad_image[row, col] @ (attrs[f] - image[row, col]))
                            if delta < 0:
                                contribute(d, delta)
                    if (d0 - p[a]) * (d0 - p[o]) < 0:
                        cross2 = q[a] + (q[o] - q[a]) / (p[o] - p[a]) * (d0 - p[a])
                    elif p[c] != p[o]:
                        cross2 = q[o] + (q[c] - q[o]) / (p[c] - p[o]) * (d0 - p[o])
                    else:
                        cross2 = q[o]
                    limit = math.ceil(cross2) if direction > 0 else math.floor(cross2)
                    out_pixel = image[pix(d0, d_out)]
                    for d in range(max(min(d_in, limit), 0), min(max(d_in, limit), n_along - 1) + 1):
                        row, col = pix(d0, d)
                        if radius is not None and abs(d - d_in) >= radius:
                            continue
                        if index[row, col] != f:
                            continue
                        delta = float(grad_image[row, col] @ (out_pixel - image[row, col]))
                        if delta < 0:
                            contribute(d, delta)
        for k in range(3):
            grad_verts[faces[f, k], :2] += g[k]
    return grad_verts, grad_attrs


# ----------------------------------------------------------------------------- scenes
def occluding_scene(seed: int, batch: int = 1) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A few random overlapping triangles at different depths (plus one partly off-screen), (B,N,3) screen space."""
    gen = torch.Generator().manual_seed(seed)
    m = 6
    centres = torch.rand(batch, m, 1, 2, generator=gen) * 1.2 - 0.6
    offsets = torch.randn(batch, m, 3, 2, generator=gen) * 0.45
    xy = (centres + offsets).reshape(batch, m * 3, 2)
    z = (torch.rand(batch, m, 1, generator=gen) * 3 + 1.5).expand(batch, m, 3) + torch.rand(batch, m, 3, generator=gen)
    verts = torch.cat([xy, z.reshape(batch, m * 3, 1)], dim=-1)
    verts[:, 0, :2] += 1.3  # one corner off the image
    faces = torch.arange(m * 3).reshape(m, 3)
    attrs = torch.rand(batch, m, 4, generator=gen)
    attrs[..., 3] = 1.0
    return verts.float(), faces, attrs.float()


def shared_mesh_scene() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A small closed mesh (octahedron-like) projected to screen space: shared edges and self-occlusion."""
    from meshadv.render import Camera

    verts = torch.tensor([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]) * 0.8
    verts = verts + torch.tensor([0.1, -0.05, 0.2])
    faces = torch.tensor([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    cam = Camera.spherical(3.0, 35.0, 25.0)
    screen = cam.project(verts)
    attrs = torch.rand(1, 8, 3, generator=torch.Generator().manual_seed(9))
    return screen, faces, attrs


def check_against_reference(
    verts: torch.Tensor,
    faces: torch.Tensor,
    attrs: torch.Tensor,
    size: tuple[int, int],
    near: float = 0.1,
    far: float = 100.0,
    cull: bool = False,
    seed: int = 0,
    ortho: bool = False,
    visibility_gradient: str = "nmr",
) -> None:
    """The rasterizer's outputs and gradients (``visibility_gradient``'s vertex gradient) against the references."""
    v = verts.clone().requires_grad_(True)
    a = attrs.clone().requires_grad_(True)
    bg = torch.rand(attrs.shape[-1], generator=torch.Generator().manual_seed(seed + 100))
    out = rasterize(v, faces, a, size, bg, near, far, cull, orthographic=ortho, visibility_gradient=visibility_gradient)
    cot = torch.randn(out.image.shape, generator=torch.Generator().manual_seed(seed))
    (out.image * cot).sum().backward()
    for b in range(verts.shape[0]):
        vb, fb, ab = verts[b].numpy(), faces.numpy(), attrs[b].numpy().astype(np.float64)
        index, depth, ambiguous = ref_forward(vb, fb, size[0], size[1], near, far, cull, ortho)
        got_index = out.face_index[b].numpy()
        clear = ~ambiguous
        np.testing.assert_array_equal(got_index[clear], index[clear])
        covered = clear & (index >= 0)
        np.testing.assert_allclose(out.depth[b].numpy()[covered], depth[covered], rtol=1e-5)
        np.testing.assert_allclose(out.depth[b].numpy()[clear & (index < 0)], far)
        expected_image = np.where(got_index[..., None] >= 0, ab[np.maximum(got_index, 0)], bg.numpy())
        np.testing.assert_allclose(out.image[b].detach().numpy(), expected_image, rtol=1e-6, atol=1e-7)
        gv, ga = ref_backward(
            vb,
            fb,
            ab,
            got_index,
            out.image[b].detach().numpy().astype(np.float64),
            cot[b].numpy().astype(np.float64),
            near,
            far,
            cull,
            ortho,
            sweep_radius(visibility_gradient),
        )
        assert np.abs(gv).sum() > 0, "the scene should produce a non-zero vertex gradient"
        scale = np.abs(gv).max()
        np.testing.assert_allclose(v.grad[b].numpy(), gv, rtol=1e-4, atol=1e-5 * scale)
        np.testing.assert_allclose(a.grad[b].numpy(), ga, rtol=1e-5, atol=1e-6)


# ----------------------------------------------------------------------------- tests
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_occluding_triangles_match_reference(seed: int) -> None:
    verts, faces, attrs = occluding_scene(seed)
    check_against_reference(verts, faces, attrs, (20, 20), seed=seed)


def test_batch_and_non_square_image_match_reference() -> None:
    verts, faces, attrs = occluding_scene(7, batch=2)
    check_against_reference(verts, faces, attrs, (16, 27), seed=7)


def test_near_far_clipping_matches_reference() -> None:
    verts, faces, attrs = occluding_scene(4)
    check_against_reference(verts, faces, attrs, (18, 18), near=2.2, far=4.0, seed=4)


def test_closed_mesh_with_culling_matches_reference() -> None:
    verts, faces, attrs = shared_mesh_scene()
    check_against_reference(verts, faces, attrs, (24, 24), seed=3)
    check_against_reference(verts, faces, attrs, (24, 24), cull=True, seed=5)


def test_shared_edges_cover_each_pixel_once() -> None:
    # Two triangles splitting the square exactly: every pixel drawn, by the face the top-left rule assigns.
    verts = torch.tensor([[[-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [1.0, 1.0, 2.0], [-1.0, 1.0, 2.0]]])
    faces = torch.tensor([[0, 1, 2], [0, 2, 3]])
    out = rasterize(verts, faces, torch.tensor([[[1.0], [2.0]]]), (9, 9))
    assert (out.face_index >= 0).all()
    counts = torch.bincount(out.face_index.flatten(), minlength=2)
    assert counts[0] + counts[1] == 81 and abs(int(counts[0]) - int(counts[1])) == 9  # diagonal pixels go to one face


def test_orthographic_depth_matches_reference() -> None:
    verts, faces, attrs = occluding_scene(11)
    check_against_reference(verts, faces, attrs, (20, 22), near=0.0, seed=11, ortho=True)
