"""The texture-image attack: the texels of a mesh's UV texture are the perturbation.

The attacked mesh is a :class:`~meshadv.mesh.surface_mesh.SurfaceMesh` with a texture image ``(Ht, Wt, 3)``; it is
rendered through :func:`~meshadv.render.render_surface` (bilinear texture sampling, exact gradients to the texels).
The parameters are the texels' logits, ``(T, Ht * Wt, 3)`` (:func:`texture_to_params` / :func:`params_to_texture`),
so the texture stays in ``[0, 1]`` as in the per-face texture attack; ``method="ddn"`` steps the texels themselves
(:class:`TexelSpace`, an RMSE ball clipped to ``[0, 1]``). The perceptual loss is the paper's image smoothness of the
renders; the distance (budget, best result) is the texel colour RMSE ``sqrt(1/(Ht Wt) sum_p ||t_p^adv - t_p||^2)``.
Results also report :func:`texture_tv`, the total variation of the change in UV (image) space.

Example:
    >>> from meshadv.mesh.surface_mesh import load_surface_mesh
    >>> attack = TextureMapAttack(steps=100)
    >>> result = attack(load_surface_mesh("textured.obj"), views, victim, TargetedMisclassification("bicycle"))
    ...                                                                                       # doctest: +SKIP
    >>> result.adversarial[0].texture.shape                                                   # doctest: +SKIP
    torch.Size([512, 512, 3])
"""

from __future__ import annotations

from typing import Any, Dict, Tuple

import torch
from torch import Tensor

from meshadv.attacks.mesh_attack import MeshAttack
from meshadv.attacks.distances import color_rmse
from meshadv.attacks.losses import image_smoothness_loss
from meshadv.attacks.norms import COLOR_EPS, ColorNorm, ColorSpace
from meshadv.attacks.texture import TEXTURE_BUDGET_DEFAULTS
from meshadv.render.surface_reflectance import SurfaceReflectance

__all__ = ["TextureMapAttack", "TexelSpace", "texture_to_params", "params_to_texture", "texture_tv",
           "texture_distances"]


def texture_to_params(texture: Tensor) -> Tensor:
    """The logits ``(Ht * Wt, 3)`` of a texture ``(Ht, Wt, 3)`` (clamped into ``[eps, 1 - eps]`` first)."""
    if texture.dim() != 3 or texture.shape[-1] != 3:
        raise ValueError(f"texture must have shape (Ht,Wt,3), got {tuple(texture.shape)}")
    return torch.logit(texture.reshape(-1, 3).clamp(COLOR_EPS, 1 - COLOR_EPS))


def params_to_texture(params: Tensor, height: int, width: int) -> Tensor:
    """The texture ``(..., Ht, Wt, 3)`` of logits ``(..., Ht * Wt, 3)``: ``sigmoid(params)``.

    Raises:
        ValueError: ``params`` do not hold ``height * width`` texels.
    """
    if params.shape[-2:] != (height * width, 3):
        raise ValueError(f"params must end in ({height * width}, 3) for a {height}x{width} texture, "
                         f"got {tuple(params.shape)}")
    return torch.sigmoid(params).reshape(*params.shape[:-2], height, width, 3)


def texture_tv(delta: Tensor) -> Tensor:
    """Total variation in UV space of a texture change ``delta`` ``(..., Ht, Wt, 3)``: the sum of absolute
    differences between vertically and horizontally adjacent texels (every channel), divided by ``3 Ht Wt``
    (a per-texel, per-channel mean; 0 for a uniform change). Returns ``(...)``."""
    rows = (delta[..., 1:, :, :] - delta[..., :-1, :, :]).abs().sum(dim=(-3, -2, -1))
    cols = (delta[..., :, 1:, :] - delta[..., :, :-1, :]).abs().sum(dim=(-3, -2, -1))
    return (rows + cols) / float(delta.shape[-3] * delta.shape[-2] * 3)


def texture_distances(texture: Tensor, texture_adv: Tensor) -> Dict[str, float]:
    """``texel_rmse`` (``sqrt(mean_p ||t_p^adv - t_p||^2)``) and ``texture_tv`` (:func:`texture_tv` of the change)
    between two ``(Ht, Wt, 3)`` textures, as floats.

    Raises:
        ValueError: the textures differ in shape.
    """
    if texture.shape != texture_adv.shape:
        raise ValueError(f"texture_adv {tuple(texture_adv.shape)} must match texture {tuple(texture.shape)}")
    with torch.no_grad():
        a, b = texture.float(), texture_adv.float()
        return {"texel_rmse": float(color_rmse(b.reshape(1, -1, 3), a.reshape(-1, 3))[0]),
                "texture_tv": float(texture_tv(b - a))}


