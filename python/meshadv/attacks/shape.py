"""The MeshAdv shape attack: optimise a per-vertex displacement ``dv`` under the 3D Laplacian flow loss.

``vertices_adv = vertices + dv``; the objective is ``L_adv + lambda * sum_i sum_{q in N(i)} ||dv_i - dv_q||^2``
(mesh-edge neighbours), minimised with Adam from ``dv = 0``. Colours and topology are unchanged.

Parametrisation: Adam optimises parameters ``p`` (``T x N x 3``) and the applied displacement is ``dv = clamp(S^k p,
-max_step, max_step)`` with ``S p = p + 0.5 * L p`` (``k = smoothing`` rounds of neighbour averaging over mesh
edges, :func:`meshadv.attacks.flow.smooth_flow`, the low-pass reparametrisation used for the dense bunny of the
indoor scene). ``smoothing=0``, the default, is the paper's exact method (``dv =
p``). ``smoothing > 0`` makes every Adam step move smooth patches of the surface instead of single vertices: it
keeps a dense mesh from roughening, but it also removes the perturbation's high frequencies. Whatever ``smoothing``
is, the objective is the same: the Laplacian loss, the budget ``max_distortion`` and the
distances of the result are those of the applied ``dv``.

Example:
    >>> from meshadv.attacks import ShapeAttack, TargetedMisclassification
    >>> attack = ShapeAttack(steps=200, lambda_perceptual=0.05)                  # the paper's per-vertex flow
    >>> smooth = ShapeAttack(steps=200, lr=1e-2, smoothing=8)                    # smoothed flow (an option)
    >>> result = attack(mesh, views, victim, TargetedMisclassification("bicycle"))   # doctest: +SKIP
    >>> result.save("out/")                                                            # doctest: +SKIP
"""

from __future__ import annotations

from typing import Any, Dict, Optional, Tuple

import torch
from torch import Tensor

from meshadv import _validate
from meshadv.attacks.mesh_attack import MeshAttack
from meshadv.attacks.flow import smooth_flow
from meshadv.attacks.losses import laplacian_flow_loss
from meshadv.attacks.masks import check_mask, check_mask_fits, mask_config
from meshadv.attacks.move_limit import move_lengths, scale_factors, shorten_moves
from meshadv.attacks.norms import FlowSpace
from meshadv.render.surface_reflectance import reflectance_of

__all__ = ["ShapeAttack", "DEFAULT_SMOOTHING", "DEFAULT_SHAPE_LR"]

#: Default rounds of neighbour averaging of the flow parameters: 0, the paper's per-vertex flow.
DEFAULT_SMOOTHING = 0
#: Default Adam learning rate of the shape attack (meshes normalised to ``[-1, 1]``).
DEFAULT_SHAPE_LR = 1e-3
#: Default options of ``method="ddn"`` on a vertex flow (:meth:`ShapeAttack.budget_defaults`).
SHAPE_BUDGET_DEFAULTS: Dict[str, Any] = {"init_budget": 1e-3, "gamma": 0.05, "step_size": 1e-3,
                                         "final_step_size": 1e-4, "min_budget": 1e-7, "smoothness": 0.1,
                                         "edge_gradient": 0.1, "visibility_gradient": "nmr"}


