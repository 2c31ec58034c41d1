"""Per-vertex mean curvature (for the paper's "perturbation vs curvature" analysis).

The mean curvature is the magnitude of the cotangent Laplace-Beltrami operator (Meyer et al. 2003):
``H_i = |sum_j (cot a_ij + cot b_ij) (v_j - v_i)| / (4 A_i)`` with ``A_i`` the mixed Voronoi area of Meyer et
al. (Voronoi region inside non-obtuse triangles; half the area at an obtuse corner, a quarter at the others).
Contributions are summed face by face, so non-manifold and inconsistently wound meshes (like PASCAL3D+'s) are
handled; the magnitude does not depend on orientation. Cotangents are clamped to
``[-COT_CLAMP, COT_CLAMP]`` so sliver triangles do not explode. On open boundaries the operator measures the
boundary's geodesic curvature as well; use :func:`meshadv.mesh.adjacency.boundary_vertex_mask` to exclude them.
"""

from __future__ import annotations

import torch

from meshadv.mesh.structure import Mesh

#: Bound on the magnitude of a cotangent weight.
COT_CLAMP = 1e3


def mean_curvature(mesh: Mesh, *, eps: float = 1e-12) -> torch.Tensor:
    """Unsigned discrete mean curvature at every vertex.

    Args:
        mesh: the mesh (any scale: curvature scales as 1 / length).
        eps: floor on the vertex area, so isolated or zero-area vertices get 0 instead of NaN.

    Returns:
        float32 ``(N,)`` tensor, ``>= 0``; about ``1 / r`` on a sphere of radius ``r``.

    Example:
        >>> h = mean_curvature(builtin_mesh("sphere"))  # doctest: +SKIP
    """
    v = mesh.vertices.detach().double()
    f = mesh.faces
    n = v.shape[0]
    tri = v[f]  # (M, 3, 3)
    laplace = torch.zeros_like(v)
    area = torch.zeros(n, dtype=v.dtype, device=v.device)
    double_area = torch.linalg.norm(torch.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], dim=1), dim=1)
    valid = double_area > eps
    cots, dots = [], []
    for k in range(3):
        a = tri[:, (k + 1) % 3] - tri[:, k]
        b = tri[:, (k + 2) % 3] - tri[:, k]
        dot = (a * b).sum(dim=1)
        dots.append(dot)
        cot = (dot / double_area.clamp(min=eps)).clamp(-COT_CLAMP, COT_CLAMP)
        cots.append(torch.where(valid, cot, torch.zeros_like(cot)))
    obtuse = torch.stack(dots, dim=1) < 0  # (M, 3): the angle at corner k is obtuse
    any_obtuse = obtuse.any(dim=1)
    for k in range(3):
        # The angle at corner k weights the opposite edge (i, j).
        i, j = (k + 1) % 3, (k + 2) % 3
        diff = tri[:, j] - tri[:, i]
        laplace.index_add_(0, f[:, i], cots[k].unsqueeze(1) * diff)
        laplace.index_add_(0, f[:, j], -cots[k].unsqueeze(1) * diff)
        # Mixed area of corner k: Voronoi part from the two edges at k, weighted by the opposite angles' cotangents.
        len_ki = (tri[:, i] - tri[:, k]).square().sum(1)
        len_kj = (tri[:, j] - tri[:, k]).square().sum(1)
        voronoi = (cots[j] * len_ki + cots[i] * len_kj) / 8
        tri_area = double_area / 2
        mixed = torch.where(any_obtuse, torch.where(obtuse[:, k], tri_area / 2, tri_area / 4), voronoi)
        area.index_add_(0, f[:, k], torch.where(valid, mixed, torch.zeros_like(mixed)))
    h = torch.linalg.norm(laplace, dim=1) / (4.0 * area.clamp(min=eps))
    h = torch.where(area > eps, h, torch.zeros_like(h))
    return h.to(torch.float32)
