"""The MeshAdv texture attack: optimise per-face colours under the rendered image's 4-neighbour smoothness loss.

Colours stay physically valid, in ``[0, 1]``, by optimising in logit space: ``colors = sigmoid(w)`` with
``w`` initialised to ``logit(clamp(colors, 1e-4, 1 - 1e-4))`` (chosen over clamping after each step because it keeps
Adam's state consistent and the gradient defined at the bounds). The perceptual loss is the paper's
``sum_p sum_{q in N4(p)} ||I_p - I_q||^2`` on each rendered adversarial image, averaged over the views.
The reported distance is the face-colour RMSE ``sqrt(1/m sum_i ||t_i^adv - t_i||^2)``.

``gradient_smoothing=k`` (default 0, the paper's method) preconditions the colour gradient with ``k`` rounds of
averaging over faces that share an edge (:func:`meshadv.attacks.lowpass.lowpass_gradient`), for Adam and
``method="ddn"`` alike: the optimiser then changes smooth colour fields, not single facets.

Example:
    >>> from meshadv.attacks import TextureAttack, TargetedMisclassification
    >>> attack = TextureAttack(steps=200, lr=0.05, lambda_perceptual=1e-4)
    >>> result = attack(mesh, views, victim, TargetedMisclassification("bicycle"))   # doctest: +SKIP
"""

from __future__ import annotations

from typing import Any, Dict, Optional, Tuple

import torch
from torch import Tensor

from meshadv import _validate
from meshadv.attacks.mesh_attack import MeshAttack
from meshadv.attacks.distances import color_rmse
from meshadv.attacks.losses import image_smoothness_loss
from meshadv.attacks.lowpass import lowpass_gradient
from meshadv.attacks.masks import check_mask, check_mask_fits, mask_config
from meshadv.attacks.norms import COLOR_EPS, ColorSpace
from meshadv.mesh.adjacency import face_adjacency

__all__ = ["TextureAttack"]

#: Default options of ``method="ddn"`` on face colours (:meth:`TextureAttack.budget_defaults`).
TEXTURE_BUDGET_DEFAULTS: Dict[str, Any] = {"init_budget": 5e-3, "gamma": 0.1, "step_size": 5e-3,
                                           "final_step_size": 5e-4, "min_budget": 1e-6}


