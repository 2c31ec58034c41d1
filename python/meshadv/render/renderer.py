"""``render``: camera + Lambert shading + the Rust rasterizer (NMR's pipeline), one native op for float32 CPU meshes."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F

from .. import _validate
from .._validate import finite_float
from ._checks import as_float_tensor, check_faces, require_instance
from ._memory import check_memory, estimate_forward_bytes
from .camera import Camera
from .flat import flat_render, supports_flat_render
from .lighting import Lights, shade
from .rasterize import RasterOutput, _native, _rasterize_int32, parse_image_size
from .visibility import sweep_radius as _sweep_radius

__all__ = ["RenderOutput", "render", "render_silhouette"]

#: Largest accepted anti-aliasing factor.
MAX_ANTIALIAS = 8


@dataclass(frozen=True)
class RenderOutput:
    """Result of :func:`render`.

    Attributes:
        image: (B,3,H,W) shaded colours in [0,1], background where empty. Differentiable.
        alpha: (B,1,H,W) coverage (1 on the mesh, 0 on background; fractional with antialias). Differentiable.
        depth: (B,H,W) view-space depth, ``far`` where empty (not differentiable).
        face_index: (B,H,W) int64 index of the drawn face, -1 for background.
    """

    image: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    face_index: torch.Tensor


def _check_mesh(vertices: Any, faces: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """Validate vertices (N,3)|(B,N,3) and faces (M,3); return batched vertices and int64 faces."""
    require_instance(vertices, torch.Tensor, "vertices")
    if not vertices.is_floating_point():
        raise ValueError(f"vertices must be a floating tensor, got {vertices.dtype}")
    if vertices.dim() not in (2, 3) or vertices.shape[-1] != 3:
        raise ValueError(f"vertices must have shape (N,3) or (B,N,3), got {tuple(vertices.shape)}")
    verts = vertices if vertices.dim() == 3 else vertices.unsqueeze(0)
    if verts.shape[0] == 0 or verts.shape[1] == 0:
        raise ValueError(f"vertices is empty, shape {tuple(vertices.shape)}")
    if not bool(torch.isfinite(verts.detach()).all()):
        raise ValueError("vertices contains NaN or Inf")
    check_faces(faces, verts.shape[1])
    return verts, faces.to(device=verts.device, dtype=torch.long)


def _batch_size(sizes: dict) -> int:
    """Common batch size of the named sizes (each 1 or B)."""
    others = {v for v in sizes.values() if v != 1}
    if len(others) > 1:
        raise ValueError(f"incompatible batch sizes: {sizes} (each must be 1 or the same B)")
    return others.pop() if others else 1


def _expand(t: torch.Tensor, b: int) -> torch.Tensor:
    """Expand the leading batch axis from 1 to ``b``."""
    return t if t.shape[0] == b else t.expand(b, *t.shape[1:])


def _check_antialias(antialias: Any) -> int:
    if isinstance(antialias, bool) or not isinstance(antialias, int) or not 1 <= antialias <= MAX_ANTIALIAS:
        raise ValueError(f"antialias must be an int in [1, {MAX_ANTIALIAS}], got {antialias!r}")
    return antialias


def _project_checked(verts: torch.Tensor, camera: Camera, b: int) -> torch.Tensor:
    """Project to screen space and reject views in which every vertex is behind the near plane."""
    require_instance(camera, Camera, "camera")
    verts_screen = _expand(camera.project(verts), b)
    z = verts_screen[..., 2].detach()
    near = _expand(camera.near.detach().to(z.dtype), b).unsqueeze(-1)
    far = _expand(camera.far.detach().to(z.dtype), b).unsqueeze(-1)
    behind = (z < near).all(dim=1)
    if bool(behind.any()):
        views = torch.nonzero(behind).flatten().tolist()
        raise ValueError(f"camera: all geometry is behind the camera's near plane in view(s) {views}")
    beyond = (z > far).all(dim=1)
    if bool(beyond.any()):
        views = torch.nonzero(beyond).flatten().tolist()
        raise ValueError(f"camera: all geometry is beyond the camera's far plane in view(s) {views}")
    return verts_screen


def _scale_gradient(x: torch.Tensor, weight: float) -> torch.Tensor:
    """``x`` in the forward pass; its gradient multiplied by ``weight`` in the backward pass (``x`` itself at 1)."""
    if weight == 1.0:
        return x
    frozen = x.detach()
    return frozen + weight * (x - frozen)


def _raster_groups(camera: Camera, b: int) -> list[tuple[list[int], float, float]]:
    """Group views by their (near, far) clip range so each group is one rasterize call."""
    near = _expand(camera.near.detach().cpu(), b).tolist()
    far = _expand(camera.far.detach().cpu(), b).tolist()
    groups: dict = {}
    for i, key in enumerate(zip(near, far)):
        groups.setdefault(key, []).append(i)
    return [(idx, key[0], key[1]) for key, idx in groups.items()]


def _rasterize_views(
    verts_screen: torch.Tensor,
    faces: torch.Tensor,
    attrs: torch.Tensor,
    size: tuple[int, int],
    background: torch.Tensor,
    camera: Camera,
    cull: bool,
    num_threads: int,
    sweep_radius: int | None = None,
) -> RasterOutput:
    """Rasterize, one call per distinct clip range (one call in the usual case); the face index stays int32."""
    b = verts_screen.shape[0]
    groups = _raster_groups(camera, b)
    if len(groups) == 1:
        _, near, far = groups[0]
        return _rasterize_int32(
            verts_screen, faces, attrs, size, background, near, far, cull, num_threads, camera.orthographic,
            sweep_radius,
        )
    parts, order = [], []
    for idx, near, far in groups:
        sel = torch.as_tensor(idx, device=verts_screen.device)
        parts.append(
            _rasterize_int32(
                verts_screen[sel],
                faces,
                attrs[sel],
                size,
                background,
                near,
                far,
                cull,
                num_threads,
                camera.orthographic,
                sweep_radius,
            )
        )
        order.extend(idx)
    inverse = torch.empty(b, dtype=torch.long)
    inverse[torch.as_tensor(order)] = torch.arange(b)
    inverse = inverse.to(verts_screen.device)
    return RasterOutput(
        image=torch.cat([p.image for p in parts])[inverse],
        face_index=torch.cat([p.face_index for p in parts])[inverse],
        depth=torch.cat([p.depth for p in parts])[inverse],
    )


def _background(background: Any, dtype: torch.dtype) -> torch.Tensor:
    if isinstance(background, torch.Tensor) and background.dtype == torch.bool:
        raise TypeError(f"background must be numeric, got {background.dtype}")
    bg = as_float_tensor(background, "background")
    bg = bg.detach().to(dtype=dtype, device="cpu").reshape(-1)
    if bg.numel() == 1:
        bg = bg.expand(3)
    if bg.numel() != 3:
        raise ValueError(f"background must be a scalar or 3 values (RGB), got {bg.numel()} values")
    if not bool(torch.isfinite(bg).all()):
        raise ValueError("background contains NaN or Inf")
    return bg


class _BoxDownsample(torch.autograd.Function):
    """``k x k`` box filter of a float32 CPU image, channels innermost, (B,kH,kW,C) -> (B,C,H,W) (a channels-last
    view), by the native kernels ``meshadv._raster.box_downsample`` / ``box_spread``.

    The same values, bit for bit, as ``F.avg_pool2d(image.permute(0, 3, 1, 2), k, k)`` and its backward (the ``k*k``
    samples added in its order, row by row, and the sum divided by ``k*k``); the backward writes the cotangent
    straight into the (B,kH,kW,C) layout the rasterizer's backward reads.
    """

    @staticmethod
    def forward(ctx: Any, image: torch.Tensor, k: int, num_threads: int) -> torch.Tensor:
        ctx.k, ctx.num_threads = k, num_threads
        out = _native().box_downsample(image.detach().contiguous().numpy(), k, num_threads)
        return torch.from_numpy(out).permute(0, 3, 1, 2)

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor, None, None]:
        cotangent = grad.permute(0, 2, 3, 1).contiguous().numpy()  # (B,H,W,C)
        return torch.from_numpy(_native().box_spread(cotangent, ctx.k, ctx.num_threads)), None, None


def _downsample(t: torch.Tensor, k: int, num_threads: int = 0) -> torch.Tensor:
    """Average-pool a channels-innermost (B,kH,kW,C) image to (B,C,H,W) (a channels-last view of (B,H,W,C)):
    natively for float32 on the CPU (every render), through ``F.avg_pool2d`` otherwise (e.g. float64 attributes)."""
    if k == 1:
        return t.permute(0, 3, 1, 2)
    if t.dtype == torch.float32 and t.device.type == "cpu":
        return _BoxDownsample.apply(t, k, num_threads)
    return F.avg_pool2d(t.permute(0, 3, 1, 2), k, k)


def render(
    vertices: torch.Tensor,
    faces: torch.Tensor,
    face_colors: torch.Tensor,
    camera: Camera,
    lights: Lights,
    image_size: int | Sequence[int] = 224,
    background: float | Sequence[float] | torch.Tensor = (1.0, 1.0, 1.0),
    fill_back: bool = True,
    antialias: int = 1,
    num_threads: int = 0,
    edge_gradient: float = 1.0,
    visibility_gradient: str = "nmr",
) -> RenderOutput:
    """Render a flat-shaded (per-face Lambert) mesh; differentiable in vertices, colours, lights and camera.

    One rasterize call with 4 channels (RGB + alpha = 1, background ``(bg_rgb, 0)``), so the silhouette receives NMR
    gradients too. Batches: ``B`` views of one mesh (vertices (N,3), camera/lights of batch B) or ``B`` meshes of one
    topology (vertices (B,N,3)); every batched argument must have batch 1 or B.

    Args:
        vertices: (N,3) or (B,N,3) world-space positions.
        faces: (M,3) integer vertex indices.
        face_colors: (M,3) or (B,M,3) reflectance in [0,1].
        camera: a :class:`Camera` of batch 1 or B.
        lights: a :class:`Lights` of batch 1 or B.
        image_size: ``int`` or ``(H, W)``.
        background: RGB background colour, scalar or 3 values (not differentiable).
        fill_back: two-sided rendering: back faces are drawn with normals flipped toward the camera. When False,
            back faces are culled (NMR ``fill_back=False``).
        antialias: render at ``antialias`` times the size and average-pool (``depth`` and ``face_index`` are then
            taken from one sample per output pixel, the one nearest its centre).
        num_threads: threads for the native rasterizer (0 = all).
        edge_gradient: weight ``w >= 0`` of NMR's rasterization gradient (the edges' sweep, docs/NMR_GRADIENT.md)
            on the screen-space vertex positions, hence on vertices and camera; the shading gradient (normals,
            colours, lights) is exact whatever ``w``. 1 (default) is NMR's definition; 0 leaves only shading. The
            image does not depend on it. Attacks use ``w < 1`` as a gradient estimator
            (:mod:`meshadv.attacks.budget`'s ``edge_gradient``).
        visibility_gradient: which rasterization gradient: ``"nmr"`` (default, docs/NMR_GRADIENT.md) or ``"local"``,
            NMR's sweeps truncated to :data:`~meshadv.render.visibility.LOCAL_RADIUS` output pixels of each edge
            (docs/LOCAL_GRADIENT.md; cheaper). The image does not depend on it.

    Returns:
        :class:`RenderOutput` (image (B,3,H,W), alpha (B,1,H,W), depth (B,H,W), face_index (B,H,W) int64).

    Raises:
        ValueError: bad shapes/dtypes/values, incompatible batch sizes, or all geometry behind the camera.

    Example:
        >>> from meshadv.render import Camera, Lights
        >>> verts = torch.tensor([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]])
        >>> faces, colors = torch.tensor([[0, 1, 2]]), torch.ones(1, 3)
        >>> out = render(verts, faces, colors, Camera.spherical(4.0), Lights.default(), 32)
        >>> out.image.shape, out.alpha.shape
        (torch.Size([1, 3, 32, 32]), torch.Size([1, 1, 32, 32]))
    """
    image, alpha, face_index, depth, k = _render_image_alpha(
        vertices, faces, face_colors, camera, lights, image_size, background, fill_back, antialias, num_threads,
        edge_gradient, visibility_gradient,
    )
    sub = slice(k // 2, None, k)
    return RenderOutput(
        image=image,
        alpha=alpha,
        depth=depth[:, sub, sub].contiguous(),
        face_index=face_index[:, sub, sub].to(torch.long, memory_format=torch.contiguous_format),
    )


def _render_image_alpha(
    vertices: torch.Tensor,
    faces: torch.Tensor,
    face_colors: torch.Tensor,
    camera: Camera,
    lights: Lights,
    image_size: int | Sequence[int],
    background: float | Sequence[float] | torch.Tensor,
    fill_back: bool,
    antialias: int,
    num_threads: int,
    edge_gradient: float,
    visibility_gradient: str = "nmr",
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, int]:
    """:func:`render`'s work (arguments as there, checked): the (B,3,H,W) image and (B,1,H,W) coverage
    (channels-last views), the (B,kH,kW) int32 face index and depth of the supersampled raster they were averaged
    from, and the supersampling factor ``k``. Callers that only need the image (attacks, every step) skip the depth
    and face-index maps.

    Float32 CPU inputs with one clip range for every view take the native flat render (:mod:`.flat`: one native
    op and one autograd node); others (float64, other devices, views of different clip ranges) the composition of
    :meth:`Camera.project`, :func:`shade` and the rasterizer, which gives the same images and gradients."""
    verts, faces = _check_mesh(vertices, faces)
    require_instance(lights, Lights, "lights")
    if not isinstance(face_colors, torch.Tensor) or not face_colors.is_floating_point():
        raise ValueError("face_colors must be a floating torch.Tensor of shape (M,3) or (B,M,3)")
    colors = face_colors if face_colors.dim() == 3 else face_colors.unsqueeze(0)
    if colors.dim() != 3 or colors.shape[1:] != (faces.shape[0], 3):
        raise ValueError(
            f"face_colors must have shape (M,3) or (B,M,3) with M = {faces.shape[0]}, got {tuple(face_colors.shape)}"
        )
    if not bool(torch.isfinite(colors.detach()).all()):
        raise ValueError("face_colors contains NaN or Inf")
    require_instance(camera, Camera, "camera")
    b = _batch_size(
        {
            "vertices": verts.shape[0],
            "face_colors": colors.shape[0],
            "camera": len(camera),
            "lights": len(lights),
        }
    )
    height, width = parse_image_size(image_size)
    k = _check_antialias(antialias)
    parse_image_size((height * k, width * k), "image_size * antialias")
    edge_weight = finite_float("edge_gradient", edge_gradient, low=0.0)
    radius = _sweep_radius(visibility_gradient, k)

    groups = _raster_groups(camera, b)
    if len(groups) == 1 and supports_flat_render(verts, colors, camera, lights):
        _, near, far = groups[0]
        num_threads = _validate.num_threads("num_threads", num_threads)
        check_memory(
            estimate_forward_bytes(b, height * k, width * k, 4, verts.shape[1], faces.shape[0]), "rasterize"
        )
        flat = flat_render(
            verts, faces.to(torch.int32).contiguous().numpy(), colors, camera, lights, (height, width),
            _background(background, torch.float32), bool(fill_back), k, num_threads, edge_weight, radius, b,
            near, far,
        )
        return flat.image, flat.alpha, flat.face_index, flat.depth, k
    verts_screen = _scale_gradient(_project_checked(verts, camera, b), edge_weight)
    shaded = _expand(shade(verts, faces, colors, lights, camera, two_sided=bool(fill_back)), b)
    attrs = torch.cat([shaded, torch.ones_like(shaded[..., :1])], dim=-1)
    bg = torch.cat([_background(background, torch.float32), torch.zeros(1)])
    out = _rasterize_views(
        verts_screen, faces, attrs, (height * k, width * k), bg, camera, not fill_back, num_threads, radius
    )
    rgba = _downsample(out.image, k, num_threads)
    return rgba[:, :3], rgba[:, 3:4], out.face_index, out.depth, k


def render_silhouette(
    vertices: torch.Tensor,
    faces: torch.Tensor,
    camera: Camera,
    image_size: int | Sequence[int] = 224,
    fill_back: bool = True,
    antialias: int = 1,
    num_threads: int = 0,
) -> torch.Tensor:
    """Render the silhouette (1 on the mesh, 0 elsewhere), with NMR gradients for the vertices and camera.

    Args:
        vertices: (N,3) or (B,N,3) world-space positions.
        faces: (M,3) integer vertex indices.
        camera: a :class:`Camera` of batch 1 or B.
        image_size: ``int`` or ``(H, W)``.
        fill_back: when False, back faces are culled.
        antialias: supersampling factor (average-pooled).
        num_threads: threads for the native rasterizer (0 = all).

    Returns:
        (B,1,H,W) coverage in [0,1].

    Raises:
        ValueError: bad input, or all geometry behind the camera.
    """
    verts, faces = _check_mesh(vertices, faces)
    require_instance(camera, Camera, "camera")
    b = _batch_size({"vertices": verts.shape[0], "camera": len(camera)})
    height, width = parse_image_size(image_size)
    k = _check_antialias(antialias)
    parse_image_size((height * k, width * k), "image_size * antialias")
    verts_screen = _project_checked(verts, camera, b)
    attrs = torch.ones(b, faces.shape[0], 1, dtype=verts_screen.dtype, device=verts_screen.device)
    out = _rasterize_views(
        verts_screen,
        faces,
        attrs,
        (height * k, width * k),
        torch.zeros(1),
        camera,
        not fill_back,
        num_threads,
    )
    return _downsample(out.image, k, num_threads)
