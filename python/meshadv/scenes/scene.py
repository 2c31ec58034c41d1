"""A scene is a list of meshes with their own transforms and colours, rendered together in one call.

All objects are concatenated into one triangle soup so the depth test resolves occlusion between them; the
face-index map is mapped back to (object, face) pairs. Only the objects whose parameters the caller passes as
overrides carry gradients; every other object is constant.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping, Optional, Sequence, Tuple

import torch

from meshadv.mesh import Mesh
from meshadv.render import Camera, Lights, render


def _as_transform(matrix: Optional[torch.Tensor], name: str) -> torch.Tensor:
    if matrix is None:
        return torch.eye(4, dtype=torch.float32)
    matrix = torch.as_tensor(matrix, dtype=torch.float32)
    if matrix.shape != (4, 4):
        raise ValueError(f"transform of scene object {name!r} must be a 4x4 matrix, got shape {tuple(matrix.shape)}")
    if not torch.isfinite(matrix).all():
        raise ValueError(f"transform of scene object {name!r} has non-finite entries")
    return matrix


@dataclass(frozen=True)
class SceneObject:
    """One mesh of a scene.

    Attributes:
        name: unique name of the object in its scene (e.g. ``"bunny"``).
        mesh: the mesh in its own (model) coordinates.
        transform: 4x4 model-to-world matrix (identity when the mesh is already in world coordinates).
    """

    name: str
    mesh: Mesh
    transform: torch.Tensor = field(default_factory=lambda: torch.eye(4))

    def world_vertices(self, vertices: Optional[torch.Tensor] = None) -> torch.Tensor:
        """Return ``vertices`` (default: the mesh's own) mapped to world coordinates, shape (N, 3)."""
        verts = self.mesh.vertices if vertices is None else vertices
        matrix = _as_transform(self.transform, self.name).to(verts.dtype)
        return verts @ matrix[:3, :3].T + matrix[:3, 3]


@dataclass(frozen=True)
class SceneCamera:
    """An explicit pinhole camera for a scene: eye, look-at point, up vector, horizontal field of view and image size.

    meshadv's rasterizer maps ``[-1, 1]`` to both image axes (NMR convention), so a ``width x height`` image with a
    horizontal field of view is rendered as a ``width x width`` square with that field of view and the central
    ``height`` rows are kept: the same pinhole picture with square pixels (Mitsuba's ``fov_axis="x"``).
    """

    eye: Tuple[float, float, float]
    at: Tuple[float, float, float]
    up: Tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov: float = 50.0
    width: int = 480
    height: int = 360
    near: float = 0.05
    far: float = 100.0

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got width={self.width}, height={self.height}")
        if self.height > self.width or (self.width - self.height) % 2:
            raise ValueError(
                f"height ({self.height}) must not exceed width ({self.width}) and differ from it by an even number"
            )
        if not 0.0 < self.fov < 180.0:
            raise ValueError(f"fov must be in (0, 180) degrees, got {self.fov}")

    def to_camera(self) -> Camera:
        """The square meshadv ``Camera`` (batch 1) that this scene camera crops from."""
        return Camera.look_at(
            eye=torch.tensor([self.eye], dtype=torch.float32),
            at=torch.tensor([self.at], dtype=torch.float32),
            up=torch.tensor([self.up], dtype=torch.float32),
            viewing_angle=self.fov,
            near=self.near,
            far=self.far,
        )

    def image_axes(self) -> Tuple[torch.Tensor, torch.Tensor]:
        """World directions (float64 unit (3,) vectors) of the image's right and up as meshadv renders this camera.

        meshadv's view frame is NMR's: the image's right is ``normalize(cross(up, at - eye))``, which is the mirror of
        a physical camera (for an eye on +Z looking at the origin, world +X appears on the image's *left*).

        Example:
            >>> right, up = SceneCamera(eye=(0.0, 0.0, 4.0), at=(0.0, 0.0, 0.0)).image_axes()
            >>> right.tolist(), up.tolist()
            ([-1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        """
        forward = torch.tensor(self.at, dtype=torch.float64) - torch.tensor(self.eye, dtype=torch.float64)
        forward = forward / forward.norm()
        right = torch.cross(torch.tensor(self.up, dtype=torch.float64), forward, dim=0)
        right = right / right.norm()
        return right, torch.cross(forward, right, dim=0)

    def resized(self, width: int) -> "SceneCamera":
        """The same camera rendering ``width`` pixels wide, the height scaled to keep the aspect ratio (rounded so
        that ``width - height`` stays even)."""
        if width <= 0:
            raise ValueError(f"width must be positive, got {width}")
        height = int(round(self.height * width / self.width))
        height -= (width - height) % 2
        return replace(self, width=width, height=max(height, 2 - width % 2))

    def crop_rows(self) -> slice:
        """Rows of the square render that form the ``height``-row image."""
        top = (self.width - self.height) // 2
        return slice(top, top + self.height)


@dataclass(frozen=True)
class SceneRender:
    """The result of rendering a scene.

    Attributes:
        image: (1, 3, H, W) colours in [0, 1].
        alpha: (1, 1, H, W) coverage of any object.
        depth: (1, H, W) view-space depth (``far`` on background).
        object_index: (1, H, W) int64 index into ``Scene.objects`` of the visible object, -1 on background.
        face_index: (1, H, W) int64 face index within the visible object, -1 on background.
    """

    image: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    object_index: torch.Tensor
    face_index: torch.Tensor

    def object_mask(self, object_index: int) -> torch.Tensor:
        """(1, 1, H, W) float mask of the pixels where object ``object_index`` is visible."""
        return (self.object_index == object_index).unsqueeze(1).float()


@dataclass(frozen=True)
class Scene:
    """Several meshes rendered together.

    Attributes:
        objects: the scene's objects, names unique.
    """

    objects: Tuple[SceneObject, ...]

    def __post_init__(self) -> None:
        names = [obj.name for obj in self.objects]
        if not names:
            raise ValueError("objects must contain at least one SceneObject")
        if len(set(names)) != len(names):
            raise ValueError(f"object names must be unique, got {names}")

    def index_of(self, name: str) -> int:
        """Index of the object called ``name``; ``ValueError`` listing the names when absent."""
        for i, obj in enumerate(self.objects):
            if obj.name == name:
                return i
        raise ValueError(f"no object named {name!r} in the scene; objects: {[o.name for o in self.objects]}")

    def __getitem__(self, name: str) -> SceneObject:
        return self.objects[self.index_of(name)]

    def face_offsets(self) -> torch.Tensor:
        """(len(objects) + 1,) int64 cumulative face counts: object k owns faces ``[off[k], off[k+1])``."""
        counts = torch.tensor([0] + [obj.mesh.faces.shape[0] for obj in self.objects], dtype=torch.int64)
        return torch.cumsum(counts, 0)

    def assemble(
        self,
        vertices: Optional[Mapping[str, torch.Tensor]] = None,
        face_colors: Optional[Mapping[str, torch.Tensor]] = None,
    ) -> Tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Concatenate every object into one mesh in world coordinates.

        Args:
            vertices: optional per-object replacement model-space vertices (N_k, 3), e.g. a perturbed object.
            face_colors: optional per-object replacement face colours (M_k, 3).

        Returns:
            (world vertices (N, 3), faces (M, 3) int64, face colours (M, 3)); gradients flow only into overrides
            (every other object's tensors are detached, so they stay fixed even if they require grad).
        """
        vertices = dict(vertices or {})
        face_colors = dict(face_colors or {})
        unknown = (set(vertices) | set(face_colors)) - {o.name for o in self.objects}
        if unknown:
            raise ValueError(f"overrides name objects not in the scene: {sorted(unknown)}")
        all_verts, all_faces, all_colors = [], [], []
        vertex_offset = 0
        for obj in self.objects:
            verts = vertices[obj.name] if obj.name in vertices else obj.mesh.vertices.detach()
            if verts.shape != obj.mesh.vertices.shape:
                raise ValueError(
                    f"vertices override for {obj.name!r} must have shape {tuple(obj.mesh.vertices.shape)}, "
                    f"got {tuple(verts.shape)}"
                )
            colors = face_colors[obj.name] if obj.name in face_colors else obj.mesh.face_colors.detach()
            if colors.shape != obj.mesh.face_colors.shape:
                raise ValueError(
                    f"face_colors override for {obj.name!r} must have shape {tuple(obj.mesh.face_colors.shape)}, "
                    f"got {tuple(colors.shape)}"
                )
            all_verts.append(obj.world_vertices(verts.float()))
            all_faces.append(obj.mesh.faces.long() + vertex_offset)
            all_colors.append(colors.float())
            vertex_offset += verts.shape[0]
        return torch.cat(all_verts), torch.cat(all_faces), torch.cat(all_colors)

    def render(
        self,
        camera: SceneCamera,
        lights: Lights,
        *,
        vertices: Optional[Mapping[str, torch.Tensor]] = None,
        face_colors: Optional[Mapping[str, torch.Tensor]] = None,
        background: Sequence[float] = (0.0, 0.0, 0.0),
    ) -> SceneRender:
        """Render every object in one rasterizer call (correct occlusion between objects).

        Args:
            camera: the scene camera.
            lights: lights of batch 1.
            vertices: per-object vertex overrides (model space), see ``assemble``.
            face_colors: per-object face-colour overrides, see ``assemble``.
            background: RGB background colour.

        Returns:
            A ``SceneRender`` of size ``camera.height x camera.width``.
        """
        verts, faces, colors = self.assemble(vertices, face_colors)
        out = render(
            verts,
            faces,
            colors,
            camera.to_camera(),
            lights,
            image_size=camera.width,
            background=background,
        )
        rows = camera.crop_rows()
        face_index = out.face_index[:, rows, :]
        offsets = self.face_offsets()
        visible = face_index >= 0
        object_index = torch.bucketize(face_index.clamp(min=0), offsets[1:], right=True)
        object_index = torch.where(visible, object_index, torch.full_like(object_index, -1))
        local_face = torch.where(visible, face_index - offsets[object_index.clamp(min=0)], face_index)
        return SceneRender(
            image=out.image[:, :, rows, :],
            alpha=out.alpha[:, :, rows, :],
            depth=out.depth[:, rows, :],
            object_index=object_index,
            face_index=local_face,
        )
