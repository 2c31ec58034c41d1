"""Convert meshadv meshes, cameras and lights into a Mitsuba 3 scene.

Everything here except :func:`build_mitsuba_scene` is plain numpy, so a :class:`SceneSpec` can be pickled to the child
process that actually renders (see :mod:`meshadv.transfer.render`).

Conventions (see docs/ARCHITECTURE.md):

* Camera: meshadv's camera (NMR conventions) becomes a Mitsuba ``perspective`` sensor with ``fov = viewing_angle``
  on the x axis and ``to_world = look_at(eye, target, up)``; the rendered image is then flipped left-right, because
  NMR's view frame is left-handed (world +X of a camera on the -Z axis appears on the image's *right*: a mirror of a
  physical camera such as Mitsuba's, which refuses a mirroring ``to_world``). Pixel centres agree with meshadv's.
  Images must be square: NMR maps [-1, 1] NDC to both axes of a non-square image (non-square pixels), which a
  Mitsuba sensor cannot do.
* Lights: meshadv's Lambert term ``reflectance * colour * max(n.l, 0)`` becomes a ``directional`` emitter with
  ``direction = -l`` and ``irradiance = pi * colour`` (a diffuse BSDF reflects ``rho * E * cos / pi``); the ambient
  term becomes a ``constant`` environment emitter with ``radiance = ambient`` (an unoccluded diffuse surface under
  a constant environment ``a`` reflects exactly ``rho * a``). Where the environment is occluded (concave shapes) the
  path tracer produces ambient occlusion that meshadv does not have.
* Material: two-sided diffuse with per-face reflectance (a ``face_color`` mesh attribute read by a ``mesh_attribute``
  texture), flat shading (no vertex normals), as meshadv's two-sided per-face Lambert shading.
* Images are linear RGB clamped to [0, 1] (no tone mapping or gamma), as meshadv's.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence, Union

import numpy as np

from meshadv.util.spherical import spherical_direction

ArrayLike = Union[np.ndarray, Sequence[float], Any]


def _as_numpy(value: Any, dtype: Any = np.float32) -> np.ndarray:
    """Convert a tensor, list or array to a numpy array of ``dtype`` (detached, on the CPU)."""
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    return np.asarray(value, dtype=dtype)


def _normalize(v: np.ndarray) -> np.ndarray:
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
    def from_camera(cls, camera: Any, index: int = 0) -> "MitsubaCamera":
        """Build from view ``index`` of a ``meshadv.render.Camera`` (spherical or look-at, tilt applied).

        Raises:
            ValueError: the camera is orthographic or ``index`` is out of range.
        """
        if getattr(camera, "orthographic", False):
            raise ValueError("camera: orthographic cameras are not supported by the Mitsuba conversion")
        if not 0 <= index < len(camera):
            raise ValueError(f"index {index} out of range for a camera batch of {len(camera)}")
        eye = _as_numpy(camera.eye()[index], np.float64)
        target = _as_numpy(camera.target()[index], np.float64)
        up = _as_numpy(camera.rotation()[index, 1], np.float64)
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
            eye, at = _as_numpy(record["eye"], np.float64), _as_numpy(record["at"], np.float64)
            up = _tilted_up(eye, at, _as_numpy(record["up"], np.float64), float(record.get("tilt", 0.0)))
            return cls(
                tuple(eye.tolist()),
                tuple(at.tolist()),
                tuple(up.tolist()),
                float(record.get("viewing_angle", 30.0)),
                float(record.get("near", 0.1)),
                float(record.get("far", 100.0)),
            )
        missing = [k for k in ("distance", "azimuth", "elevation") if k not in record]
        if missing:
            raise ValueError(f"record is missing camera keys {missing} (or eye, at, up)")
        return cls.spherical(
            float(record["distance"]),
            float(record["azimuth"]),
            float(record["elevation"]),
            float(record.get("tilt", 0.0)),
            float(record.get("viewing_angle", 30.0)),
            float(record.get("near", 0.1)),
            float(record.get("far", 100.0)),
        )

    def view_axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """NMR's view axes ``(x, y, z)``: x is image right, y image up, z the viewing direction."""
        eye, target, up = (np.asarray(v, dtype=np.float64) for v in (self.eye, self.target, self.up))
        z = _normalize(target - eye)
        x = _normalize(np.cross(up, z))
        y = _normalize(np.cross(z, x))
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


