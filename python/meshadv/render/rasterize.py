"""The differentiable rasterizer: a thin autograd wrapper around the Rust op ``meshadv._raster``.

The op works on screen-space vertices ``(x_ndc, y_ndc, z_view)`` and per-face attributes (NMR's split): the
forward pass draws the nearest face at each pixel centre and writes its attributes (flat shading); the backward
pass gives the exact gradient of the attributes and NMR's approximate rasterization gradient for the vertex
positions (see docs/NMR_GRADIENT.md). Every argument is validated here, before the native code is called.
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np
import torch

from .. import _validate
from ._checks import as_float_tensor, check_faces, require_instance
from ._memory import check_memory, estimate_forward_bytes
from .visibility import sweep_radius as _sweep_radius

__all__ = ["MAX_IMAGE_SIDE", "RasterOutput", "native_available", "parse_image_size", "rasterize"]

#: Largest accepted image side in pixels.
MAX_IMAGE_SIDE = 16384
_MAX_PIXELS_TIMES_CHANNELS = 2**31 - 1
_FLOAT32_MAX = float(np.finfo(np.float32).max)


def _native() -> ModuleType:
    """Import the native module, with an actionable message when it is missing."""
    try:
        return importlib.import_module("meshadv._raster")
    except ImportError as exc:  # pragma: no cover - depends on the build
        raise ImportError(
            "the native module meshadv._raster is not built; run `maturin develop --release` in the repository root"
        ) from exc


def native_available() -> bool:
    """True when the native module ``meshadv._raster`` can be imported."""
    try:
        _native()
    except ImportError:
        return False
    return True


@dataclass(frozen=True)
class RasterOutput:
    """Output of :func:`rasterize`.

    Attributes:
        image: (B,H,W,C) attributes of the face drawn at each pixel, ``background`` where empty. Differentiable.
        face_index: (B,H,W) int64 index of the face drawn at each pixel, -1 for background.
        depth: (B,H,W) view-space depth of the drawn surface, ``far`` where empty (not differentiable).
    """

    image: torch.Tensor
    face_index: torch.Tensor
    depth: torch.Tensor


def parse_image_size(image_size: int | Sequence[int], name: str = "image_size") -> tuple[int, int]:
    """Validate an image size given as ``int`` or ``(H, W)`` and return ``(H, W)``.

    Raises:
        TypeError: not an integer or a pair of integers.
        ValueError: not positive, or larger than ``MAX_IMAGE_SIDE``.
    """
    if isinstance(image_size, (tuple, list)):
        if len(image_size) != 2:
            raise ValueError(f"{name} must be an int or a pair (H, W) of ints, got {len(image_size)} values")
        hw = (_validate.integer(f"{name}[0]", image_size[0]), _validate.integer(f"{name}[1]", image_size[1]))
    elif isinstance(image_size, (int, np.integer)) and not isinstance(image_size, bool):
        hw = (int(image_size), int(image_size))
    else:
        raise TypeError(f"{name} must be an int or a pair (H, W) of ints, got {image_size!r}")
    if min(hw) < 1 or max(hw) > MAX_IMAGE_SIDE:
        raise ValueError(f"{name} must be between 1 and {MAX_IMAGE_SIDE} pixels per side, got {hw}")
    return hw


def _check_float_tensor(t: Any, name: str, ndims: tuple[int, ...], shape_doc: str) -> torch.Tensor:
    """Check a floating tensor's type, rank and finiteness."""
    require_instance(t, torch.Tensor, name)
    if not t.is_floating_point():
        raise ValueError(f"{name} must be a floating tensor (float32 or float64), got {t.dtype}")
    if t.dim() not in ndims:
        raise ValueError(f"{name} must have shape {shape_doc}, got {tuple(t.shape)}")
    if not bool(torch.isfinite(t.detach()).all()):
        raise ValueError(f"{name} contains NaN or Inf")
    if t.dtype == torch.float64 and t.numel() and float(t.detach().abs().max()) > _FLOAT32_MAX:
        raise ValueError(f"{name} holds values beyond float32's range (the native op computes in float32)")
    return t


def _to_numpy_f32(t: torch.Tensor) -> np.ndarray:
    """Zero-copy view when ``t`` is a contiguous float32 CPU tensor; otherwise one conversion copy."""
    return t.detach().to(device="cpu", dtype=torch.float32).contiguous().numpy()


def _to_numpy_i32(t: torch.Tensor) -> np.ndarray:
    """Zero-copy view when ``t`` is a contiguous int32 CPU tensor; otherwise one conversion copy."""
    return t.detach().to(device="cpu", dtype=torch.int32).contiguous().numpy()


