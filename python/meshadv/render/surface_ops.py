"""Autograd wrappers of the native per-pixel surface ops (``meshadv._raster``): fragments, perspective-correct
weights, per-corner attribute interpolation, the UV texture sampled at each pixel (UV interpolation and bilinear
sample in one pass) and the vertex gradient of an image whose colours vary within faces.

Each op computes on the CPU in float32 and returns tensors on the device of its first tensor argument; gradients are
exact (``pixel_weights``, ``interpolate``, ``sample_uv_texture``) or NMR's approximate visibility gradient
(``pixel_visibility``, docs/NMR_GRADIENT.md with colours read from the image). Arguments are assumed checked by the
caller (:func:`meshadv.render.surface.render_surface`); the native code checks them again and raises ``ValueError``
naming the argument.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from .rasterize import _native

__all__ = ["Fragments", "fragments", "interpolate", "pixel_visibility", "pixel_weights", "sample_uv_texture"]

WRAP_MODES = ("repeat", "clamp")


def _f32(t: torch.Tensor) -> np.ndarray:
    """A contiguous float32 CPU array of ``t`` (zero-copy when it already is one)."""
    return t.detach().to(device="cpu", dtype=torch.float32).contiguous().numpy()


def _i32(t: torch.Tensor) -> np.ndarray:
    """A contiguous int32 CPU array of ``t`` (zero-copy when it already is one)."""
    return t.detach().to(device="cpu", dtype=torch.int32).contiguous().numpy()


def _as_inputs(
    grads: Sequence[np.ndarray], needs: Sequence[bool], types: Sequence[tuple[torch.dtype, torch.device]]
) -> list[torch.Tensor | None]:
    """Native gradients as tensors of their inputs' ``(dtype, device)`` in ``types``; ``None`` where not needed."""
    return [
        torch.from_numpy(g).to(device=device, dtype=dtype) if need else None
        for g, need, (dtype, device) in zip(grads, needs, types)
    ]


@dataclass(frozen=True)
class Fragments:
    """The face drawn at each pixel and the raster parameters it was drawn with.

    Attributes:
        face_index: (B,H,W) int32 face index, -1 on background.
        depth: (B,H,W) view depth, ``far`` on background.
        near: the near clip depth of each view, (B,) floats.
        far: the far clip depth of each view, (B,) floats.
        cull_backfaces: whether back faces were culled.
        orthographic: linear (orthographic) instead of perspective depth.
    """

    face_index: torch.Tensor
    depth: torch.Tensor
    near: tuple[float, ...]
    far: tuple[float, ...]
    cull_backfaces: bool
    orthographic: bool

    def groups(self) -> list[tuple[list[int], float, float]]:
        """Views grouped by their clip range: ``[(views, near, far), ...]``."""
        out: dict[tuple[float, float], list[int]] = {}
        for i, key in enumerate(zip(self.near, self.far)):
            out.setdefault(key, []).append(i)
        return [(idx, key[0], key[1]) for key, idx in out.items()]


def fragments(
    verts_screen: torch.Tensor,
    faces: torch.Tensor,
    size: tuple[int, int],
    near: tuple[float, ...],
    far: tuple[float, ...],
    cull_backfaces: bool,
    orthographic: bool,
    num_threads: int,
) -> Fragments:
    """Rasterize (not differentiable): the face index and depth of every pixel, one native call per clip range.

    Args:
        verts_screen: (B,N,3) screen-space vertices ``(x_ndc, y_ndc, z_view)``.
        faces: (M,3) vertex indices.
        size: ``(H, W)``.
        near: (B,) near clip depths.
        far: (B,) far clip depths.
        cull_backfaces: drop back faces.
        orthographic: orthographic depth.
        num_threads: native threads (0 = all).
    """
    b = verts_screen.shape[0]
    m = faces.shape[0]
    face_index = torch.empty((b, *size), dtype=torch.int32)
    depth = torch.empty((b, *size), dtype=torch.float32)
    frags = Fragments(face_index, depth, tuple(near), tuple(far), bool(cull_backfaces), bool(orthographic))
    v_np, f_np = _f32(verts_screen), _i32(faces)
    ones = np.ones((1, m, 1), dtype=np.float32)
    for idx, lo, hi in frags.groups():
        sel = np.asarray(idx)
        _, fi, dp = _native().rasterize_forward(
            np.ascontiguousarray(v_np[sel]),
            f_np,
            np.ascontiguousarray(np.broadcast_to(ones, (len(idx), m, 1))),
            np.zeros(1, dtype=np.float32),
            size[0],
            size[1],
            lo,
            hi,
            cull_backfaces,
            num_threads,
            orthographic,
        )
        face_index[torch.as_tensor(idx)] = torch.from_numpy(fi)
        depth[torch.as_tensor(idx)] = torch.from_numpy(dp)
    return frags


