"""Build the Mitsuba 3 scene of a :class:`~meshadv.transfer.mitsuba_spec.SceneSpec` (runs in the rendering child
process), and a procedural outdoor environment map (sky, sun, ground) for its ``envmap`` emitter
(:func:`outdoor_environment`). Only :func:`build_mitsuba_scene` and :func:`sensor_dict` need Mitsuba (passed in as
``mi``).

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
  texture), flat shading (no vertex normals), as meshadv's two-sided per-face Lambert shading; a textured or
  vertex-coloured mesh's bitmap texture or ``vertex_color`` attribute instead (a mesh with both: their product, the
  ``meshadv_product`` texture of :mod:`~meshadv.transfer.mitsuba_product`), and its vertex normals when meshadv
  shades it smooth.
* Images are linear RGB clamped to [0, 1] (no tone mapping or gamma), as meshadv's.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from meshadv import _validate
from meshadv.transfer.mitsuba_product import product_texture
from meshadv.transfer.mitsuba_spec import MeshObject, MitsubaCamera, MitsubaLights, SceneSpec, normalize
from meshadv.util.spherical import spherical_direction

__all__ = ["build_mitsuba_scene", "outdoor_environment", "sensor_dict"]


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
        TypeError: ``height`` is not an int.
        ValueError: ``height`` < 4.
    """
    _validate.integer("height", height, low=4)
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
    """A Mitsuba mesh of ``obj`` (``to_world`` applied) with its face colours, its bitmap texture (bilinear, repeat,
    linear values), its vertex colours (interpolated) or the product of both, as a two-sided diffuse reflectance;
    vertex normals when it has them."""
    if obj.texture is not None:
        reflectance = {
            "type": "bitmap",
            "bitmap": mi.Bitmap(np.ascontiguousarray(obj.texture, dtype=np.float32)),
            "filter_type": "bilinear",
            "wrap_mode": "repeat",
            "raw": True,
        }
        if obj.vertex_colors is not None:
            reflectance = product_texture(mi, reflectance, {"type": "mesh_attribute", "name": "vertex_color"})
    elif obj.vertex_colors is not None:
        reflectance = {"type": "mesh_attribute", "name": "vertex_color"}
    else:
        reflectance = {"type": "mesh_attribute", "name": "face_color"}
    bsdf = mi.load_dict({"type": "twosided", "material": {"type": "diffuse", "reflectance": reflectance}})
    props = mi.Properties()
    props["bsdf"] = bsdf
    vertices = obj.vertices.astype(np.float64)
    if obj.to_world is not None:
        homo = np.concatenate([vertices, np.ones((len(vertices), 1))], axis=1) @ obj.to_world.T
        vertices = homo[:, :3] / homo[:, 3:4]
    mesh = mi.Mesh(
        obj.name,
        len(vertices),
        len(obj.faces),
        props=props,
        has_vertex_normals=obj.normals is not None,
        has_vertex_texcoords=obj.uvs is not None,
    )
    params = mi.traverse(mesh)
    float_buffer = type(params["vertex_positions"])  # mi.Float (JIT variants) or drjit.scalar.ArrayXf (scalar)
    params["vertex_positions"] = float_buffer(vertices.astype(np.float32).ravel())
    params["faces"] = type(params["faces"])(obj.faces.ravel())
    if obj.uvs is not None:
        # Mitsuba's bitmap rows run top to bottom in v (its OBJ loader flips v): meshadv's v is 1 - v there.
        texcoords = np.stack([obj.uvs[:, 0], 1.0 - obj.uvs[:, 1]], axis=1).astype(np.float32)
        params["vertex_texcoords"] = float_buffer(texcoords.ravel())
    if obj.normals is not None:
        normals = obj.normals.astype(np.float64)
        if obj.to_world is not None:
            normals = normals @ np.linalg.inv(obj.to_world[:3, :3])
        params["vertex_normals"] = float_buffer(normals.astype(np.float32).ravel())
    params.update()
    mesh.add_attribute("face_color", 3, float_buffer(obj.face_colors.ravel()))
    if obj.vertex_colors is not None:
        mesh.add_attribute("vertex_color", 3, float_buffer(obj.vertex_colors.astype(np.float32).ravel()))
    return mesh


