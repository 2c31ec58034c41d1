"""What Mitsuba renders, as plain numpy values: the camera (:class:`MitsubaCamera`, a pinhole camera in meshadv's
conventions built from spherical or look-at cameras and view records), the lights (:class:`MitsubaLights`), the
meshes (:class:`MeshObject`) and the scene settings (:class:`SceneSpec`, :func:`scene_spec`, :func:`mask_spec`).

Nothing here imports Mitsuba or torch, so a :class:`SceneSpec` can be pickled to the child process that renders it
(:mod:`meshadv.transfer.mitsuba_process`), where :func:`~meshadv.transfer.mitsuba_scene.build_mitsuba_scene` turns
it into a Mitsuba scene. The conventions of the conversion are described in :mod:`meshadv.transfer.mitsuba_scene`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Optional, Union

import numpy as np

from meshadv import _validate
from meshadv.util.spherical import spherical_direction

if TYPE_CHECKING:
    from meshadv.render import Camera, Lights

__all__ = [
    "MeshObject", "MitsubaCamera", "MitsubaLights", "SceneSpec", "as_mesh_object", "as_numpy", "mask_spec",
    "normalize", "scene_spec",
]


def as_numpy(value: Any, dtype: Any = np.float32) -> np.ndarray:
    """Convert a tensor, list or array to a numpy array of ``dtype`` (detached, on the CPU)."""
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    return np.asarray(value, dtype=dtype)


def normalize(v: np.ndarray) -> np.ndarray:
    """``v`` divided by its length; raise ValueError for a zero vector."""
    norm = float(np.linalg.norm(v))
    if norm < 1e-12:
        raise ValueError("cannot normalise a zero vector (camera eye equals target, or up is parallel to the view)")
    return v / norm


@dataclass(frozen=True)
class MitsubaCamera:
    """A pinhole camera in meshadv's conventions, ready for Mitsuba.

    Attributes:
        eye: camera position (3,) in world space.
        target: the point looked at (3,).
        up: up vector (3,), before orthogonalisation (tilt already applied).
        viewing_angle: full horizontal field of view in degrees (NMR ``viewing_angle``).
        near: near clip distance.
        far: far clip distance.
    """

    eye: tuple[float, float, float]
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    viewing_angle: float = 30.0
    near: float = 0.1
    far: float = 100.0

    def __post_init__(self) -> None:
        for name in ("eye", "target", "up"):
            value = getattr(self, name)
            if isinstance(value, (str, bytes)) or len(value) != 3:
                raise ValueError(f"{name} must be 3 numbers, got {value!r}")
            for i, v in enumerate(value):
                _validate.finite_float(f"{name}[{i}]", v)
        for name in ("viewing_angle", "near", "far"):
            _validate.finite_float(name, getattr(self, name))
        if not 0.0 < self.viewing_angle < 180.0:
            raise ValueError(f"viewing_angle must be in (0, 180) degrees, got {self.viewing_angle}")
        if not 0.0 < self.near < self.far:
            raise ValueError(f"need 0 < near < far, got near={self.near}, far={self.far}")

    @classmethod
    def spherical(
        cls,
        distance: float,
        azimuth: float,
        elevation: float,
        tilt: float = 0.0,
        viewing_angle: float = 30.0,
        near: float = 0.1,
        far: float = 100.0,
    ) -> "MitsubaCamera":
        """A camera on a sphere around the origin, exactly as ``meshadv.render.Camera.spherical``.

        Args:
            distance: distance from the origin (> 0).
            azimuth: degrees; ``eye = d * (cos(el) sin(az), sin(el), -cos(el) cos(az))``.
            elevation: degrees.
            tilt: degrees; rotates the up vector about the viewing axis, counter-clockwise in the image.
            viewing_angle: full field of view in degrees.
            near: near clip distance.
            far: far clip distance.

        Raises:
            ValueError: ``distance`` is not positive.
        """
        if not distance > 0:
            raise ValueError(f"distance must be positive, got {distance}")
        eye = distance * np.array(spherical_direction(azimuth, elevation))
        up = _tilted_up(eye, np.zeros(3), np.array([0.0, 1.0, 0.0]), tilt)
        return cls(tuple(eye.tolist()), (0.0, 0.0, 0.0), tuple(up.tolist()), viewing_angle, near, far)

    @classmethod
    def from_camera(cls, camera: Camera, index: int = 0) -> "MitsubaCamera":
        """Build from view ``index`` of a ``meshadv.render.Camera`` (spherical or look-at, tilt applied).

        Raises:
            ValueError: the camera is orthographic or ``index`` is out of range.
        """
        if getattr(camera, "orthographic", False):
            raise ValueError("camera: orthographic cameras are not supported by the Mitsuba conversion")
        if not 0 <= index < len(camera):
            raise ValueError(f"index {index} out of range for a camera batch of {len(camera)}")
        eye = as_numpy(camera.eye()[index], np.float64)
        target = as_numpy(camera.target()[index], np.float64)
        up = as_numpy(camera.rotation()[index, 1], np.float64)
        return cls(
            tuple(eye.tolist()),
            tuple(target.tolist()),
            tuple(up.tolist()),
            float(camera.viewing_angle[index]),
            float(camera.near[index]),
            float(camera.far[index]),
        )

    @classmethod
    def from_record(cls, record: Mapping[str, Any]) -> "MitsubaCamera":
        """Build from a ``ViewSet.to_records()`` record.

        Spherical records have keys distance, azimuth, elevation; look-at records have eye, at, up; both may have
        tilt, viewing_angle, near, far.

        Raises:
            ValueError: required keys are missing, or the record is orthographic.
        """
        if record.get("orthographic", False):
            raise ValueError("record: orthographic cameras are not supported by the Mitsuba conversion")
        if all(k in record for k in ("eye", "at", "up")):
            eye, at = as_numpy(record["eye"], np.float64), as_numpy(record["at"], np.float64)
            up = _tilted_up(eye, at, as_numpy(record["up"], np.float64), float(record.get("tilt", 0.0)))
            return cls(tuple(eye.tolist()), tuple(at.tolist()), tuple(up.tolist()), *_lens(record))
        missing = [k for k in ("distance", "azimuth", "elevation") if k not in record]
        if missing:
            raise ValueError(f"record is missing camera keys {missing} (or eye, at, up)")
        return cls.spherical(float(record["distance"]), float(record["azimuth"]), float(record["elevation"]),
                             float(record.get("tilt", 0.0)), *_lens(record))

    def view_axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """NMR's view axes ``(x, y, z)``: x is image right, y image up, z the viewing direction."""
        eye, target, up = (np.asarray(v, dtype=np.float64) for v in (self.eye, self.target, self.up))
        z = normalize(target - eye)
        x = normalize(np.cross(up, z))
        y = normalize(np.cross(z, x))
        return x, y, z

    def project(self, points_world: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
        """Project world points to pixel coordinates ``(column, row)`` (floats, pixel centres at ``k + 0.5``).

        Args:
            points_world: (P, 3) points.
            image_size: (H, W).

        Returns:
            (P, 2) array of (column, row) positions.
        """
        x, y, z = self.view_axes()
        rel = np.asarray(points_world, dtype=np.float64) - np.asarray(self.eye)
        view = np.stack([rel @ x, rel @ y, rel @ z], axis=-1)
        width = math.tan(math.radians(self.viewing_angle) / 2)
        x_ndc = view[:, 0] / (view[:, 2] * width)
        y_ndc = view[:, 1] / (view[:, 2] * width)
        h, w = image_size
        return np.stack([(x_ndc + 1) * w / 2, (1 - y_ndc) * h / 2], axis=-1)


def _lens(record: Mapping[str, Any]) -> tuple[float, float, float]:
    """``viewing_angle``, ``near`` and ``far`` of a view record (defaults 30 degrees, 0.1, 100)."""
    return float(record.get("viewing_angle", 30.0)), float(record.get("near", 0.1)), float(record.get("far", 100.0))


def _tilted_up(eye: np.ndarray, target: np.ndarray, up: np.ndarray, tilt: float) -> np.ndarray:
    """Rotate ``up`` about the viewing axis by ``tilt`` degrees, counter-clockwise in the image."""
    if tilt == 0.0:
        return up.astype(np.float64)
    z = normalize(target - eye)
    x = normalize(np.cross(up, z))
    y = np.cross(z, x)
    t = math.radians(tilt)
    # Image up (0, 1) rotated counter-clockwise by t is (-sin t, cos t) in image (right, up) coordinates.
    return math.cos(t) * y - math.sin(t) * x


@dataclass(frozen=True)
class MitsubaLights:
    """meshadv's lights: directional lights (direction FROM the surface TOWARD the light) plus ambient.

    Attributes:
        directions: (K, 3) float32, toward the lights (normalised on use).
        colors: (K, 3) float32 light colours (meshadv units: a white face lit head-on by colour c has value c).
        ambient: (3,) float32 ambient colour.
    """

    directions: np.ndarray
    colors: np.ndarray
    ambient: np.ndarray

    def __post_init__(self) -> None:
        d = np.asarray(self.directions, dtype=np.float32).reshape(-1, 3)
        c = np.asarray(self.colors, dtype=np.float32).reshape(-1, 3)
        a = np.asarray(self.ambient, dtype=np.float32).reshape(3)
        if d.shape != c.shape:
            raise ValueError(f"directions {d.shape} and colors {c.shape} must have the same shape (K, 3)")
        object.__setattr__(self, "directions", d)
        object.__setattr__(self, "colors", c)
        object.__setattr__(self, "ambient", a)

    @classmethod
    def from_record(cls, record: Mapping[str, Any]) -> "MitsubaLights":
        """Build from a ``ViewSet.to_records()`` record (keys light_directions, light_colors, ambient).

        Raises:
            ValueError: a required key is missing.
        """
        missing = [k for k in ("light_directions", "light_colors", "ambient") if k not in record]
        if missing:
            raise ValueError(f"record is missing light keys {missing}")
        return cls(
            as_numpy(record["light_directions"]), as_numpy(record["light_colors"]), as_numpy(record["ambient"])
        )

    @classmethod
    def from_lights(cls, lights: Lights, index: int = 0) -> "MitsubaLights":
        """Build from a ``meshadv.render.Lights`` (view ``index`` of a batched one)."""
        d, c, a = (as_numpy(t) for t in (lights.directions, lights.colors, lights.ambient))
        if d.ndim == 3:
            d, c = d[index], c[index]
        if a.ndim == 2:
            a = a[index]
        return cls(d, c, a)


@dataclass(frozen=True)
class MeshObject:
    """A triangle mesh with per-face colours (diffuse reflectance) to place in the scene.

    Attributes:
        vertices: (N, 3) float32 world positions (before ``to_world``).
        faces: (M, 3) uint32 vertex indices.
        face_colors: (M, 3) float32 reflectance in [0, 1].
        to_world: optional (4, 4) object-to-world transform.
        name: identifier used in the Mitsuba scene.
        uvs: optional (N, 2) float32 per-vertex texture coordinates (origin bottom-left, docs/TEXTURES.md), with
            ``texture``: then the reflectance is the bitmap (times ``vertex_colors`` when given), not ``face_colors``.
        texture: optional (Ht, Wt, 3) float32 reflectance image, row 0 at the top.
        normals: optional (N, 3) float32 vertex normals (smooth shading); without them Mitsuba shades flat.
        vertex_colors: optional (N, 3) float32 per-vertex reflectance in [0, 1], interpolated over the faces: then
            the reflectance is these (times the texture when given), not ``face_colors``.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_colors: np.ndarray
    to_world: Optional[np.ndarray] = None
    name: str = "object"
    uvs: Optional[np.ndarray] = None
    texture: Optional[np.ndarray] = None
    normals: Optional[np.ndarray] = None
    vertex_colors: Optional[np.ndarray] = None

    def __post_init__(self) -> None:
        v = as_numpy(self.vertices, np.float32)
        f = as_numpy(self.faces, np.int64)
        c = as_numpy(self.face_colors, np.float32)
        if v.ndim != 2 or v.shape[1] != 3:
            raise ValueError(f"vertices must have shape (N, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise ValueError(f"faces must have shape (M, 3) with M > 0, got {f.shape}")
        if f.min() < 0 or f.max() >= len(v):
            raise ValueError(f"faces index vertices out of range [0, {len(v)})")
        if c.shape != f.shape:
            raise ValueError(f"face_colors must have shape {f.shape}, got {c.shape}")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f.astype(np.uint32))
        object.__setattr__(self, "face_colors", np.clip(c, 0.0, 1.0))
        if self.to_world is not None:
            m = as_numpy(self.to_world, np.float64)
            if m.shape != (4, 4):
                raise ValueError(f"to_world must be a 4x4 matrix, got {m.shape}")
            object.__setattr__(self, "to_world", m)
        if (self.uvs is None) != (self.texture is None):
            raise ValueError("uvs and texture must be given together")
        for name, width in (("uvs", 2), ("normals", 3), ("vertex_colors", 3)):
            value = getattr(self, name)
            if value is not None:
                a = as_numpy(value, np.float32)
                if a.shape != (len(v), width) or not np.isfinite(a).all():
                    raise ValueError(f"{name} must be finite with shape ({len(v)}, {width}), got {a.shape}")
                object.__setattr__(self, name, a)
        if self.texture is not None:
            t = as_numpy(self.texture, np.float32)
            if t.ndim != 3 or t.shape[2] != 3 or 0 in t.shape:
                raise ValueError(f"texture must have shape (Ht, Wt, 3) with Ht, Wt >= 1, got {t.shape}")
            object.__setattr__(self, "texture", np.clip(t, 0.0, 1.0))

    @classmethod
    def from_mesh(cls, mesh: Any, to_world: Optional[np.ndarray] = None, name: str = "object") -> "MeshObject":
        """Build from a ``meshadv.mesh.Mesh`` (or anything with vertices, faces, face_colors); a
        ``meshadv.mesh.SurfaceMesh`` with a texture or vertex colours as :meth:`from_surface` under its own shading
        (what meshadv renders of it)."""
        if getattr(mesh, "texture", None) is not None or getattr(mesh, "vertex_colors", None) is not None:
            return cls.from_surface(mesh, mesh.shading, to_world, name)
        return cls(mesh.vertices, mesh.faces, mesh.face_colors, to_world, name)

    @classmethod
    def from_surface(
        cls, surface: Any, shading: str = "flat", to_world: Optional[np.ndarray] = None, name: str = "object"
    ) -> "MeshObject":
        """Build from a ``meshadv.mesh.SurfaceMesh``: vertices split where UVs (or normals) differ, as a Mitsuba
        mesh needs one of each per vertex; its texture, vertex colours or both (drawn multiplied, as meshadv draws
        them); ``shading="smooth"`` gives the normals meshadv shades with (the file's, or area-weighted ones of the
        vertices)."""
        import torch

        from meshadv.render import vertex_normals

        faces = surface.mesh.faces.cpu().numpy()
        keys = [faces]
        normals = normal_faces = None
        if shading == "smooth":
            if surface.normals is not None:
                normals, normal_faces = surface.normals.cpu().numpy(), surface.normal_faces.cpu().numpy()
            else:
                with torch.no_grad():
                    normals = vertex_normals(surface.mesh.vertices, surface.mesh.faces)[0].numpy()
                normal_faces = faces
            keys.append(normal_faces)
        if surface.uvs is not None:
            keys.append(surface.uv_faces.cpu().numpy())
        corners = np.stack([k.reshape(-1) for k in keys], axis=1)
        unique, inverse = np.unique(corners, axis=0, return_inverse=True)
        new_faces = inverse.reshape(-1, 3)
        verts = surface.mesh.vertices.detach().cpu().numpy()[unique[:, 0]]
        return cls(
            verts,
            new_faces,
            surface.mesh.face_colors.detach().cpu().numpy(),
            to_world,
            name,
            uvs=None if surface.uvs is None else surface.uvs.detach().cpu().numpy()[unique[:, -1]],
            texture=None if surface.texture is None else surface.texture.detach().cpu().numpy(),
            normals=None if normals is None else normals[unique[:, 1]],
            vertex_colors=(None if surface.vertex_colors is None
                           else surface.vertex_colors.detach().cpu().numpy()[unique[:, 0]]),
        )


@dataclass(frozen=True)
class SceneSpec:
    """Everything needed to render one image with Mitsuba; picklable.

    Attributes:
        objects: meshes to render (the adversarial object, possibly more).
        camera: the camera.
        lights: meshadv lights converted to emitters, or None to use only the base scene's / environment's lights.
        image_size: (H, W).
        spp: samples per pixel.
        max_depth: path tracer depth; 2 = direct light only (no interreflection), larger adds interreflection.
        background: RGB composited where no surface is hit (as meshadv's background), or None to show the
            environment / base scene.
        base_scene: optional Mitsuba XML scene file to merge the objects into (its sensor and integrator are replaced).
        base_exclude: substrings of shape ``filename`` / ``id`` values to drop from the base scene (e.g. ``"bunny"``).
        base_emitters: keep the base scene's emitters.
        environment: optional (He, We, 3) float32 lat-long radiance map (Mitsuba ``envmap``, +Y up).
        environment_scale: multiplier of ``environment``.
        ground: optional (height, (r, g, b)) of a large diffuse ground plane ``y = height``.
        mask: render a coverage mask (alpha) of the objects only, with one sample at each pixel centre
            (meshadv's coverage rule) unless ``spp > 1``.
        seed: sampler seed.
    """

    objects: tuple[MeshObject, ...]
    camera: MitsubaCamera
    lights: Optional[MitsubaLights] = None
    image_size: tuple[int, int] = (224, 224)
    spp: int = 64
    max_depth: int = 8
    background: Optional[tuple[float, float, float]] = (1.0, 1.0, 1.0)
    base_scene: Optional[str] = None
    base_exclude: tuple[str, ...] = ()
    base_emitters: bool = True
    environment: Optional[np.ndarray] = None
    environment_scale: float = 1.0
    ground: Optional[tuple[float, tuple[float, float, float]]] = None
    mask: bool = False
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "image_size", _square_size(self.image_size))
        object.__setattr__(self, "objects", tuple(self.objects))
        for i, obj in enumerate(self.objects):
            if not isinstance(obj, MeshObject):
                raise TypeError(f"objects[{i}] must be a MeshObject, got {type(obj).__name__}")
        if not isinstance(self.camera, MitsubaCamera):
            raise TypeError(f"camera must be a MitsubaCamera, got {type(self.camera).__name__}")
        if self.lights is not None and not isinstance(self.lights, MitsubaLights):
            raise TypeError(f"lights must be a MitsubaLights or None, got {type(self.lights).__name__}")
        _validate.positive_int("spp", self.spp)
        _validate.integer("max_depth", self.max_depth)
        if self.max_depth < 1 and self.max_depth != -1:
            raise ValueError(f"max_depth must be >= 1 (or -1 for unlimited), got {self.max_depth}")
        _validate.seed("seed", self.seed)
        _validate.finite_float("environment_scale", self.environment_scale, low=0.0)
        if self.base_scene is not None and not Path(self.base_scene).is_file():
            raise FileNotFoundError(f"base_scene {self.base_scene} does not exist")
        if self.environment is not None:
            env = as_numpy(self.environment, np.float32)
            if env.ndim != 3 or env.shape[2] != 3:
                raise ValueError(f"environment must be (H, W, 3), got {env.shape}")
            object.__setattr__(self, "environment", env)


def _square_size(image_size: Any) -> tuple[int, int]:
    """``(S, S)`` from an int ``S`` or an ``(H, W)`` pair of ints with ``H == W`` (Mitsuba's images are square).

    Raises:
        TypeError: ``image_size`` is not an int or a pair of ints.
        ValueError: a side is not positive, or ``H != W``.
    """
    if isinstance(image_size, (tuple, list)) and len(image_size) == 2:
        size = (_validate.integer("image_size[0]", image_size[0]), _validate.integer("image_size[1]", image_size[1]))
    elif isinstance(image_size, (tuple, list)):
        raise ValueError(f"image_size must be an int or (H, W), got {image_size!r}")
    else:
        side = _validate.integer("image_size", image_size)
        size = (side, side)
    if min(size) <= 0 or size[0] != size[1]:
        raise ValueError(f"image_size must be positive and square (H == W), got {size}")
    return size


def scene_spec(
    mesh: Any,
    camera: Union[MitsubaCamera, Mapping[str, Any]],
    lights: Union[MitsubaLights, Mapping[str, Any], None] = None,
    **kwargs: Any,
) -> SceneSpec:
    """Convenience constructor from a meshadv ``Mesh`` and a view record (or converted camera/lights).

    Args:
        mesh: a ``meshadv.mesh.Mesh`` or a :class:`MeshObject`.
        camera: a :class:`MitsubaCamera` or a ``ViewSet.to_records()`` record (lights are read from it too when
            ``lights`` is None and the record has light keys).
        lights: :class:`MitsubaLights`, a record, or None.
        **kwargs: other :class:`SceneSpec` fields.

    Returns:
        The scene spec.

    Example:
        >>> spec = scene_spec(builtin_mesh("sphere"), views.to_records()[0], image_size=64)  # doctest: +SKIP
    """
    obj = as_mesh_object(mesh)
    if isinstance(camera, Mapping):
        record = camera
        camera = MitsubaCamera.from_record(record)
        if lights is None and "light_directions" in record:
            lights = record
    if isinstance(lights, Mapping):
        lights = MitsubaLights.from_record(lights)
    return SceneSpec(objects=(obj,), camera=camera, lights=lights, **kwargs)


def mask_spec(mesh: Any, camera: MitsubaCamera, image_size: Any = 224, *, spp: int = 1) -> SceneSpec:
    """The scene of the coverage mask of ``mesh`` (a ``meshadv.mesh.Mesh`` or :class:`MeshObject`) seen by
    ``camera``: no lights, no background; with ``spp == 1`` one ray through each pixel centre, meshadv's coverage
    rule, so the mask is binary."""
    return SceneSpec(objects=(as_mesh_object(mesh),), camera=camera, image_size=image_size, spp=spp, mask=True,
                     background=None)


def as_mesh_object(mesh: Any) -> MeshObject:
    """``mesh`` itself when it is a :class:`MeshObject`, else :meth:`MeshObject.from_mesh` of it (a
    ``meshadv.mesh.Mesh`` or anything with vertices, faces and face_colors)."""
    return mesh if isinstance(mesh, MeshObject) else MeshObject.from_mesh(mesh)