class TextureAttack(MeshAttack):
    """Adversarial per-face colours (the paper's texture attack); hyper-parameters as in :class:`MeshAttack`.

    Args:
        face_mask: optional bool ``(M,)``: only these faces change colour (one object of a merged scene); the
            distance is then measured on them only.
        gradient_smoothing: rounds of face-neighbour averaging of the colour gradient (``>= 0``; 0 = none).
        **kwargs: the keyword-only hyper-parameters of :class:`~meshadv.attacks.mesh_attack.MeshAttack`; the default
            ``lr`` is 0.05 (in logit space) and ``lambda_perceptual`` 1e-4 (the image loss sums over pixels).

    Raises:
        ValueError: a hyper-parameter out of range.
    """

    perturbation = "texture"

    def __init__(self, *, face_mask: Optional[Tensor] = None, gradient_smoothing: int = 0, **kwargs: Any) -> None:
        kwargs.setdefault("lr", 0.05)
        kwargs.setdefault("lambda_perceptual", 1e-4)
        super().__init__(**kwargs)
        self.face_mask = check_mask(face_mask, "face_mask", "face")
        self.gradient_smoothing = _validate.non_negative_int("gradient_smoothing", gradient_smoothing, high=10_000)
        self._face_edges: Optional[Tuple[Tensor, Tensor]] = None

    def config(self) -> Dict[str, Any]:
        """Hyper-parameters, including ``face_mask`` (and ``gradient_smoothing`` when it is on)."""
        smoothing = {"gradient_smoothing": self.gradient_smoothing} if self.gradient_smoothing else {}
        return {**super().config(), "face_mask": mask_config(self.face_mask), **smoothing}

    def _preconditioned(self, params: Tensor, mesh: Any) -> Tensor:
        """``params`` with the face-neighbour low-pass on their gradient (``gradient_smoothing`` rounds)."""
        if not self.gradient_smoothing:
            return params
        cached = self._face_edges
        if cached is None or cached[0] is not mesh.faces:
            cached = (mesh.faces, face_adjacency(mesh.faces))
            self._face_edges = cached
        return lowpass_gradient(params, cached[1], self.gradient_smoothing)

    def check_mesh(self, mesh: Any) -> None:
        """Raise ``ValueError`` when ``face_mask`` does not fit ``mesh``."""
        check_mask_fits(self.face_mask, "face_mask", mesh.faces.shape[0], "faces")

    def initial_params(self, mesh: Any, num_targets: int) -> Tensor:
        """The logits of the pristine colours, ``(T, M, 3)``."""
        logits = torch.logit(mesh.face_colors.clamp(COLOR_EPS, 1 - COLOR_EPS))
        return logits.unsqueeze(0).repeat(num_targets, 1, 1)

    def colors(self, params: Tensor, mesh: Any, edges: Tensor) -> Tensor:
        """Face colours ``(K, M, 3)`` for parameters ``params`` (faces outside ``face_mask`` keep theirs)."""
        colors = self._colors(params, mesh, edges)
        if self.face_mask is None:
            return colors
        mask = self.face_mask.to(colors.device)[None, :, None]
        return torch.where(mask, colors, mesh.face_colors.unsqueeze(0).expand_as(colors))

    def _colors(self, params: Tensor, mesh: Any, edges: Tensor) -> Tensor:
        """Unmasked face colours of the parametrisation: ``sigmoid(params)``."""
        return torch.sigmoid(params)

    def apply(self, params: Tensor, mesh: Any, edges: Tensor) -> Tuple[Tensor, Tensor]:
        """The unchanged vertices, expanded to ``(K, N, 3)``, and the face colours ``(K, M, 3)``."""
        verts = mesh.vertices.unsqueeze(0).expand(params.shape[0], -1, -1)
        return verts, self.colors(self._preconditioned(params, mesh), mesh, edges)

    def perceptual(self, params: Tensor, mesh: Any, edges: Tensor, images: Tensor, alpha: Tensor,
                   num_views: int) -> Tensor:
        """The image smoothness loss of the renders, mean over the views, ``(K,)``."""
        return image_smoothness_loss(images).view(params.shape[0], num_views).mean(dim=1)

    def distance(self, params: Tensor, mesh: Any, edges: Tensor) -> Tensor:
        """The face-colour RMSE (over ``face_mask``'s faces when given), ``(K,)``."""
        colors = self._colors(params, mesh, edges)
        if self.face_mask is None:
            return color_rmse(colors, mesh.face_colors)
        mask = self.face_mask.to(colors.device)
        return color_rmse(colors[:, mask], mesh.face_colors[mask])

    @classmethod
    def budget_defaults(cls) -> Dict[str, Any]:
        """The ddn defaults of face colours, in :class:`~meshadv.attacks.norms.ColorNorm` (RMSE) units."""
        return dict(TEXTURE_BUDGET_DEFAULTS)

    def budget_space(self, **options: Any) -> ColorSpace:
        """The colours of the logit parameters, measured by their RMSE (:class:`~meshadv.attacks.norms.ColorSpace`).

        Raises:
            ValueError: a subclass with another colour mapping (the parameters are then not the colours' logits),
                or an option (the colour space has none).
        """
        if type(self)._colors is not TextureAttack._colors or type(self).apply is not TextureAttack.apply:
            raise ValueError(f"method='ddn' cannot step the parametrisation of {type(self).__name__}")
        if options:
            raise ValueError(f"the colour space takes no options, got {sorted(options)}")
        return ColorSpace(self.face_mask)