def sensor_dict(mi: Any, camera: MitsubaCamera, image_size: tuple[int, int], spp: int, seed: int,
                mask: bool) -> dict[str, Any]:
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
    scene: dict[str, Any] = {"type": "scene", "integrator": _integrator(spec)}
    scene["sensor"] = sensor_dict(mi, spec.camera, spec.image_size, spec.spp, spec.seed, spec.mask)
    for i, obj in enumerate(spec.objects):
        scene[f"object_{i}"] = _mitsuba_mesh(mi, obj)
    if spec.mask:
        return mi.load_dict(scene)
    if spec.lights is not None:
        scene.update(_light_emitters(spec.lights))
    if spec.environment is not None:
        bitmap = mi.Bitmap(np.ascontiguousarray(spec.environment, dtype=np.float32))
        scene["environment"] = {"type": "envmap", "bitmap": bitmap, "scale": float(spec.environment_scale)}
    if spec.ground is not None:
        scene["ground"] = _ground_plane(mi, spec.ground)
    if spec.base_scene is not None:
        scene.update(_base_scene_parts(mi, spec.base_scene, spec.base_exclude, spec.base_emitters))
    return mi.load_dict(scene)


def _integrator(spec: SceneSpec) -> dict[str, Any]:
    """A path tracer: for a coverage mask, emitters hidden and ``max_depth = 2`` (a mask scene has no emitters, so
    the colour is black whatever the depth; with ``max_depth = 1`` the ``scalar_rgb`` variant, the fallback, leaves
    the alpha empty); else ``max_depth`` bounces with emitters hidden behind a background colour."""
    if spec.mask:
        return {"type": "path", "max_depth": 2, "hide_emitters": True}
    return {"type": "path", "max_depth": int(spec.max_depth), "hide_emitters": spec.background is not None}


def _light_emitters(lights: MitsubaLights) -> dict[str, dict[str, Any]]:
    """meshadv's lights as Mitsuba emitters: a ``directional`` emitter per light of non-zero colour (``light_k``,
    ``direction = -l``, ``irradiance = pi * colour``) and a ``constant`` one for a non-zero ambient (``ambient``)."""
    emitters: dict[str, dict[str, Any]] = {}
    for k, (d, c) in enumerate(zip(lights.directions, lights.colors)):
        if not np.any(c > 0):
            continue
        d = normalize(np.asarray(d, dtype=np.float64))
        emitters[f"light_{k}"] = {
            "type": "directional",
            "direction": (-d).tolist(),
            "irradiance": {"type": "rgb", "value": (math.pi * np.asarray(c, dtype=np.float64)).tolist()},
        }
    if np.any(lights.ambient > 0):
        emitters["ambient"] = {
            "type": "constant",
            "radiance": {"type": "rgb", "value": lights.ambient.astype(np.float64).tolist()},
        }
    return emitters


def _ground_plane(mi: Any, ground: tuple[float, tuple[float, float, float]]) -> dict[str, Any]:
    """The ``(height, colour)`` ground: a 100 x 100 diffuse rectangle of that colour in the plane ``y = height``,
    facing up."""
    height, color = ground
    return {
        "type": "rectangle",
        "to_world": mi.ScalarTransform4f().translate([0.0, float(height), 0.0])
        @ mi.ScalarTransform4f().rotate([1, 0, 0], -90)
        @ mi.ScalarTransform4f().scale(50.0),
        "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(map(float, color))}},
    }


def _base_scene_parts(mi: Any, path: str, exclude: Sequence[str], keep_emitters: bool) -> dict[str, Any]:
    """The shapes of the Mitsuba scene file ``path`` (``base_shape_i``; those matching ``exclude`` dropped) and, with
    ``keep_emitters``, its environment emitters (``base_emitter_i``)."""
    base = mi.load_string(_base_scene_xml(Path(path), exclude, keep_emitters))
    parts: dict[str, Any] = {f"base_shape_{i}": shape for i, shape in enumerate(base.shapes())}
    if keep_emitters:
        for i, emitter in enumerate(base.emitters()):
            if emitter.is_environment():
                parts[f"base_emitter_{i}"] = emitter
    return parts