def _tilted_up(eye: np.ndarray, target: np.ndarray, up: np.ndarray, tilt: float) -> np.ndarray:
    """Rotate ``up`` about the viewing axis by ``tilt`` degrees, counter-clockwise in the image."""
    if tilt == 0.0:
        return up.astype(np.float64)
    z = _normalize(target - eye)
    x = _normalize(np.cross(up, z))
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
            _as_numpy(record["light_directions"]), _as_numpy(record["light_colors"]), _as_numpy(record["ambient"])
        )

    @classmethod
    def from_lights(cls, lights: Any, index: int = 0) -> "MitsubaLights":
        """Build from a ``meshadv.render.Lights`` (view ``index`` of a batched one)."""
        d, c, a = (_as_numpy(t) for t in (lights.directions, lights.colors, lights.ambient))
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
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_colors: np.ndarray
    to_world: Optional[np.ndarray] = None
    name: str = "object"

    def __post_init__(self) -> None:
        v = _as_numpy(self.vertices, np.float32)
        f = _as_numpy(self.faces, np.int64)
        c = _as_numpy(self.face_colors, np.float32)
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
            m = _as_numpy(self.to_world, np.float64)
            if m.shape != (4, 4):
                raise ValueError(f"to_world must be a 4x4 matrix, got {m.shape}")
            object.__setattr__(self, "to_world", m)

    @classmethod
    def from_mesh(cls, mesh: Any, to_world: Optional[np.ndarray] = None, name: str = "object") -> "MeshObject":
        """Build from a ``meshadv.mesh.Mesh`` (or anything with vertices, faces, face_colors)."""
        return cls(mesh.vertices, mesh.faces, mesh.face_colors, to_world, name)


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
        size = self.image_size
        if isinstance(size, int):
            size = (size, size)
        size = (int(size[0]), int(size[1]))
        if min(size) <= 0 or size[0] != size[1]:
            raise ValueError(f"image_size must be positive and square (H == W), got {size}")
        object.__setattr__(self, "image_size", size)
        object.__setattr__(self, "objects", tuple(self.objects))
        if self.spp < 1:
            raise ValueError(f"spp must be >= 1, got {self.spp}")
        if self.max_depth < 1 and self.max_depth != -1:
            raise ValueError(f"max_depth must be >= 1 (or -1 for unlimited), got {self.max_depth}")
        if self.base_scene is not None and not Path(self.base_scene).is_file():
            raise FileNotFoundError(f"base_scene {self.base_scene} does not exist")
        if self.environment is not None:
            env = _as_numpy(self.environment, np.float32)
            if env.ndim != 3 or env.shape[2] != 3:
                raise ValueError(f"environment must be (H, W, 3), got {env.shape}")
            object.__setattr__(self, "environment", env)


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
    obj = mesh if isinstance(mesh, MeshObject) else MeshObject.from_mesh(mesh)
    if isinstance(camera, Mapping):
        record = camera
        camera = MitsubaCamera.from_record(record)
        if lights is None and "light_directions" in record:
            lights = record
    if isinstance(lights, Mapping):
        lights = MitsubaLights.from_record(lights)
    return SceneSpec(objects=(obj,), camera=camera, lights=lights, **kwargs)


# ----------------------------------------------------------------------------------------------------------------------
# Mitsuba side (imported only inside the rendering child process)
# ----------------------------------------------------------------------------------------------------------------------


