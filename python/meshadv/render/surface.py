"""``render_surface``: renders with attributes that vary within faces: a UV texture image, per-vertex colours, and
smooth (per-pixel interpolated vertex normal) or flat Lambert shading.

Pipeline per view: project (PyTorch), rasterize the face index (Rust), the texture sampled at each pixel's
perspective-correct UV (Rust, one pass), perspective-correct weights of the drawn face with colours / normals
interpolated with them (Rust), Lambert + ambient + K directional lights per pixel (PyTorch), RGB + coverage, NMR's
visibility gradient on the image (Rust), box filter.
Gradients: exact to texels, UVs, vertex colours, normals and lights, and to vertex positions through the weights
(interior) plus NMR's visibility gradient (edges), weighted by ``edge_gradient``. Conventions: docs/TEXTURES.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch

from .._validate import MAX_TEXTURE_COORDINATE, finite_float
from ._checks import require_instance
from ._ops import small_matmul
from .camera import Camera, _normalize
from .lighting import Lights, face_normals, orient_normals
from .rasterize import parse_image_size
from .renderer import (
    RenderOutput,
    _background,
    _batch_size,
    _check_antialias,
    _check_mesh,
    _downsample,
    _expand,
    _project_checked,
    _scale_gradient,
)
from .visibility import sweep_radius
from .surface_ops import WRAP_MODES, fragments, interpolate, pixel_visibility, pixel_weights, sample_uv_texture

__all__ = ["SHADING_MODES", "render_surface", "vertex_normals"]

#: Shading modes: ``flat`` (one normal per face, NMR's model) and ``smooth`` (vertex normals interpolated per pixel).
SHADING_MODES = ("flat", "smooth")


def vertex_normals(vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Area-weighted unit vertex normals (the sum of the adjacent faces' unnormalised normals), differentiable.

    Args:
        vertices: (N,3) or (B,N,3) positions.
        faces: (M,3) vertex indices.

    Returns:
        (B,N,3) unit normals (B = 1 for unbatched vertices); a vertex of no face gets a zero normal.
    """
    verts = vertices if vertices.dim() == 3 else vertices.unsqueeze(0)
    faces = faces.long()
    tri = verts[:, faces]
    n = torch.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0], dim=-1)
    acc = torch.zeros_like(verts)
    for k in range(3):
        acc = acc.index_add(1, faces[:, k], n)
    return _normalize(acc)


def _float_array(value: Any, name: str, shapes: tuple[str, ...], ndims: tuple[int, ...], last: int) -> torch.Tensor:
    """Check a finite floating tensor of rank in ``ndims`` whose last axis is ``last``."""
    require_instance(value, torch.Tensor, name)
    if not value.is_floating_point():
        raise ValueError(f"{name} must be a floating tensor, got {value.dtype}")
    if value.dim() not in ndims or value.shape[-1] != last or 0 in value.shape:
        raise ValueError(f"{name} must have shape {' or '.join(shapes)} (non-empty), got {tuple(value.shape)}")
    if not bool(torch.isfinite(value.detach()).all()):
        raise ValueError(f"{name} contains NaN or Inf")
    return value


def _corners(value: Any, name: str, num_faces: int, rows: int, rows_name: str) -> torch.Tensor:
    """Check an (M,3) integer corner index into ``rows`` rows of ``rows_name``."""
    require_instance(value, torch.Tensor, name)
    if value.is_floating_point() or value.dtype == torch.bool:
        raise ValueError(f"{name} must be an integer tensor, got {value.dtype}")
    if tuple(value.shape) != (num_faces, 3):
        raise ValueError(
            f"{name} must have shape (M,3) with M = {num_faces} (one row per face), got {tuple(value.shape)}"
        )
    lo, hi = int(value.min()), int(value.max())
    if lo < 0 or hi >= rows:
        raise ValueError(f"{name} holds rows in [{lo}, {hi}] but {rows_name} has {rows} rows")
    return value


def _lambert(normals: torch.Tensor, lights: Lights) -> torch.Tensor:
    """``ambient + sum_j c_j max(dot(d_j, n), 0)`` for (B,P,3) unit normals: (B,P,3)."""
    dtype = normals.dtype
    dirs = _normalize(lights.directions.to(device=normals.device, dtype=dtype))
    b = max(normals.shape[0], dirs.shape[0])
    intensity = lights.ambient.to(device=normals.device, dtype=dtype).unsqueeze(1).expand(b, 1, 3)
    if lights.num_lights > 0:
        cos = small_matmul(normals, dirs.transpose(1, 2)).clamp_min(0)
        intensity = intensity + small_matmul(cos, lights.colors.to(device=normals.device, dtype=dtype))
    return intensity