class TexelSpace(ColorSpace):
    """The texels of a texture as ``method="ddn"`` steps them: a change ``(T, Ht * Wt, 3)`` of parameters that are
    the texels' logits, measured by the texel RMSE (:class:`~meshadv.attacks.norms.ColorNorm` over texels) and
    clipped so the texture stays in ``[0, 1]``."""

    def __init__(self) -> None:
        super().__init__(None)

    def prepare(self, mesh: Any, edges: Tensor) -> None:
        """The origin is ``mesh.texture``'s texels (clamped as the parametrisation's start)."""
        self._norm = ColorNorm(None)
        self.origin = mesh.texture.detach().reshape(-1, 3).clamp(COLOR_EPS, 1 - COLOR_EPS)


class TextureMapAttack(MeshAttack):
    """Adversarial texture image of a UV-textured mesh; hyper-parameters as in :class:`MeshAttack`.

    The mesh of a call is a :class:`~meshadv.mesh.surface_mesh.SurfaceMesh` with a texture; the result's adversarial
    meshes are SurfaceMeshes carrying the adversarial texture at the file's resolution, and its ``distances`` add
    ``texel_rmse`` and ``texture_tv`` (:func:`texture_distances`) to the mesh distances.

    Args:
        **kwargs: the keyword-only hyper-parameters of :class:`~meshadv.attacks.mesh_attack.MeshAttack`; the default
            ``lr`` is 0.05 (in logit space) and ``lambda_perceptual`` 1e-4 (the image loss sums over pixels);
            ``max_distortion`` is a texel RMSE.

    Raises:
        ValueError: a hyper-parameter out of range.
    """

    perturbation = "texture-map"

    def __init__(self, **kwargs: Any) -> None:
        kwargs.setdefault("lr", 0.05)
        kwargs.setdefault("lambda_perceptual", 1e-4)
        super().__init__(**kwargs)

    def check_mesh(self, mesh: Any) -> None:
        """Raise ``ValueError`` unless ``mesh`` carries a UV texture image."""
        if getattr(mesh, "texture", None) is None or getattr(mesh, "uvs", None) is None:
            raise ValueError("mesh: the texture-map attack needs a mesh with a UV texture image (a SurfaceMesh "
                             "from load_surface_mesh of an OBJ with map_Kd or a GLB with a base-colour texture), got "
                             f"{type(mesh).__name__} without one")

    def initial_params(self, mesh: Any, num_targets: int) -> Tensor:
        """The logits of the pristine texels, ``(T, Ht * Wt, 3)``."""
        return texture_to_params(mesh.texture).unsqueeze(0).repeat(num_targets, 1, 1)

    def textures(self, params: Tensor, mesh: Any) -> Tensor:
        """The textures ``(K, Ht, Wt, 3)`` of parameters ``(K, Ht * Wt, 3)``."""
        height, width = mesh.texture.shape[:2]
        return params_to_texture(params, height, width)

    def apply(self, params: Tensor, mesh: Any, edges: Tensor) -> Tuple[Tensor, SurfaceReflectance]:
        """The unchanged vertices ``(K, N, 3)`` and the ``K`` textures as a
        :class:`~meshadv.render.surface_reflectance.SurfaceReflectance` (what ``RenderSetup.render`` draws)."""
        verts = mesh.vertices.unsqueeze(0).expand(params.shape[0], -1, -1)
        return verts, SurfaceReflectance(self.textures(params, mesh), mesh.uvs, mesh.uv_faces, mesh.vertex_colors,
                                         mesh.shading)

    def perceptual(self, params: Tensor, mesh: Any, edges: Tensor, images: Tensor, alpha: Tensor,
                   num_views: int) -> Tensor:
        """The image smoothness loss of the renders, mean over the views, ``(K,)``."""
        return image_smoothness_loss(images).view(params.shape[0], num_views).mean(dim=1)

    def distance(self, params: Tensor, mesh: Any, edges: Tensor) -> Tensor:
        """The texel colour RMSE, ``(K,)``."""
        return color_rmse(torch.sigmoid(params), mesh.texture.reshape(-1, 3))

    def result_meshes(self, params: Tensor, mesh: Any, edges: Tensor) -> Tuple[Any, ...]:
        """The ``T`` adversarial SurfaceMeshes: ``mesh`` with each target's texture."""
        with torch.no_grad():
            textures = self.textures(params, mesh)
        return tuple(mesh.with_texture(t.clone().contiguous()) for t in textures)

    def result_distances(self, mesh: Any, adversarial: Any, edges: Tensor) -> Dict[str, float]:
        """The mesh distances plus ``texel_rmse`` and ``texture_tv`` (:func:`texture_distances`)."""
        return {**super().result_distances(mesh, adversarial, edges),
                **texture_distances(mesh.texture, adversarial.texture)}

    @classmethod
    def budget_defaults(cls) -> Dict[str, Any]:
        """The ddn defaults of the texels, in texel-RMSE units (those of the per-face colours)."""
        return dict(TEXTURE_BUDGET_DEFAULTS)

    def budget_space(self, **options: Any) -> TexelSpace:
        """The texels of the logit parameters, measured by their RMSE (:class:`TexelSpace`).

        Raises:
            ValueError: an option (the texel space has none).
        """
        if options:
            raise ValueError(f"the texel space takes no options, got {sorted(options)}")
        return TexelSpace()