def _base_scene_xml(path: Path, exclude: Sequence[str], keep_emitters: bool) -> str:
    """Read a Mitsuba XML scene, drop its sensor/integrator (and excluded shapes), make file names absolute."""
    tree = ET.parse(path)
    root = tree.getroot()
    for child in list(root):
        tag = child.tag
        if tag in ("sensor", "integrator"):
            root.remove(child)
        elif tag == "emitter" and not keep_emitters:
            root.remove(child)
        elif tag == "shape":
            names = [child.get("id", "")] + [
                s.get("value", "") for s in child.iter("string") if s.get("name") == "filename"
            ]
            if any(ex and ex in name for ex in exclude for name in names):
                root.remove(child)
            elif not keep_emitters:
                for em in child.findall("emitter"):
                    child.remove(em)
    for node in root.iter("string"):
        if node.get("name") == "filename":
            value = node.get("value", "")
            if value and not Path(value).is_absolute():
                node.set("value", str((path.parent / value).resolve()))
    return ET.tostring(root, encoding="unicode")


def _mitsuba_mesh(mi: Any, obj: MeshObject) -> Any:
    bsdf = mi.load_dict(
        {
            "type": "twosided",
            "material": {"type": "diffuse", "reflectance": {"type": "mesh_attribute", "name": "face_color"}},
        }
    )
    props = mi.Properties()
    props["bsdf"] = bsdf
    vertices = obj.vertices.astype(np.float64)
    if obj.to_world is not None:
        homo = np.concatenate([vertices, np.ones((len(vertices), 1))], axis=1) @ obj.to_world.T
        vertices = homo[:, :3] / homo[:, 3:4]
    mesh = mi.Mesh(
        obj.name, len(vertices), len(obj.faces), props=props, has_vertex_normals=False, has_vertex_texcoords=False
    )
    params = mi.traverse(mesh)
    float_buffer = type(params["vertex_positions"])  # mi.Float (JIT variants) or drjit.scalar.ArrayXf (scalar)
    params["vertex_positions"] = float_buffer(vertices.astype(np.float32).ravel())
    params["faces"] = type(params["faces"])(obj.faces.ravel())
    params.update()
    mesh.add_attribute("face_color", 3, float_buffer(obj.face_colors.ravel()))
    return mesh


def sensor_dict(mi: Any, camera: MitsubaCamera, image_size: tuple[int, int], spp: int, seed: int, mask: bool) -> dict:
    """The Mitsuba ``perspective`` sensor dict of meshadv's camera (a physical camera: flip its image left-right)."""
    h, w = image_size
    if h != w:
        raise ValueError(f"image_size must be square for Mitsuba (meshadv stretches non-square images), got {(h, w)}")
    to_world = mi.ScalarTransform4f().look_at(origin=list(camera.eye), target=list(camera.target), up=list(camera.up))
    if mask and spp == 1:
        sampler = {"type": "stratified", "sample_count": 1, "jitter": False, "seed": seed}
    else:
        sampler = {"type": "independent", "sample_count": spp, "seed": seed}
    return {
        "type": "perspective",
        "fov": float(camera.viewing_angle),
        "fov_axis": "x",
        "near_clip": float(camera.near),
        "far_clip": float(camera.far),
        "to_world": to_world,
        "sampler": sampler,
        "film": {
            "type": "hdrfilm",
            "width": int(w),
            "height": int(h),
            "pixel_format": "rgba",
            "rfilter": {"type": "box"},
        },
    }


