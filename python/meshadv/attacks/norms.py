"""The parameter spaces of the distortion-budget rule (``method="ddn"``, :mod:`meshadv.attacks.budget`): how large a
perturbation is, which step is steepest, what a step may not change, and how a perturbation becomes the attack's
parameters and back.

* :class:`LaplacianNorm` (shape): ``sqrt(laplacian_pair_mean(dv))``, directions preconditioned by
  ``(L + I / smoothness)^-1`` (the steepest descent in the metric ``L + I / smoothness``, ``L`` the mesh graph
  Laplacian), perturbations kept free of every connected component's translation (invisible to ``L``);
* :class:`ColorNorm` (texture): the face-colour RMSE, directions along the colour gradient.
* :class:`FlowSpace` and :class:`ColorSpace`: a family's perturbation (a vertex flow, a colour change) with its norm,
  read from and written into the attack's parameters. A family returns one from
  :meth:`~meshadv.attacks.mesh_attack.MeshAttack.budget_space`.

All work on ``(T, ...)`` rows, one per target.
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np
import torch
from torch import Tensor

from meshadv.attacks.losses import laplacian_flow_loss

__all__ = ["COLOR_EPS", "ColorNorm", "ColorSpace", "FlowSpace", "LaplacianNorm", "per_row", "positive_option",
           "unit_rows"]

#: Sizes below this count as zero (a zero gradient has no direction).
TINY = 1e-30
#: Colours are clamped into ``[COLOR_EPS, 1 - COLOR_EPS]`` before their logit (the texture parametrisation's start).
COLOR_EPS = 1e-4


def positive_option(name: str, value: Any) -> float:
    """``value`` as a float when it is a finite real number ``> 0``; a ``ValueError`` naming ``name`` for any other
    value, of any type (the options of ``method="ddn"`` come as one JSON-able dict, ``method_options``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or not value > 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return float(value)


def per_row(values: Tensor, like: Tensor) -> Tensor:
    """``values (K,)`` viewed as ``(K, 1, ..., 1)`` to scale the rows of ``like (K, ...)``."""
    return values.view((-1,) + (1,) * (like.dim() - 1))


def unit_rows(u: Tensor, size: Tensor) -> Tensor:
    """``u / size`` per target (``size (K,)``), zero where ``size`` is 0."""
    size = per_row(size, u)
    return torch.where(size > TINY, u / size.clamp(min=TINY), torch.zeros_like(u))


class LaplacianNorm:
    """The shape norm ``sqrt(laplacian_pair_mean(dv))`` and its preconditioned steepest-descent direction.

    Args:
        edges: int ``(E, 2)`` unique undirected mesh edges, ``E >= 1``.
        num_vertices: ``N``.
        smoothness: ``s`` of the metric ``L + I / s`` in which steps are steepest; ``None`` = the Laplacian alone
            (the steepest direction for the Laplacian distance itself: the smoothest, most global one).
        vertex_mask: optional bool ``(N,)``: only these vertices move.

    Raises:
        ValueError: bad ``edges``, ``num_vertices``, ``smoothness`` or ``vertex_mask``.
    """

    def __init__(self, edges: Tensor, num_vertices: int, smoothness: Optional[float] = 1.0,
                 vertex_mask: Optional[Tensor] = None) -> None:
        import scipy.sparse as sp
        from scipy.sparse.csgraph import connected_components
        from scipy.sparse.linalg import factorized

        if isinstance(num_vertices, bool) or int(num_vertices) != num_vertices or num_vertices < 1:
            raise ValueError(f"num_vertices must be an integer >= 1, got {num_vertices!r}")
        if not isinstance(edges, Tensor) or edges.dim() != 2 or edges.shape[1] != 2 or edges.is_floating_point():
            raise ValueError("edges must be an integer tensor of shape (E, 2)")
        n = int(num_vertices)
        e = edges.detach().cpu().long().numpy()
        if len(e) == 0 or e.min() < 0 or e.max() >= n:
            raise ValueError(f"edges must be a non-empty list of vertex pairs in [0, {n})")
        self.smoothness = None if smoothness is None else positive_option("smoothness", smoothness)
        if vertex_mask is not None and (not isinstance(vertex_mask, Tensor) or tuple(vertex_mask.shape) != (n,)):
            raise ValueError(f"vertex_mask must be None or a bool tensor of shape ({n},)")
        self.vertex_mask = None if vertex_mask is None else vertex_mask.detach().bool().cpu()
        self.edges = edges.detach().long().cpu()
        self.num_vertices = n
        self.num_pairs = 2 * len(e)
        adj = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
        adj = ((adj + adj.T) > 0).astype(np.float64)
        lap = sp.diags(np.asarray(adj.sum(axis=1)).ravel()) - adj
        count, labels = connected_components(adj, directed=False)
        self.num_components = int(count)
        self._labels = torch.from_numpy(labels.astype(np.int64))
        self._sizes = torch.bincount(self._labels, minlength=count).to(torch.float64).clamp(min=1)
        # L alone is singular on translations; the tiny shift is harmless: both sides are projected off them
        shift = 1.0 / self.smoothness if self.smoothness is not None else 1e-8 * float(lap.diagonal().mean())
        self._solve = factorized((lap + shift * sp.identity(n)).tocsc())

    def distance(self, dv: Tensor) -> Tensor:
        """The Eq. 4 Laplacian (the sum) of ``dv (T, N, 3)``, ``(T,)``."""
        return laplacian_flow_loss(dv, self.edges.to(dv.device))

    def norm(self, dv: Tensor) -> Tensor:
        """``sqrt(distance / 2E)`` per target, ``(T,)``."""
        return (self.distance(dv) / self.num_pairs).clamp(min=0).sqrt()

    def from_distance(self, distance: float) -> float:
        """The norm of a perturbation whose Eq. 4 distance is ``distance``."""
        return math.sqrt(max(distance, 0.0) / self.num_pairs)

    def project(self, dv: Tensor) -> Tensor:
        """``dv (T, N, 3)`` masked and without its per-connected-component translation (invisible to the norm)."""
        out = dv.double()
        if self.vertex_mask is not None:
            out = out * self.vertex_mask.to(dv.device).view(1, -1, 1)
        labels = self._labels.to(dv.device)
        sums = torch.zeros(dv.shape[0], self.num_components, 3, dtype=torch.float64, device=dv.device)
        sums.index_add_(1, labels, out)
        out = out - (sums / self._sizes.to(dv.device).view(1, -1, 1))[:, labels]
        if self.vertex_mask is not None:  # a masked vertex inside a moving component: keep it still
            out = out * self.vertex_mask.to(dv.device).view(1, -1, 1)
        return out.to(dv.dtype)

    def direction(self, grad: Tensor) -> Tensor:
        """Unit-norm descent direction ``-(L + I/s)^-1 grad`` (projected) per target; zero where ``grad`` is 0."""
        g = self.project(grad).double()
        t = g.shape[0]
        rhs = g.permute(1, 0, 2).reshape(self.num_vertices, 3 * t).cpu().numpy()
        u = torch.from_numpy(np.asarray(self._solve(rhs))).reshape(self.num_vertices, t, 3).permute(1, 0, 2)
        u = self.project(u.to(grad.device))
        return unit_rows(-u, self.norm(u)).to(grad.dtype)


class ColorNorm:
    """The texture norm: the face-colour RMSE of ``dt (T, M, 3)`` (over the faces of ``face_mask`` when given).

    Args:
        face_mask: optional bool ``(M,)``: only these faces change colour and count in the norm.
    """

    def __init__(self, face_mask: Optional[Tensor] = None) -> None:
        self.face_mask = None if face_mask is None else face_mask.detach().bool().cpu()

    def norm(self, dt: Tensor) -> Tensor:
        """RMSE per target, ``(T,)``."""
        if self.face_mask is not None:
            dt = dt[:, self.face_mask.to(dt.device)]
        return dt.pow(2).sum(dim=-1).mean(dim=-1).sqrt()

    def from_distance(self, distance: float) -> float:
        """The texture distance is the norm itself."""
        return float(distance)

    def project(self, dt: Tensor) -> Tensor:
        """Faces outside ``face_mask`` keep their colour."""
        if self.face_mask is None:
            return dt
        return dt * self.face_mask.to(dt.device).view(1, -1, 1).to(dt.dtype)

    def direction(self, grad: Tensor) -> Tensor:
        """Unit-RMSE descent direction ``-grad`` per target; zero where ``grad`` is 0."""
        g = self.project(grad)
        return unit_rows(-g, self.norm(g))


class _Space:
    """What both spaces share: the norm of the prepared mesh and its methods on perturbations ``(K, ...)``."""

    _norm: Any = None
    origin: Optional[Tensor] = None

    def _built(self) -> Any:
        if self._norm is None:
            raise RuntimeError(f"{type(self).__name__}.prepare(mesh, edges) must be called first")
        return self._norm

    def norm(self, delta: Tensor) -> Tensor:
        """The size of every row of ``delta`` in the space's norm, ``(K,)``."""
        return self._built().norm(delta)

    def from_distance(self, distance: float) -> float:
        """The norm of a perturbation whose distortion (the family's ``distance``) is ``distance``."""
        return self._built().from_distance(distance)

    def project(self, delta: Tensor) -> Tensor:
        """``delta`` without what a step may not change."""
        return self._built().project(delta)

    def direction(self, grad: Tensor) -> Tensor:
        """The unit steepest-descent direction of a gradient with respect to the perturbation."""
        return self._built().direction(grad)


class FlowSpace(_Space):
    """A vertex flow ``dv (T, N, 3)`` that is the attack's parameters themselves, measured by :class:`LaplacianNorm`.

    Args:
        smoothness: ``s`` of the metric ``L + I / s`` of the steps (``None``: the Laplacian alone).
        vertex_mask: optional bool ``(N,)``: only these vertices move.

    Raises:
        ValueError: ``smoothness`` is not a finite number > 0 (or None).
    """

    def __init__(self, smoothness: Optional[float] = None, vertex_mask: Optional[Tensor] = None) -> None:
        self.smoothness = None if smoothness is None else positive_option("smoothness", smoothness)
        self.vertex_mask = vertex_mask

    def prepare(self, mesh: Any, edges: Tensor) -> None:
        """Build the norm of ``mesh`` (its Laplacian and connected components); the origin is no displacement."""
        self._norm = LaplacianNorm(edges, mesh.vertices.shape[0], self.smoothness, self.vertex_mask)
        self.origin = torch.zeros_like(mesh.vertices)

    def gradient(self, params: Tensor, idx: Tensor) -> Tensor:
        """The gradient of the rows ``idx`` with respect to the flow (zeros when there is none)."""
        grad = params.grad
        return torch.zeros_like(params[idx]) if grad is None else grad[idx].detach()

    def write(self, params: Tensor, idx: Tensor, delta: Tensor) -> Tensor:
        """Write the flow ``delta`` of the rows ``idx`` into ``params``; returns it."""
        params[idx] = delta.to(params.dtype)
        return delta

    def read(self, params: Tensor, idx: Tensor) -> Tensor:
        """The flow of the rows ``idx`` of ``params`` (a detached copy)."""
        return params[idx].detach().clone()


class ColorSpace(_Space):
    """A face-colour change ``dt (T, M, 3)`` of parameters that are the colours' logits, measured by
    :class:`ColorNorm`; colours stay in ``[0, 1]``.

    Args:
        face_mask: optional bool ``(M,)``: only these faces change colour and count in the norm.
    """

    def __init__(self, face_mask: Optional[Tensor] = None) -> None:
        self.face_mask = face_mask

    def prepare(self, mesh: Any, edges: Tensor) -> None:
        """The norm of ``mesh``'s faces; the origin is its colours (clamped as the parametrisation's start)."""
        self._norm = ColorNorm(self.face_mask)
        self.origin = mesh.face_colors.detach().clamp(COLOR_EPS, 1 - COLOR_EPS)

    def gradient(self, params: Tensor, idx: Tensor) -> Tensor:
        """The gradient of the rows ``idx`` with respect to the colours: ``d loss / d logit / (c (1 - c))``."""
        grad = params.grad
        grad = torch.zeros_like(params[idx]) if grad is None else grad[idx].detach()
        colors = torch.sigmoid(params[idx].detach())
        return grad / (colors * (1 - colors)).clamp(min=TINY)

    def write(self, params: Tensor, idx: Tensor, delta: Tensor) -> Tensor:
        """Write the colour change ``delta`` of the rows ``idx`` into ``params`` as logits, the colours
        ``origin + delta`` clipped into ``[0, 1]`` and projected again; returns the change kept."""
        if self.origin is None:
            raise RuntimeError("ColorSpace.prepare(mesh, edges) must be called first")
        delta = (self.origin + delta).clamp(0.0, 1.0) - self.origin
        delta = self.project(delta)
        params[idx] = torch.logit((self.origin + delta).clamp(COLOR_EPS, 1 - COLOR_EPS)).to(params.dtype)
        return delta

    def read(self, params: Tensor, idx: Tensor) -> Tensor:
        """The colour change of the rows ``idx`` of ``params`` (logits) from the origin."""
        if self.origin is None:
            raise RuntimeError("ColorSpace.prepare(mesh, edges) must be called first")
        return torch.sigmoid(params[idx].detach()) - self.origin