class _Rasterize(torch.autograd.Function):
    """Private autograd op: ``meshadv._raster.rasterize_forward`` / ``rasterize_backward``."""

    @staticmethod
    def forward(
        ctx: Any,
        verts_screen: torch.Tensor,
        face_attrs: torch.Tensor,
        faces: torch.Tensor,
        background: torch.Tensor,
        height: int,
        width: int,
        near: float,
        far: float,
        cull_backfaces: bool,
        num_threads: int,
        orthographic: bool,
        sweep_radius: int | None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        native = _native()
        v_np, a_np = _to_numpy_f32(verts_screen), _to_numpy_f32(face_attrs)
        f_np, bg_np = _to_numpy_i32(faces), _to_numpy_f32(background)
        image, face_index, depth = native.rasterize_forward(
            v_np, f_np, a_np, bg_np, height, width, near, far, cull_backfaces, num_threads, orthographic
        )
        device = verts_screen.device
        image_t = torch.from_numpy(image).to(device)
        index_t = torch.from_numpy(face_index).to(device)
        depth_t = torch.from_numpy(depth).to(device)
        ctx.save_for_backward(verts_screen, face_attrs, faces, background, image_t, index_t)
        ctx.params = (height, width, near, far, cull_backfaces, num_threads, orthographic)
        ctx.sweep_radius = sweep_radius
        ctx.mark_non_differentiable(index_t, depth_t)
        # The index and depth never have a cotangent: no zero-filled (B,H,W) maps for them in every backward.
        ctx.set_materialize_grads(False)
        return image_t, index_t, depth_t

    @staticmethod
    def backward(
        ctx: Any, grad_image: torch.Tensor | None, _grad_index: Any, _grad_depth: Any
    ) -> tuple[torch.Tensor | None, ...]:
        verts_screen, face_attrs, faces, background, image, face_index = ctx.saved_tensors
        height, width, near, far, cull_backfaces, num_threads, orthographic = ctx.params
        need_v, need_a = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        if grad_image is None or not (need_v or need_a):
            return (None,) * 12
        # Attribute-only backward (e.g. texture attacks) skips the NMR vertex sweep, the expensive part.
        grad_v, grad_a = _native().rasterize_backward(
            _to_numpy_f32(verts_screen),
            _to_numpy_i32(faces),
            _to_numpy_f32(face_attrs),
            _to_numpy_f32(background),
            height,
            width,
            near,
            far,
            cull_backfaces,
            _to_numpy_i32(face_index),
            _to_numpy_f32(image),
            _to_numpy_f32(grad_image),
            num_threads,
            orthographic,
            vertex_grad=bool(need_v),
            sweep_radius=ctx.sweep_radius,
        )
        if need_v and not np.isfinite(grad_v).all() and bool(torch.isfinite(grad_image).all()):
            peak = float(face_attrs.detach().abs().max())
            raise ValueError(
                f"face_attrs: the vertex gradient overflows float32 (max |face_attrs| = {peak:.3g}); "
                "scale the attributes down (the gradient grows with the attribute jump across an edge times the "
                "image size)"
            )
        gv = torch.from_numpy(grad_v).to(device=verts_screen.device, dtype=verts_screen.dtype) if need_v else None
        ga = torch.from_numpy(grad_a).to(device=face_attrs.device, dtype=face_attrs.dtype) if need_a else None
        return gv, ga, None, None, None, None, None, None, None, None, None, None


def rasterize(
    verts_screen: torch.Tensor,
    faces: torch.Tensor,
    face_attrs: torch.Tensor,
    image_size: int | Sequence[int],
    background: float | Sequence[float] | torch.Tensor | None = None,
    near: float = 0.1,
    far: float = 100.0,
    cull_backfaces: bool = False,
    num_threads: int = 0,
    orthographic: bool = False,
    visibility_gradient: str = "nmr",
) -> RasterOutput:
    """Rasterize screen-space triangles with per-face attributes (differentiable, NMR gradients).

    Args:
        verts_screen: (B,N,3) or (N,3) float ``(x_ndc, y_ndc, z_view)``; NDC [-1,1], +y up.
        faces: (M,3) integer vertex indices in ``[0, N)``.
        face_attrs: (B,M,C) or (M,C) float per-face attributes (e.g. RGB + 1 for alpha), broadcast over B.
        image_size: ``int`` or ``(H, W)``.
        background: scalar or (C,) attribute value of empty pixels (default zeros).
        near: near clipping depth on ``z_view``.
        far: far clipping depth (> near).
        cull_backfaces: drop faces whose normal faces away from the camera.
        num_threads: worker threads for the native op (0 = all available). Results do not depend on it.
        orthographic: interpolate depth linearly (orthographic camera) instead of ``1/z`` (perspective).
        visibility_gradient: the vertex gradient, ``"nmr"`` (docs/NMR_GRADIENT.md) or ``"local"``: NMR's sweeps
            truncated to :data:`~meshadv.render.visibility.LOCAL_RADIUS` pixels of each edge
            (docs/LOCAL_GRADIENT.md). The image does not depend on it.

    Returns:
        :class:`RasterOutput` with ``image`` (B,H,W,C) in the dtype of ``face_attrs``, ``face_index`` (B,H,W) int64
        and ``depth`` (B,H,W). Tensors are on the device of ``verts_screen`` (computed on the CPU).

    Raises:
        ValueError: bad dtype, shape, NaN/Inf, face index out of range, empty mesh, bad image size or clip range,
            unknown ``visibility_gradient``, naming the offending argument.
        ImportError: the native module is not built.

    Example:
        >>> verts = torch.tensor([[[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [0.0, 1.0, 1.0]]])
        >>> out = rasterize(verts, torch.tensor([[0, 2, 1]]), torch.ones(1, 1, 1), 8)
        >>> out.image.shape
        torch.Size([1, 8, 8, 1])
    """
    out = _rasterize_int32(
        verts_screen, faces, face_attrs, image_size, background, near, far, cull_backfaces, num_threads, orthographic,
        _sweep_radius(visibility_gradient),
    )
    return RasterOutput(image=out.image, face_index=out.face_index.long(), depth=out.depth)


def _rasterize_int32(
    verts_screen: torch.Tensor,
    faces: torch.Tensor,
    face_attrs: torch.Tensor,
    image_size: int | Sequence[int],
    background: float | Sequence[float] | torch.Tensor | None,
    near: float,
    far: float,
    cull_backfaces: bool,
    num_threads: int,
    orthographic: bool,
    sweep_radius: int | None = None,
) -> RasterOutput:
    """:func:`rasterize` with the face index as the core's int32 (renderers that subsample it, or never read it,
    convert only what they keep) and the native backward's ``sweep_radius`` (``None``: NMR's gradient)."""
    verts_screen = _check_float_tensor(verts_screen, "verts_screen", (2, 3), "(B,N,3) or (N,3)")
    if verts_screen.dim() == 2:
        verts_screen = verts_screen.unsqueeze(0)
    b, n = verts_screen.shape[0], verts_screen.shape[1]
    if verts_screen.shape[2] != 3:
        raise ValueError(f"verts_screen must have shape (B,N,3), got {tuple(verts_screen.shape)}")
    if b == 0:
        raise ValueError("verts_screen has batch size 0")
    if n == 0:
        raise ValueError("verts_screen is empty (N = 0 vertices)")

    m = check_faces(faces, n).shape[0]

    face_attrs = _check_float_tensor(face_attrs, "face_attrs", (2, 3), "(B,M,C) or (M,C)")
    if face_attrs.dim() == 2:
        face_attrs = face_attrs.unsqueeze(0)
    if face_attrs.shape[1] != m:
        raise ValueError(f"face_attrs must have one row per face (M = {m}), got shape {tuple(face_attrs.shape)}")
    c = face_attrs.shape[2]
    if c == 0:
        raise ValueError("face_attrs must have at least one channel (C >= 1)")
    if face_attrs.shape[0] not in (1, b):
        raise ValueError(f"face_attrs batch size {face_attrs.shape[0]} does not match verts_screen batch size {b}")
    if face_attrs.shape[0] != b:
        face_attrs = face_attrs.expand(b, -1, -1)

    height, width = parse_image_size(image_size)
    if b * height * width * max(c, 1) > _MAX_PIXELS_TIMES_CHANNELS:
        raise ValueError(f"image_size {(height, width)} with batch {b} and {c} channels is too large")

    if background is None:
        bg = torch.zeros(c, dtype=torch.float32)
    else:
        bg = as_float_tensor(background, "background")
        bg = bg.detach().to(torch.float32).reshape(-1)
        if bg.numel() == 1:
            bg = bg.expand(c)
        if bg.numel() != c:
            raise ValueError(f"background must be a scalar or have C = {c} values, got {bg.numel()}")
        if not bool(torch.isfinite(bg).all()):
            raise ValueError("background contains NaN or Inf")

    near = _validate.finite_float("near", near, low=0.0)
    far = _validate.finite_float("far", far)
    if not far > near:
        raise ValueError(f"far must be > near, got near={near} far={far}")
    num_threads = _validate.num_threads("num_threads", num_threads)
    check_memory(estimate_forward_bytes(b, height, width, c, n, m), "rasterize")

    image, face_index, depth = _Rasterize.apply(
        verts_screen,
        face_attrs,
        faces,
        bg.cpu(),
        height,
        width,
        float(near),
        float(far),
        bool(cull_backfaces),
        int(num_threads),
        bool(orthographic),
        sweep_radius,
    )
    return RasterOutput(image=image.to(face_attrs.dtype), face_index=face_index, depth=depth)
