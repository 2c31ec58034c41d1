"""The render setup of an attack: everything about how the attacked mesh becomes an image except the views.

A :class:`RenderSetup` holds the image size, the background (an RGB colour or a photo composited with the render's
alpha), the supersampling factor and the *static* objects of a scene (a desk, a chair, the floor) that are rendered
together with the attacked mesh in one rasterizer call, so occlusion between them is exact. The attacked mesh may
have a model-to-world transform (a scene object), and a scene camera that renders a square and keeps its central
rows (:class:`~meshadv.scenes.scene.SceneCamera`) is expressed by ``crop_rows``.

It is data, not a hyper-parameter: the same attack runs on a white background, over a photo or inside the indoor
scene by changing the setup it is called with (``attack(mesh, views, victim, criterion, setup=...)``).

Example:
    >>> setup = RenderSetup(image_size=64, background=(1.0, 1.0, 1.0), antialias=2)
    >>> setup.output_size
    (64, 64)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Dict, Optional, Sequence, Tuple, Union

import torch
from torch import Tensor

from meshadv.render.surface_reflectance import SurfaceReflectance

__all__ = ["RenderSetup", "StaticObject", "render_views", "SETUP_OPTIONS", "split_setup_options", "static_objects"]

#: Option names (in configs and ``attack_kwargs``) that describe the render setup, not the attack.
SETUP_OPTIONS = ("image_size", "background", "antialias")

ImageSize = Union[int, Tuple[int, int]]
Background = Union[Tuple[float, float, float], Tensor]


def _parse_image_size(image_size: Any) -> Tuple[int, int]:
    if isinstance(image_size, bool):
        raise TypeError(f"image_size must be an int or (H, W), got {image_size!r}")
    if isinstance(image_size, int):
        size: Tuple[int, ...] = (image_size, image_size)
    else:
        try:
            size = tuple(int(s) for s in image_size)
        except TypeError:
            raise TypeError(f"image_size must be an int or (H, W), got {image_size!r}") from None
    if len(size) != 2 or min(size) < 8:
        raise ValueError(f"image_size must be an int or (H, W) of at least 8 pixels, got {image_size!r}")
    return size[0], size[1]


@dataclass(frozen=True)
class StaticObject:
    """A fixed object of a scene, already in world coordinates (no gradient reaches it).

    Attributes:
        name: the object's name (for records).
        vertices: float ``(N, 3)`` world coordinates.
        faces: int64 ``(M, 3)``.
        face_colors: float ``(M, 3)`` in ``[0, 1]``.
    """

    name: str
    vertices: Tensor
    faces: Tensor
    face_colors: Tensor


@dataclass(frozen=True)
class RenderSetup:
    """How the attacked mesh is rendered for the victim (the views come separately).

    Attributes:
        image_size: ``int`` or ``(H, W)`` of the rendered square / rectangle (the victim resizes internally).
        background: RGB colour, or a ``(3, H_out, W_out)`` photo composited behind everything with the alpha.
        antialias: supersampling factor.
        static: fixed world-space objects rendered with the attacked mesh (occlusion between them is exact).
        transform: optional ``(4, 4)`` model-to-world matrix of the attacked mesh.
        crop_rows: optional ``(top, bottom)``: keep these rows of the render (a scene camera's central band).

    Raises:
        ValueError / TypeError: a field of the wrong value or type, naming it.
    """

    image_size: ImageSize = 224
    background: Background = (1.0, 1.0, 1.0)
    antialias: int = 1
    static: Tuple[StaticObject, ...] = field(default_factory=tuple)
    transform: Optional[Tensor] = None
    crop_rows: Optional[Tuple[int, int]] = None

    def __post_init__(self) -> None:
        from meshadv.render.rasterize import parse_image_size
        from meshadv.render.renderer import _check_antialias

        size = parse_image_size(_parse_image_size(self.image_size))
        object.__setattr__(self, "image_size", size)
        _check_antialias(self.antialias)
        parse_image_size((size[0] * self.antialias, size[1] * self.antialias), "image_size * antialias")
        if self.crop_rows is not None:
            top, bottom = (int(r) for r in self.crop_rows)
            if not 0 <= top < bottom <= size[0]:
                raise ValueError(f"crop_rows must be (top, bottom) within [0, {size[0]}], got {self.crop_rows!r}")
            object.__setattr__(self, "crop_rows", (top, bottom))
        object.__setattr__(self, "background", self._checked_background())
        if self.transform is not None:
            matrix = torch.as_tensor(self.transform, dtype=torch.float32)
            if matrix.shape != (4, 4) or not bool(torch.isfinite(matrix).all()):
                raise ValueError(f"transform must be a finite (4, 4) matrix, got shape {tuple(matrix.shape)}")
            object.__setattr__(self, "transform", matrix)
        object.__setattr__(self, "static", tuple(self.static))
        for obj in self.static:
            if not isinstance(obj, StaticObject):
                raise TypeError(f"static must hold StaticObject items, got {type(obj).__name__}")

    def _checked_background(self) -> Background:
        """The background as 3 finite floats or a finite ``(3, H_out, W_out)`` image."""
        bg = self.background
        if isinstance(bg, Tensor) and bg.dim() == 3:
            if bg.shape[0] != 3 or tuple(bg.shape[1:]) != self.output_size:
                raise ValueError(f"background image must have shape (3, {self.output_size[0]}, "
                                 f"{self.output_size[1]}), got {tuple(bg.shape)}")
            if not bg.is_floating_point():
                raise TypeError(f"background image must be a floating tensor, got {bg.dtype}")
            if not bool(torch.isfinite(bg.detach()).all()):
                raise ValueError("background image contains NaN or Inf")
            return bg
        if isinstance(bg, (str, bytes)) or not (isinstance(bg, Tensor) or hasattr(bg, "__iter__")):
            raise TypeError(f"background must be 3 numbers (RGB) or a (3, H, W) image, got {bg!r}")
        try:
            values = tuple(float(c) for c in bg)
        except (TypeError, ValueError):
            raise TypeError(f"background must be 3 numbers (RGB) or a (3, H, W) image, got {bg!r}") from None
        if len(values) != 3:
            raise ValueError(f"background must be 3 numbers (RGB) or a (3, H, W) image, got {bg!r}")
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"background must be finite, got {values!r}")
        return values

    @property
    def output_size(self) -> Tuple[int, int]:
        """``(H, W)`` of the images handed to the victim (after ``crop_rows``)."""
        h, w = self.image_size  # type: ignore[misc]
        if self.crop_rows is not None:
            h = self.crop_rows[1] - self.crop_rows[0]
        return h, w

    @property
    def has_photo(self) -> bool:
        """True when the background is an image."""
        return isinstance(self.background, Tensor)

    def config(self) -> Dict[str, Any]:
        """A JSON-able description (the photo is summarised as ``"image"``)."""
        return {
            "image_size": list(self.image_size),  # type: ignore[arg-type]
            "background": "image" if self.has_photo else list(self.background),  # type: ignore[arg-type]
            "antialias": self.antialias,
            "static": [obj.name for obj in self.static],
            "transform": None if self.transform is None else self.transform.tolist(),
            "crop_rows": None if self.crop_rows is None else list(self.crop_rows),
        }

    def render(self, vertices: Tensor, faces: Tensor, face_colors: Union[Tensor, SurfaceReflectance], views: Any,
               edge_gradient: float = 1.0, num_threads: int = 0,
               visibility_gradient: str = "nmr") -> Tuple[Tensor, Tensor]:
        """Render ``K`` versions of the attacked mesh (one topology) from each of ``V`` views in one batched call.

        The batch is mesh-major: image ``k * V + v`` is mesh ``k`` seen from view ``v``. Static objects are drawn in
        the same call; a photo background is composited as ``image + (1 - alpha) * photo`` over a black render.

        Args:
            vertices: ``(K, N, 3)`` model-space vertices of the attacked mesh.
            faces: int ``(M, 3)``.
            face_colors: ``(M, 3)`` shared, or ``(K, M, 3)``; or a
                :class:`~meshadv.render.surface_reflectance.SurfaceReflectance` of ``K`` textures (drawn by
                :func:`~meshadv.render.render_surface`; no static objects then).
            views: a ``ViewSet`` of ``V`` views.
            edge_gradient: weight of NMR's rasterization gradient on the vertices (:func:`meshadv.render.render`;
                the update rule's choice, not the setup's: 1 = NMR's definition).
            num_threads: the native renderer's threads (forward and backward): 0 = rayon's global pool; a count runs
                on a pool of the calling thread's own, which threads rendering at the same time do not share (an
                attack's step workers). The images do not depend on it.
            visibility_gradient: the rasterization gradient of the vertices, ``"nmr"`` or ``"local"``
                (:func:`meshadv.render.render`; the update rule's choice). The images do not depend on it.

        Returns:
            ``(images (K*V, 3, H, W), alpha (K*V, 1, H, W))`` with ``(H, W) = output_size``.

        Raises:
            TypeError: ``views`` is not a ViewSet (the other arguments are checked by :func:`meshadv.render.render`).
            ValueError: ``vertices`` is not ``(K, N, 3)`` (one mesh is ``vertices[None]``).
        """
        from meshadv.render import ViewSet
        from meshadv.render.renderer import _render_image_alpha

        views = ViewSet.require(views)
        if not isinstance(vertices, Tensor) or vertices.dim() != 3 or vertices.shape[-1] != 3:
            shape = tuple(vertices.shape) if isinstance(vertices, Tensor) else type(vertices).__name__
            raise ValueError(f"vertices must be a (K, N, 3) batch of meshes (one mesh: vertices[None]), got {shape}")
        k, v = vertices.shape[0], len(views)
        batched = ViewSet.cat([views] * k) if k > 1 else views
        verts = vertices.repeat_interleave(v, dim=0) if v > 1 else vertices
        colors = face_colors
        if isinstance(face_colors, SurfaceReflectance):
            colors = face_colors.repeat_views(v, k)
        elif face_colors.dim() == 3:
            colors = face_colors.repeat_interleave(v, dim=0) if v > 1 else face_colors
        if self.transform is not None:
            matrix = self.transform.to(verts.dtype)
            verts = verts @ matrix[:3, :3].T + matrix[:3, 3]
        faces = faces.long()
        bg = (0.0, 0.0, 0.0) if self.has_photo else self.background
        if isinstance(colors, SurfaceReflectance):
            image, alpha = self._render_surface(verts, faces, colors, batched, bg, edge_gradient, num_threads,
                                                visibility_gradient)
        else:
            if self.static:
                verts, faces, colors = self._with_static(verts, faces, colors)
            # The image alone: an attack step never reads the depth or face-index maps.
            image, alpha, _, _, _ = _render_image_alpha(
                verts, faces, colors, batched.camera, batched.lights, self.image_size, bg, fill_back=True,
                antialias=self.antialias, num_threads=num_threads, edge_gradient=edge_gradient,
                visibility_gradient=visibility_gradient)
        if self.crop_rows is not None:
            rows = slice(*self.crop_rows)
            image, alpha = image[:, :, rows, :], alpha[:, :, rows, :]
        if self.has_photo:
            image = image + (1.0 - alpha) * self.background.to(image.dtype).unsqueeze(0)  # type: ignore[union-attr]
        return image, alpha

    def _render_surface(self, verts: Tensor, faces: Tensor, reflectance: SurfaceReflectance, views: Any,
                        background: Any, edge_gradient: float, num_threads: int,
                        visibility_gradient: str) -> Tuple[Tensor, Tensor]:
        """``(image, alpha)`` of a textured batch through :func:`~meshadv.render.render_surface`.

        Raises:
            ValueError: the setup has static scene objects (they carry per-face colours, not a texture).
        """
        from meshadv.render.surface import render_surface

        if self.static:
            raise ValueError("a textured mesh is rendered alone: this RenderSetup has static scene objects")
        out = render_surface(verts, faces, views.camera, views.lights, self.image_size,
                             texture=reflectance.texture, uvs=reflectance.uvs, uv_faces=reflectance.uv_faces,
                             vertex_colors=reflectance.vertex_colors, shading=reflectance.shading,
                             wrap=reflectance.wrap, background=background, antialias=self.antialias,
                             num_threads=num_threads, edge_gradient=edge_gradient,
                             visibility_gradient=visibility_gradient)
        return out.image, out.alpha

    def _with_static(self, verts: Tensor, faces: Tensor, colors: Tensor) -> Tuple[Tensor, Tensor, Tensor]:
        """Append the static objects to a batch of attacked meshes (the attacked mesh's faces come first)."""
        b = verts.shape[0]
        all_verts, all_faces, all_colors = [verts], [faces], []
        offset = verts.shape[1]
        for obj in self.static:
            all_verts.append(obj.vertices.detach().to(verts.dtype).unsqueeze(0).expand(b, -1, -1))
            all_faces.append(obj.faces.long() + offset)
            offset += obj.vertices.shape[0]
        base = colors if colors.dim() == 3 else colors.unsqueeze(0).expand(b, -1, -1)
        all_colors.append(base)
        for obj in self.static:
            all_colors.append(obj.face_colors.detach().to(base.dtype).unsqueeze(0).expand(b, -1, -1))
        return torch.cat(all_verts, dim=1), torch.cat(all_faces), torch.cat(all_colors, dim=1)


def render_views(vertices: Tensor, faces: Tensor, face_colors: Tensor, views: Any,
                 setup: Optional[RenderSetup] = None) -> Tuple[Tensor, Tensor]:
    """``setup.render(vertices, faces, face_colors, views)`` (default setup: 224 px, white, no supersampling);
    ``vertices`` is a ``(K, N, 3)`` batch (one mesh: ``vertices[None]``)."""
    return (setup or RenderSetup()).render(vertices, faces, face_colors, views)


def split_setup_options(options: Dict[str, Any]) -> Tuple[Dict[str, Any], Dict[str, Any]]:
    """Split a mixed option dict (a sweep's ``[attack]`` table, ``attack_kwargs``) into the render setup's options
    (:data:`SETUP_OPTIONS`) and the attack's hyper-parameters."""
    setup = {k: v for k, v in options.items() if k in SETUP_OPTIONS}
    return setup, {k: v for k, v in options.items() if k not in SETUP_OPTIONS}


def static_objects(objects: Sequence[Any]) -> Tuple[StaticObject, ...]:
    """Static objects from scene objects (``name``, ``mesh``, ``world_vertices()``)."""
    return tuple(StaticObject(o.name, o.world_vertices().detach(), o.mesh.faces.long(), o.mesh.face_colors.detach())
                 for o in objects)