def _blinn_phong(normals: torch.Tensor, view: torch.Tensor, lights: Lights, specular: float,
                 shininess: float) -> torch.Tensor:
    """``specular * sum_j c_j max(dot(n, h_j), 0)^shininess`` over the lights facing the surface (``dot(n, d_j) >
    0``), with ``h_j = normalize(d_j + v)`` the half vector of light ``j`` and the unit view vector ``v`` toward the
    camera; (B,P,3) for (B,P,3) unit normals and view vectors."""
    dtype = normals.dtype
    b = max(normals.shape[0], lights.directions.shape[0])
    if lights.num_lights == 0:
        return torch.zeros(b, normals.shape[1], 3, dtype=dtype, device=normals.device)
    dirs = _normalize(lights.directions.to(device=normals.device, dtype=dtype))  # (B,K,3)
    half = _normalize(dirs.unsqueeze(1) + view.unsqueeze(2))  # (B,P,K,3)
    cos_h = (normals.unsqueeze(2) * half).sum(-1).clamp_min(0)  # (B,P,K)
    facing = (small_matmul(normals, dirs.transpose(1, 2)) > 0).to(dtype)
    return small_matmul(specular * cos_h.pow(shininess) * facing, lights.colors.to(device=normals.device, dtype=dtype))


def render_surface(
    vertices: torch.Tensor,
    faces: torch.Tensor,
    camera: Camera,
    lights: Lights,
    image_size: int | Sequence[int] = 224,
    *,
    texture: torch.Tensor | None = None,
    uvs: torch.Tensor | None = None,
    uv_faces: torch.Tensor | None = None,
    vertex_colors: torch.Tensor | None = None,
    normals: torch.Tensor | None = None,
    normal_faces: torch.Tensor | None = None,
    shading: str = "smooth",
    specular: float = 0.0,
    shininess: float = 32.0,
    wrap: str = "repeat",
    background: float | Sequence[float] | torch.Tensor = (1.0, 1.0, 1.0),
    fill_back: bool = True,
    antialias: int = 1,
    num_threads: int = 0,
    edge_gradient: float = 1.0,
    visibility_gradient: str = "nmr",
) -> RenderOutput:
    """Render a mesh whose reflectance is a UV texture and/or per-vertex colours, flat or smooth shaded.

    The reflectance at a pixel is ``texture(uv)`` times the interpolated vertex colour (either alone when only one is
    given); the shaded colour is ``clamp(reflectance * (ambient + sum_j c_j max(dot(d_j, n), 0)), 0, 1)`` with ``n``
    the face normal (``flat``) or the interpolated, renormalised vertex normal (``smooth``), turned toward the camera
    on faces seen from behind when ``fill_back``. With ``specular > 0`` (smooth shading) a white Blinn-Phong term is
    added before the clamp: ``specular * sum_j c_j max(dot(n, h_j), 0)^shininess`` over the lights facing the
    surface, ``h_j`` the half vector of light ``j`` and the direction toward the camera from the pixel's surface
    point (perspective) or the viewing direction (orthographic).

    Args:
        vertices: (N,3) or (B,N,3) world positions.
        faces: (M,3) vertex indices.
        camera: a :class:`Camera` of batch 1 or B.
        lights: a :class:`Lights` of batch 1 or B.
        image_size: ``int`` or ``(H, W)``.
        texture: (Ht,Wt,3) or (B,Ht,Wt,3) RGB reflectance image, row 0 at the top.
        uvs: (T,2) texture coordinates, origin at the bottom-left of the image (required with ``texture``).
        uv_faces: (M,3) rows of ``uvs`` at each face corner (default: ``faces``, one UV per vertex).
        vertex_colors: (N,3) or (B,N,3) per-vertex reflectance.
        normals: (Nn,3) vertex normals for ``smooth`` (default: area-weighted normals of ``vertices``, which follow
            the vertices' gradient); with ``normal_faces`` (M,3) their rows at each corner (default: ``faces``).
        normal_faces: see ``normals``.
        shading: ``"flat"`` or ``"smooth"``.
        specular: weight of the Blinn-Phong specular term (0: Lambert only, the default); smooth shading only.
        shininess: Blinn-Phong exponent (>= 1).
        wrap: texel indices outside the image: ``"repeat"`` or ``"clamp"``.
        background: RGB background (not differentiable).
        fill_back: two-sided rendering (False culls back faces).
        antialias: supersampling factor.
        num_threads: native threads (0 = all).
        edge_gradient: weight of NMR's visibility gradient on the screen-space vertices (as :func:`render`); the
            interior gradient (texture coordinates and normals moving with the vertices) is exact whatever it is.
        visibility_gradient: ``"nmr"`` or ``"local"``, as :func:`render`.

    Returns:
        :class:`RenderOutput` (image (B,3,H,W), alpha (B,1,H,W), depth (B,H,W), face_index (B,H,W) int64).

    Raises:
        TypeError: an argument of the wrong type.
        ValueError: bad shapes, NaN/Inf, UVs beyond +-1e6, corner rows out of range, an empty texture, no
            reflectance given, an unknown ``shading`` or ``wrap``, a negative ``specular`` (or one with flat
            shading) or a ``shininess`` below 1; each message names the argument.

    Example:
        >>> from meshadv.render import Camera, Lights
        >>> verts = torch.tensor([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]])
        >>> uvs = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.5, 1.0]])
        >>> out = render_surface(verts, torch.tensor([[0, 1, 2]]), Camera.spherical(4.0), Lights.default(), 32,
        ...                      texture=torch.rand(8, 8, 3), uvs=uvs)
        >>> out.image.shape
        torch.Size([1, 3, 32, 32])
    """
    verts, faces = _check_mesh(vertices, faces)
    require_instance(camera, Camera, "camera")
    require_instance(lights, Lights, "lights")
    if shading not in SHADING_MODES:
        raise ValueError(f"shading must be one of {SHADING_MODES}, got {shading!r}")
    if wrap not in WRAP_MODES:
        raise ValueError(f"wrap must be one of {WRAP_MODES}, got {wrap!r}")
    if texture is None and vertex_colors is None:
        raise ValueError("render_surface needs a reflectance: texture (with uvs) and/or vertex_colors")
    specular = finite_float("specular", specular, low=0.0)
    shininess = finite_float("shininess", shininess, low=1.0)
    if specular > 0 and shading != "smooth":
        raise ValueError(f"specular needs shading='smooth', got shading={shading!r}")
    n, m = verts.shape[1], faces.shape[0]
    sizes = {"vertices": verts.shape[0], "camera": len(camera), "lights": len(lights)}
    if texture is not None:
        texture = _float_array(texture, "texture", ("(Ht,Wt,3)", "(B,Ht,Wt,3)"), (3, 4), 3)
        texture = texture if texture.dim() == 4 else texture.unsqueeze(0)
        sizes["texture"] = texture.shape[0]
        if uvs is None:
            raise ValueError("uvs is required with texture (T,2 texture coordinates)")
        uvs = _float_array(uvs, "uvs", ("(T,2)",), (2,), 2)
        if float(uvs.detach().abs().max()) > MAX_TEXTURE_COORDINATE:
            raise ValueError(f"uvs must lie within +-{MAX_TEXTURE_COORDINATE:g} (texture coordinates, 1 = the whole "
                             f"image), got {float(uvs.detach().abs().max()):g}")
        uv_faces = faces if uv_faces is None else _corners(uv_faces, "uv_faces", m, uvs.shape[0], "uvs")
        if uv_faces is faces and uvs.shape[0] != n:
            raise ValueError(f"uvs must have one row per vertex (N = {n}) without uv_faces, got {uvs.shape[0]}")
    if vertex_colors is not None:
        vertex_colors = _float_array(vertex_colors, "vertex_colors", ("(N,3)", "(B,N,3)"), (2, 3), 3)
        vertex_colors = vertex_colors if vertex_colors.dim() == 3 else vertex_colors.unsqueeze(0)
        if vertex_colors.shape[1] != n:
            raise ValueError(f"vertex_colors must have one row per vertex (N = {n}), got {vertex_colors.shape[1]}")
        sizes["vertex_colors"] = vertex_colors.shape[0]
    if normals is not None:
        normals = _float_array(normals, "normals", ("(Nn,3)", "(B,Nn,3)"), (2, 3), 3)
        normals = normals if normals.dim() == 3 else normals.unsqueeze(0)
        normal_faces = (
            faces if normal_faces is None else _corners(normal_faces, "normal_faces", m, normals.shape[1], "normals")
        )
        if normal_faces is faces and normals.shape[1] != n:
            raise ValueError(
                f"normals must have one row per vertex (N = {n}) without normal_faces, got {normals.shape[1]}"
            )
        sizes["normals"] = normals.shape[0]
    b = _batch_size(sizes)
    height, width = parse_image_size(image_size)
    k = _check_antialias(antialias)
    size = parse_image_size((height * k, width * k), "image_size * antialias")
    edge_weight = finite_float("edge_gradient", edge_gradient, low=0.0)
    radius = sweep_radius(visibility_gradient, k)

    verts_screen = _project_checked(verts, camera, b)
    near = _expand(camera.near.detach().cpu(), b).tolist()
    far = _expand(camera.far.detach().cpu(), b).tolist()
    frags = fragments(verts_screen, faces, size, near, far, not fill_back, camera.orthographic, num_threads)
    face_index = frags.face_index.to(device=verts.device, dtype=torch.long)
    drawn = (face_index >= 0).unsqueeze(-1)
    safe_index = face_index.clamp_min(0).reshape(b, -1)

    weights: list[torch.Tensor] = []  # the perspective-correct weights, computed once when an attribute needs them

    def per_pixel(values: torch.Tensor, corners: torch.Tensor) -> torch.Tensor:
        if not weights:
            weights.append(pixel_weights(verts_screen, faces, frags, num_threads))
        return interpolate(weights[0], values, corners, verts_screen, faces, frags, num_threads)

    reflectance = None
    if texture is not None:
        uv_args = (uvs.unsqueeze(0), verts_screen, uv_faces, faces, frags, wrap, num_threads)
        reflectance = sample_uv_texture(texture, *uv_args)
    if vertex_colors is not None:
        colors = per_pixel(vertex_colors, faces)
        reflectance = colors if reflectance is None else reflectance * colors
    assert reflectance is not None

    # Faces seen from behind have their normals turned toward the camera (flat: the face normal; smooth: the
    # interpolated vertex normal, by its face's side).
    fn = face_normals(verts, faces)
    side = orient_normals(fn, verts, faces, camera) * fn if fill_back else None
    if shading == "flat":
        n_face = _expand(orient_normals(fn, verts, faces, camera) if fill_back else fn, b)
        n_px = torch.gather(n_face, 1, safe_index.unsqueeze(-1).expand(-1, -1, 3))
    else:
        vn = vertex_normals(verts, faces) if normals is None else normals
        n_px = per_pixel(vn, faces if normals is None else normal_faces).reshape(b, -1, 3)
        if side is not None:
            flip = _expand(side.sum(-1, keepdim=True).sign().detach(), b)  # (B,M,1): -1 seen from behind
            n_px = n_px * torch.gather(flip, 1, safe_index.unsqueeze(-1))
        n_px = _normalize(n_px)
    intensity = _lambert(n_px, lights).reshape(b, *size, 3)
    rgb = reflectance * intensity
    if specular > 0:
        if camera.orthographic:
            view = _expand(_normalize(camera.eye() - camera.target()).to(n_px.dtype), b).unsqueeze(1)
            view = view.expand(-1, n_px.shape[1], -1)
        else:
            points = per_pixel(verts, faces).reshape(b, -1, 3)  # the surface point of each pixel (world)
            view = _normalize(_expand(camera.eye().to(points.dtype), b).unsqueeze(1) - points)
        rgb = rgb + _blinn_phong(n_px, view, lights, specular, shininess).reshape(b, *size, 3)
    rgb = rgb.clamp(0.0, 1.0)
    bg = _background(background, rgb.dtype).to(rgb.device)
    rgba = torch.cat([torch.where(drawn, rgb, bg), drawn.to(rgb.dtype)], dim=-1)
    rgba = pixel_visibility(
        _scale_gradient(verts_screen, edge_weight), rgba.contiguous(), faces, frags, num_threads, radius
    )
    out = _downsample(rgba, k, num_threads)
    sub = slice(k // 2, None, k)
    return RenderOutput(
        image=out[:, :3],
        alpha=out[:, 3:4],
        depth=frags.depth[:, sub, sub].contiguous().to(verts.device),
        face_index=face_index[:, sub, sub].contiguous(),
    )