class _PixelWeights(torch.autograd.Function):
    """Perspective-correct weights of the drawn face, differentiable in ``verts_screen``."""

    @staticmethod
    def forward(
        ctx: Any, verts_screen: torch.Tensor, faces: torch.Tensor, frags: Fragments, num_threads: int
    ) -> torch.Tensor:
        args = (_f32(verts_screen), _i32(faces), frags.face_index.numpy())
        near, far = min(frags.near), max(frags.far)
        w = _native().pixel_weights(*args, near, far, frags.orthographic, num_threads)
        ctx.args, ctx.clip, ctx.orthographic, ctx.num_threads = args, (near, far), frags.orthographic, num_threads
        ctx.dtype, ctx.device = verts_screen.dtype, verts_screen.device
        return torch.from_numpy(w).to(verts_screen.device)

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor | None, None, None, None]:
        if not ctx.needs_input_grad[0]:
            return None, None, None, None
        g = _native().pixel_weights_backward(*ctx.args, _f32(grad), *ctx.clip, ctx.orthographic, ctx.num_threads)
        return torch.from_numpy(g).to(device=ctx.device, dtype=ctx.dtype), None, None, None


def pixel_weights(
    verts_screen: torch.Tensor, faces: torch.Tensor, frags: Fragments, num_threads: int = 0
) -> torch.Tensor:
    """(B,H,W,3) perspective-correct barycentric weights of the face drawn at each pixel (0 on background);
    differentiable in ``verts_screen`` (x, y and z, exact at fixed face assignment)."""
    return _PixelWeights.apply(verts_screen, faces, frags, num_threads)


class _Interpolate(torch.autograd.Function):
    """Per-corner attributes interpolated with the weights, differentiable in the weights and the values."""

    @staticmethod
    def forward(
        ctx: Any,
        weights: torch.Tensor,
        values: torch.Tensor,
        corners: torch.Tensor,
        verts_screen: torch.Tensor,
        faces: torch.Tensor,
        frags: Fragments,
        num_threads: int,
    ) -> torch.Tensor:
        mesh = (_f32(verts_screen), _i32(faces), frags.face_index.numpy())
        args = (_f32(weights), _i32(corners), _f32(values))
        out = _native().interpolate(*mesh, *args, num_threads)
        ctx.mesh, ctx.args, ctx.num_threads = mesh, args, num_threads
        ctx.types = [(t.dtype, t.device) for t in (weights, values)]
        return torch.from_numpy(out).to(device=weights.device, dtype=values.dtype)

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        need_w, need_v = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        if not (need_w or need_v):
            return (None,) * 7
        gv, gw = _native().interpolate_backward(*ctx.mesh, *ctx.args, _f32(grad), ctx.num_threads)
        return (*_as_inputs((gw, gv), (need_w, need_v), ctx.types), None, None, None, None, None)


def interpolate(
    weights: torch.Tensor,
    values: torch.Tensor,
    corners: torch.Tensor,
    verts_screen: torch.Tensor,
    faces: torch.Tensor,
    frags: Fragments,
    num_threads: int = 0,
) -> torch.Tensor:
    """(B,H,W,K) per-corner attributes ``values`` (Bv,A,K) with rows ``corners`` (M,3), interpolated with
    ``weights`` (B,H,W,3) at every pixel (0 on background); differentiable in ``weights`` and ``values``."""
    return _Interpolate.apply(weights, values, corners, verts_screen, faces, frags, num_threads)