def build_mitsuba_scene(mi: Any, spec: SceneSpec) -> Any:
    """Build the Mitsuba scene object for ``spec`` (call with a variant already set).

    Args:
        mi: the imported ``mitsuba`` module.
        spec: the scene.

    Returns:
        A ``mi.Scene``.
    """
    scene: dict[str, Any] = {"type": "scene"}
    if spec.mask:
        scene["integrator"] = {"type": "path", "max_depth": 1, "hide_emitters": True}
    else:
        scene["integrator"] = {
            "type": "path",
            "max_depth": int(spec.max_depth),
            "hide_emitters": spec.background is not None,
        }
    scene["sensor"] = sensor_dict(mi, spec.camera, spec.image_size, spec.spp, spec.seed, spec.mask)
    for i, obj in enumerate(spec.objects):
        scene[f"object_{i}"] = _mitsuba_mesh(mi, obj)
    if spec.mask:
        return mi.load_dict(scene)
    if spec.lights is not None:
        for k, (d, c) in enumerate(zip(spec.lights.directions, spec.lights.colors)):
            if not np.any(c > 0):
                continue
            d = _normalize(np.asarray(d, dtype=np.float64))
            scene[f"light_{k}"] = {
                "type": "directional",
                "direction": (-d).tolist(),
                "irradiance": {"type": "rgb", "value": (math.pi * np.asarray(c, dtype=np.float64)).tolist()},
            }
        if np.any(spec.lights.ambient > 0):
            scene["ambient"] = {
                "type": "constant",
                "radiance": {"type": "rgb", "value": spec.lights.ambient.astype(np.float64).tolist()},
            }
    if spec.environment is not None:
        bitmap = mi.Bitmap(np.ascontiguousarray(spec.environment, dtype=np.float32))
        scene["environment"] = {"type": "envmap", "bitmap": bitmap, "scale": float(spec.environment_scale)}
    if spec.ground is not None:
        height, color = spec.ground
        scene["ground"] = {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f().translate([0.0, float(height), 0.0])
            @ mi.ScalarTransform4f().rotate([1, 0, 0], -90)
            @ mi.ScalarTransform4f().scale(50.0),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(map(float, color))}},
        }
    if spec.base_scene is not None:
        xml = _base_scene_xml(Path(spec.base_scene), spec.base_exclude, spec.base_emitters)
        base = mi.load_string(xml)
        for i, shape in enumerate(base.shapes()):
            scene[f"base_shape_{i}"] = shape
        if spec.base_emitters:
            for i, emitter in enumerate(base.emitters()):
                if emitter.is_environment():
                    scene[f"base_emitter_{i}"] = emitter
    return mi.load_dict(scene)


def outdoor_environment(
    height: int = 64,
    sun_elevation: float = 45.0,
    sun_azimuth: float = 30.0,
    sun_strength: float = 40.0,
    sky: tuple[float, float, float] = (0.45, 0.6, 0.9),
    horizon: tuple[float, float, float] = (0.9, 0.9, 0.85),
    ground: tuple[float, float, float] = (0.3, 0.27, 0.22),
) -> np.ndarray:
    """A simple procedural outdoor lat-long environment map (sky gradient, small sun, dark ground).

    Args:
        height: map height in pixels (width is twice that).
        sun_elevation: sun elevation in degrees.
        sun_azimuth: sun azimuth in degrees (meshadv's azimuth convention for a direction).
        sun_strength: radiance of the sun disc relative to the sky.
        sky: zenith colour.
        horizon: horizon colour.
        ground: colour below the horizon.

    Returns:
        (height, 2 * height, 3) float32 radiance, Mitsuba's lat-long layout (+Y up).

    Raises:
        ValueError: ``height`` < 4.
    """
    if height < 4:
        raise ValueError(f"height must be >= 4, got {height}")
    w = 2 * height
    theta = (np.arange(height) + 0.5) / height * math.pi  # 0 at +Y
    phi = (np.arange(w) + 0.5) / w * 2 * math.pi
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    # Mitsuba's envmap: direction = (sin(theta) sin(phi), cos(theta), -sin(theta) cos(phi)).
    dirs = np.stack([np.sin(th) * np.sin(ph), np.cos(th), -np.sin(th) * np.cos(ph)], axis=-1)
    up = np.clip(dirs[..., 1], -1, 1)
    t = np.clip(up, 0, 1)[..., None] ** 0.5
    env = (1 - t) * np.asarray(horizon) + t * np.asarray(sky)
    env = np.where(up[..., None] < 0, np.asarray(ground), env)
    sun = np.array(spherical_direction(sun_azimuth, sun_elevation))
    cos_angle = dirs @ sun
    env = env + sun_strength * (cos_angle > math.cos(math.radians(4.0)))[..., None]
    return env.astype(np.float32)


__all__ = [
    "MeshObject",
    "MitsubaCamera",
    "MitsubaLights",
    "SceneSpec",
    "build_mitsuba_scene",
    "outdoor_environment",
    "scene_spec",
    "sensor_dict",
]
