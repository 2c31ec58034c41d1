"""A bumpy grid with a UV seam, the test mesh of the textured-surface tests."""

from __future__ import annotations

import torch


def seamed_grid(n: int, generator: torch.Generator, height: float
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """An n x n grid over [-1, 1]^2 with random heights in [0, ``height``) drawn from ``generator``, per-vertex UVs
    over [0.1, 0.9], and a UV seam: the right half of the faces read a second copy of their UVs shifted by 0.05
    (separate uv_faces rows).

    Returns:
        ``(verts (n*n, 3), faces (M, 3), uvs (2*n*n, 2), uv_faces (M, 3))``.
    """
    xs = torch.linspace(-1.0, 1.0, n)
    yy, xx = torch.meshgrid(xs, xs, indexing="ij")
    verts = torch.stack([xx, yy, height * torch.rand(n, n, generator=generator)], -1).reshape(-1, 3)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1
            faces += [[a, b, d], [a, d, c]]
    faces_t = torch.tensor(faces)
    uv = 0.1 + 0.8 * (verts[:, :2] + 1) / 2
    uvs = torch.cat([uv, uv + 0.05])
    uv_faces = faces_t.clone()
    uv_faces[verts[faces_t].mean(1)[:, 0] > 0] += verts.shape[0]
    return verts, faces_t, uvs, uv_faces
