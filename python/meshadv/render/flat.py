"""The flat (per-face Lambert) render of a float32 CPU mesh as one native op and one autograd node.

``meshadv._raster.flat_render_forward`` projects the world-space vertices, shades the faces, rasterizes them (RGB +
coverage) and box-filters the antialiased image in one call; ``flat_render_backward`` is the adjoint of all of it
(the box filter's, the rasterizer's with NMR's or the local visibility gradient, the shading's and the projection's).
The camera's rotation, eye and projection scale and the unit light directions are computed in PyTorch (a few
values per view), so gradients reach every camera and light parameter through autograd.

The images are those of the composition :meth:`Camera.project`, :func:`~meshadv.render.lighting.shade`,
:func:`~meshadv.render.rasterize.rasterize` and the box filter that :func:`meshadv.render.render` uses for other
dtypes and devices, bit for bit where PyTorch's CPU kernels are its AVX2 or AVX-512 ones (the native op rounds as
they do). So are the gradients of the vertices and colours (the native adjoint rounds as PyTorch's autograd of that
composition does) when the vertices have one copy per view or there is one view; with one copy of the vertices
shared by several views they differ only by the order in which the views' parts are added. The camera's and the
lights' gradients are computed in ``float64`` and equal the composition's up to float rounding.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from .camera import Camera, _normalize
from .lighting import Lights
from .rasterize import _native

__all__ = ["FlatRender", "flat_render", "supports_flat_render"]


@dataclass(frozen=True)
class FlatRender:
    """Result of :func:`flat_render`.

    Attributes:
        image: (B,3,H,W) shaded colours (a channels-last view). Differentiable.
        alpha: (B,1,H,W) coverage (a channels-last view). Differentiable.
        face_index: (B,kH,kW) int32 face index of the supersampled render, -1 for background.
        depth: (B,kH,kW) view depth of the supersampled render, ``far`` where empty.
    """

    image: torch.Tensor
    alpha: torch.Tensor
    face_index: torch.Tensor
    depth: torch.Tensor


@dataclass(frozen=True)
class _Spec:
    """The non-tensor arguments of one flat render."""

    faces: np.ndarray
    background: np.ndarray
    batch: int
    height: int
    width: int
    k: int
    near: float
    far: float
    fill_back: bool
    orthographic: bool
    num_threads: int
    edge_weight: float
    sweep_radius: int | None

    def scalars(self) -> tuple:
        return (self.background, self.batch, self.height, self.width, self.k, self.near, self.far, self.fill_back,
                self.orthographic)


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().contiguous().numpy()


class _FlatRenderOp(torch.autograd.Function):
    """``flat_render_forward`` / ``flat_render_backward`` of ``meshadv._raster``; inputs float32 CPU tensors."""

    @staticmethod
    def forward(  # type: ignore[override]
        ctx: Any,
        verts: torch.Tensor,
        colors: torch.Tensor,
        rotation: torch.Tensor,
        eye: torch.Tensor,
        scale: torch.Tensor,
        directions: torch.Tensor,
        light_colors: torch.Tensor,
        ambient: torch.Tensor,
        spec: _Spec,
    ) -> tuple[torch.Tensor, ...]:
        arrays = [_np(t) for t in (verts, colors, rotation, eye, scale, directions, light_colors, ambient)]
        v, c, r, e, s, d, lc, a = arrays
        image, full, face_index, depth, verts_screen, attrs = _native().flat_render_forward(
            v, spec.faces, c, r, e, s, d, lc, a, *spec.scalars(), spec.num_threads
        )
        rgba = torch.from_numpy(image).permute(0, 3, 1, 2)
        index_t, depth_t = torch.from_numpy(face_index), torch.from_numpy(depth)
        ctx.spec = spec
        ctx.save_for_backward(verts, colors, rotation, eye, scale, directions, light_colors, ambient)
        ctx.raster = (verts_screen, attrs, face_index, image if full is None else full)
        ctx.mark_non_differentiable(index_t, depth_t)
        ctx.set_materialize_grads(False)
        return rgba[:, :3], rgba[:, 3:4], index_t, depth_t

    @staticmethod
    def backward(ctx: Any, grad_image: torch.Tensor | None, grad_alpha: torch.Tensor | None,
                 *_unused: Any) -> tuple[torch.Tensor | None, ...]:
        needs = ctx.needs_input_grad
        if (grad_image is None and grad_alpha is None) or not any(needs[:8]):
            return (None,) * 9
        spec: _Spec = ctx.spec
        need_verts = any(needs[i] for i in (0, 2, 3, 4))
        cot = [None if g is None else g.detach().to(torch.float32).numpy() for g in (grad_image, grad_alpha)]
        v, c, r, e, s, d, lc, a = (_np(t) for t in ctx.saved_tensors)
        grads = _native().flat_render_backward(
            v, spec.faces, c, r, e, s, d, lc, a, *spec.scalars(), *ctx.raster, cot[0], cot[1],
            edge_weight=spec.edge_weight, need_verts=need_verts, sweep_radius=spec.sweep_radius,
            num_threads=spec.num_threads,
        )
        out = [torch.from_numpy(g) if need else None for g, need in zip(grads, needs[:8])]
        return (*out, None)


def supports_flat_render(verts: torch.Tensor, colors: torch.Tensor, camera: Camera, lights: Lights) -> bool:
    """True when :func:`flat_render` takes these inputs: float32 CPU vertices and colours, CPU camera and lights,
    and a native module that has the op (a build older than the Python package falls back to the composition)."""
    tensors = (verts, colors, camera.near, lights.ambient)
    return (verts.dtype == torch.float32 and colors.dtype == torch.float32
            and all(t.device.type == "cpu" for t in tensors) and hasattr(_native(), "flat_render_forward"))


def flat_render(
    verts: torch.Tensor,
    faces: np.ndarray,
    colors: torch.Tensor,
    camera: Camera,
    lights: Lights,
    size: tuple[int, int],
    background: torch.Tensor,
    fill_back: bool,
    antialias: int,
    num_threads: int,
    edge_weight: float,
    sweep_radius: int | None,
    batch: int,
    near: float,
    far: float,
) -> FlatRender:
    """The flat render of ``batch`` views in one native call (arguments checked by :func:`meshadv.render.render`).

    Args:
        verts: (Bv,N,3) float32 world-space vertices, Bv 1 or ``batch``.
        faces: (M,3) int32 C-contiguous vertex indices.
        colors: (Bc,M,3) float32 reflectances.
        camera: cameras of batch 1 or ``batch``.
        lights: lights of batch 1 or ``batch``.
        size: output ``(H, W)``.
        background: (3,) float32 RGB background.
        fill_back: two-sided shading; else back faces are culled.
        antialias: supersampling factor ``k``.
        num_threads: the native threads (0 = all).
        edge_weight: weight of the rasterization gradient on the screen-space vertices.
        sweep_radius: ``None`` for NMR's visibility gradient, else the local one's radius in supersampled pixels.
        batch: the number of views ``B``.
        near: the clipping depths of every view.
        far: see ``near``.

    Returns:
        :class:`FlatRender`.
    """
    if verts.shape[0] != batch:
        verts = verts.expand(batch, -1, -1)  # one copy per view: the views' gradients are summed by autograd
    rotation = camera.rotation().to(torch.float32)
    eye = camera.eye().to(torch.float32)
    scale = camera._projection_scale(torch.float32)
    directions = _normalize(lights.directions.to(torch.float32))
    spec = _Spec(
        faces=faces,
        background=_np(background),
        batch=batch,
        height=size[0],
        width=size[1],
        k=antialias,
        near=float(near),
        far=float(far),
        fill_back=bool(fill_back),
        orthographic=camera.orthographic,
        num_threads=num_threads,
        edge_weight=float(edge_weight),
        sweep_radius=sweep_radius,
    )
    image, alpha, face_index, depth = _FlatRenderOp.apply(
        verts, colors, rotation, eye, scale, directions, lights.colors.to(torch.float32),
        lights.ambient.to(torch.float32), spec,
    )
    return FlatRender(image=image, alpha=alpha, face_index=face_index, depth=depth)