class _SampleUvTexture(torch.autograd.Function):
    """The texture sampled at each pixel's perspective-correct UV in one native pass, differentiable in the texels,
    the UVs and ``verts_screen`` (the UVs moving with the vertices at fixed face assignment)."""

    @staticmethod
    def forward(
        ctx: Any,
        texture: torch.Tensor,
        uvs: torch.Tensor,
        verts_screen: torch.Tensor,
        corners: torch.Tensor,
        faces: torch.Tensor,
        frags: Fragments,
        wrap: str,
        num_threads: int,
    ) -> torch.Tensor:
        face_index, texels = frags.face_index.numpy(), _f32(texture)
        args = (_f32(verts_screen), _i32(faces), face_index, _i32(corners), _f32(uvs), texels)
        opts = (min(frags.near), max(frags.far), frags.orthographic, wrap, num_threads)
        out, planes = _native().sample_uv_texture(*args, *opts)
        # The backward reuses the forward's checked inputs and drawn faces' UV planes.
        ctx.planes, ctx.face_index, ctx.texels, ctx.opts = planes, face_index, texels, (wrap, num_threads)
        ctx.types = [(t.dtype, t.device) for t in (texture, uvs, verts_screen)]
        return torch.from_numpy(out).to(device=verts_screen.device, dtype=texture.dtype)

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        needs = ctx.needs_input_grad[:3]
        if not any(needs):
            return (None,) * 8
        gt, guv, gv = _native().sample_uv_texture_backward(
            ctx.planes, ctx.face_index, ctx.texels, _f32(grad), *ctx.opts
        )
        return (*_as_inputs((gt, guv, gv), needs, ctx.types), None, None, None, None, None)


def sample_uv_texture(
    texture: torch.Tensor,
    uvs: torch.Tensor,
    verts_screen: torch.Tensor,
    corners: torch.Tensor,
    faces: torch.Tensor,
    frags: Fragments,
    wrap: str = "repeat",
    num_threads: int = 0,
) -> torch.Tensor:
    """(B,H,W,C) bilinear samples of ``texture`` (Bt,Ht,Wt,C) at each drawn pixel's perspective-correct UV (0
    elsewhere), interpolated from ``uvs`` (Bv,T,2) with rows ``corners`` (M,3); UV origin at the bottom-left of the
    image (docs/TEXTURES.md). Differentiable in ``texture``, ``uvs`` and ``verts_screen`` (x, y and z, exact at fixed
    face assignment)."""
    return _SampleUvTexture.apply(texture, uvs, verts_screen, corners, faces, frags, wrap, num_threads)


class _PixelVisibility(torch.autograd.Function):
    """Identity on the image; NMR's visibility gradient to ``verts_screen`` from the image and its cotangent."""

    @staticmethod
    def forward(
        ctx: Any,
        verts_screen: torch.Tensor,
        image: torch.Tensor,
        faces: torch.Tensor,
        frags: Fragments,
        num_threads: int,
        sweep_radius: int | None,
    ) -> torch.Tensor:
        ctx.save_for_backward(verts_screen, image)
        ctx.faces, ctx.frags, ctx.num_threads, ctx.sweep_radius = faces, frags, num_threads, sweep_radius
        return image.clone()

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        verts_screen, image = ctx.saved_tensors
        grad_v = None
        if ctx.needs_input_grad[0]:
            frags: Fragments = ctx.frags
            v_np, f_np = _f32(verts_screen), _i32(ctx.faces)
            im_np, g_np = _f32(image), _f32(grad)
            out = np.zeros(v_np.shape, dtype=np.float32)
            for idx, near, far in frags.groups():
                sel = np.asarray(idx)
                out[sel] = _native().image_vertex_backward(
                    np.ascontiguousarray(v_np[sel]),
                    f_np,
                    np.ascontiguousarray(frags.face_index.numpy()[sel]),
                    np.ascontiguousarray(im_np[sel]),
                    np.ascontiguousarray(g_np[sel]),
                    near,
                    far,
                    frags.cull_backfaces,
                    frags.orthographic,
                    ctx.num_threads,
                    ctx.sweep_radius,
                )
            grad_v = torch.from_numpy(out).to(device=verts_screen.device, dtype=verts_screen.dtype)
        grad_image = grad if ctx.needs_input_grad[1] else None
        return grad_v, grad_image, None, None, None, None


def pixel_visibility(
    verts_screen: torch.Tensor,
    image: torch.Tensor,
    faces: torch.Tensor,
    frags: Fragments,
    num_threads: int = 0,
    sweep_radius: int | None = None,
) -> torch.Tensor:
    """``image`` (B,H,W,C) itself, with NMR's visibility gradient of it added to ``verts_screen`` in the backward pass
    (the colours a face would give the pixels beyond its edges are read from the image at the edge);
    ``sweep_radius`` as :func:`meshadv.render.visibility.sweep_radius` returns it (``None``: NMR's sweeps)."""
    return _PixelVisibility.apply(verts_screen, image, faces, frags, num_threads, sweep_radius)