class ShapeAttack(MeshAttack):
    """Adversarial vertex flow (the paper's shape attack); hyper-parameters as in :class:`MeshAttack`.

    Args:
        smoothing: rounds ``k`` of neighbour averaging applied to the optimised parameters before they become the
            displacement, ``dv = S^k p`` (see the module docstring); ``0`` (default) = the paper's exact per-vertex
            flow. Smoothed flows move less per step: use a larger ``lr`` with them (e.g. 1e-2 for ``k = 8``).
        max_step: optional per-coordinate bound on the applied ``|dv|`` (a clamp inside the parametrisation);
            ``None`` = unbounded.
        vertex_mask: optional bool ``(N,)``: only these vertices may move (e.g. one object of a merged scene). The
            other vertices' parameters are multiplied by zero before the parametrisation, so they get no gradient;
            objects of a merged scene share no edge, so neither the smoothing nor the Laplacian crosses them.
        **kwargs: the keyword-only hyper-parameters of :class:`~meshadv.attacks.mesh_attack.MeshAttack`; the default
            ``lr`` is :data:`DEFAULT_SHAPE_LR` and ``lambda_perceptual`` 0.05 (meshes scaled to ``[-1, 1]``).

    Raises:
        ValueError: a hyper-parameter out of range.
    """

    perturbation = "shape"

    def __init__(self, *, smoothing: int = DEFAULT_SMOOTHING, max_step: Optional[float] = None,
                 vertex_mask: Optional[Tensor] = None, **kwargs: Any) -> None:
        kwargs.setdefault("lr", DEFAULT_SHAPE_LR)
        kwargs.setdefault("lambda_perceptual", 0.05)
        super().__init__(**kwargs)
        self.smoothing = _validate.non_negative_int("smoothing", smoothing)
        self.max_step = None if max_step is None else _validate.positive_float("max_step", max_step)
        self.vertex_mask = check_mask(vertex_mask, "vertex_mask", "vertex")

    def config(self) -> Dict[str, Any]:
        """Hyper-parameters, including ``smoothing``, ``max_step`` and ``vertex_mask``."""
        return {**super().config(), "smoothing": self.smoothing, "max_step": self.max_step,
                "vertex_mask": mask_config(self.vertex_mask)}

    def check_mesh(self, mesh: Any) -> None:
        """Raise ``ValueError`` when ``vertex_mask`` does not fit ``mesh``."""
        check_mask_fits(self.vertex_mask, "vertex_mask", mesh.vertices.shape[0], "vertices")

    def displacement(self, params: Tensor, edges: Tensor) -> Tensor:
        """The displacement ``dv`` applied to the mesh for parameters ``params``.

        Args:
            params: ``(T, N, 3)`` (or ``(N, 3)``) optimised parameters.
            edges: int ``(E, 2)`` unique undirected edges of the mesh.

        Returns:
            ``clamp(S^smoothing params, -max_step, max_step)``, the shape of ``params``.
        """
        if self.vertex_mask is not None:
            params = params * self.vertex_mask.to(params.device)[..., :, None].to(params.dtype)
        dv = smooth_flow(params, edges, self.smoothing)
        return dv if self.max_step is None else dv.clamp(-self.max_step, self.max_step)

    def limit_moves(self, params: Tensor, idx: Tensor, edges: Tensor, radius: float) -> bool:
        """Pull the rows ``idx`` of ``params`` (in place) so that no applied vertex move is longer than ``radius``
        (:mod:`meshadv.attacks.move_limit`); ``True`` when a row changed.

        With ``smoothing=0`` the parameters are the flow (masked, clamped by ``max_step``), and every vertex that
        moved too far is pulled back along its move (the Euclidean projection onto the limit); with ``smoothing > 0``
        the flow ``S^k p`` is linear in ``p``, and the rows with a vertex too far are scaled down as a whole. Rows
        whose moves are all within ``radius`` are left exactly as they are.
        """
        with torch.no_grad():
            rows = params[idx]
            over = move_lengths(self.displacement(rows, edges)) > radius  # (K, N)
            if not bool(over.any()):
                return False
            goal = radius * (1.0 - 1e-6)  # a hair inside, so float rounding never leaves a pulled row outside
            if self.smoothing == 0:
                # |dv_i| <= |p_i|: shortening p_i to the radius brings dv_i inside it
                limited = torch.where(over.unsqueeze(-1), shorten_moves(rows, goal), rows)
            else:
                masked = rows if self.vertex_mask is None else rows * self.vertex_mask.to(rows)[..., :, None]
                flow = smooth_flow(masked, edges, self.smoothing)  # the flow before max_step's clamp
                factor = torch.where(over.any(dim=1), scale_factors(flow, goal), torch.ones_like(flow[:, 0, 0]))
                limited = rows * factor.view(-1, 1, 1)
            params[idx] = limited.to(params.dtype)
        return True

    def initial_params(self, mesh: Any, num_targets: int) -> Tensor:
        """No displacement: zeros ``(T, N, 3)``."""
        return mesh.vertices.new_zeros((num_targets, *mesh.vertices.shape))

    def apply(self, params: Tensor, mesh: Any, edges: Tensor) -> Tuple[Tensor, Tensor]:
        """The displaced vertices ``(K, N, 3)`` and the unchanged reflectance (face colours, or the texture of a
        textured mesh)."""
        return mesh.vertices.unsqueeze(0) + self.displacement(params, edges), reflectance_of(mesh)

    def _laplacian(self, params: Tensor, edges: Tensor) -> Tensor:
        """The Eq. 4 Laplacian of the applied displacement per target ``(K,)``: the perceptual loss and the
        distance of the shape attack."""
        return laplacian_flow_loss(self.displacement(params, edges), edges)

    def perceptual(self, params: Tensor, mesh: Any, edges: Tensor, images: Tensor, alpha: Tensor,
                   num_views: int) -> Tensor:
        """The Eq. 4 Laplacian of the applied displacement, ``(K,)``."""
        return self._laplacian(params, edges)

    def distance(self, params: Tensor, mesh: Any, edges: Tensor) -> Tensor:
        """The Eq. 4 Laplacian of the applied displacement, ``(K,)``."""
        return self._laplacian(params, edges)

    def terms(self, params: Tensor, mesh: Any, edges: Tensor, images: Tensor, alpha: Tensor,
              num_views: int) -> Tuple[Tensor, Tensor]:
        """The perceptual loss and the distance are the same Laplacian: computed once."""
        loss = self._laplacian(params, edges)
        return loss, loss

    @classmethod
    def budget_defaults(cls) -> Dict[str, Any]:
        """The ddn defaults of a vertex flow, in :class:`~meshadv.attacks.norms.LaplacianNorm` units for a mesh
        normalised to ``[-1, 1]`` (:func:`meshadv.attacks.budget.shape_options_for` scales them to another size);
        ``smoothness`` is the space's, ``edge_gradient`` the weight of the rasterization gradient in the steps and
        ``visibility_gradient`` which one (:func:`meshadv.render.render`'s)."""
        return dict(SHAPE_BUDGET_DEFAULTS)

    def budget_space(self, **options: Any) -> FlowSpace:
        """The flow itself, measured by the Laplacian norm (:class:`~meshadv.attacks.norms.FlowSpace`).

        Raises:
            ValueError: a smoothed (``smoothing != 0``) or clamped (``max_step``) flow, or a subclass with its own
                displacement: the parameters are then not the flow.
        """
        if type(self).displacement is not ShapeAttack.displacement:
            raise ValueError(f"method='ddn' cannot step the parametrisation of {type(self).__name__}")
        if self.smoothing != 0:
            raise ValueError(f"smoothing must be 0 with method='ddn' (its preconditioner smooths the steps), "
                             f"got {self.smoothing}")
        if self.max_step is not None:
            raise ValueError(f"max_step must be None with method='ddn', got {self.max_step}")
        return FlowSpace(vertex_mask=self.vertex_mask, **options)
