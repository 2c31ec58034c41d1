"""Read the geometry, materials and camera of a Mitsuba 3 scene file into a meshadv ``Scene``.

Only what the rasterizer can use is read: ``ply``/``obj`` shapes and ``rectangle`` shapes with their
``to_world`` transforms (``scale``, ``rotate``, ``translate``, ``matrix``, ``lookat`` is not supported on shapes),
diffuse reflectances (also inside ``twosided``), and the ``perspective`` sensor. Emitters are skipped (a shape that
carries an ``area`` emitter is the light's geometry and is left out).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import defusedxml.ElementTree as _safe_xml
import torch
from defusedxml import DefusedXmlException

from meshadv.mesh import Mesh, load_mesh
from meshadv.scenes.scene import Scene, SceneCamera, SceneObject

_GREY = (0.5, 0.5, 0.5)


def _floats(text: str) -> List[float]:
    return [float(v) for v in text.replace(",", " ").split()]


def _rotation(axis: Tuple[float, float, float], angle_deg: float) -> torch.Tensor:
    axis_t = torch.tensor(axis, dtype=torch.float64)
    axis_t = axis_t / axis_t.norm()
    x, y, z = axis_t.tolist()
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    t = 1.0 - c
    m = torch.eye(4, dtype=torch.float64)
    m[:3, :3] = torch.tensor(
        [
            [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
            [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
            [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
        ],
        dtype=torch.float64,
    )
    return m


def parse_transform(node: Optional[ET.Element]) -> torch.Tensor:
    """Compose a Mitsuba ``<transform>`` element into a 4x4 float32 matrix (each op applied after the previous)."""
    matrix = torch.eye(4, dtype=torch.float64)
    if node is None:
        return matrix.float()
    for op in node:
        step = torch.eye(4, dtype=torch.float64)
        if op.tag == "scale":
            if "value" in op.attrib:
                values = _floats(op.attrib["value"])
                sx, sy, sz = (values * 3)[:3] if len(values) == 1 else values[:3]
            else:
                sx, sy, sz = (float(op.attrib.get(k, 1.0)) for k in ("x", "y", "z"))
            step[0, 0], step[1, 1], step[2, 2] = sx, sy, sz
        elif op.tag == "translate":
            if "value" in op.attrib:
                step[:3, 3] = torch.tensor(_floats(op.attrib["value"])[:3], dtype=torch.float64)
            else:
                step[:3, 3] = torch.tensor([float(op.attrib.get(k, 0.0)) for k in ("x", "y", "z")], dtype=torch.float64)
        elif op.tag == "rotate":
            if "value" in op.attrib:
                axis = tuple(_floats(op.attrib["value"])[:3])
            else:
                axis = tuple(float(op.attrib.get(k, 0.0)) for k in ("x", "y", "z"))
            step = _rotation(axis, float(op.attrib["angle"]))
        elif op.tag == "matrix":
            step = torch.tensor(_floats(op.attrib["value"]), dtype=torch.float64).reshape(4, 4)
        else:
            raise ValueError(f"unsupported transform operation <{op.tag}> in a shape's to_world")
        matrix = step @ matrix
    return matrix.float()


def _reflectance(bsdf: Optional[ET.Element]) -> Tuple[float, float, float]:
    if bsdf is None:
        return _GREY
    for rgb in bsdf.iter("rgb"):
        if rgb.attrib.get("name") == "reflectance":
            values = _floats(rgb.attrib["value"])
            return tuple((values * 3)[:3]) if len(values) == 1 else tuple(values[:3])  # type: ignore[return-value]
    return _GREY


#: Rectangles are split into a grid of this many cells per side: the rasterizer drops a triangle with a vertex
#: behind the camera (as NMR does), so large floors and walls must be made of small triangles.
RECTANGLE_CELLS = 24


def _rectangle_mesh(color: Tuple[float, float, float], cells: int = RECTANGLE_CELLS) -> Mesh:
    """Mitsuba's ``rectangle`` ([-1, 1]^2 in the z = 0 plane) as a ``cells x cells`` grid of triangle pairs."""
    ticks = torch.linspace(-1.0, 1.0, cells + 1)
    ys, xs = torch.meshgrid(ticks, ticks, indexing="ij")
    vertices = torch.stack([xs.reshape(-1), ys.reshape(-1), torch.zeros(xs.numel())], dim=1)
    idx = torch.arange((cells + 1) ** 2).reshape(cells + 1, cells + 1)
    a, b = idx[:-1, :-1].reshape(-1), idx[:-1, 1:].reshape(-1)
    c, d = idx[1:, 1:].reshape(-1), idx[1:, :-1].reshape(-1)
    faces = torch.cat([torch.stack([a, b, c], 1), torch.stack([a, c, d], 1)]).to(torch.int64)
    colors = torch.tensor([color], dtype=torch.float32).expand(faces.shape[0], 3).contiguous()
    return Mesh(vertices=vertices.float().contiguous(), faces=faces, face_colors=colors)


@dataclass(frozen=True)
class MitsubaSceneInfo:
    """What was read from a Mitsuba scene file: the meshadv scene, its camera, and the source path."""

    scene: Scene
    camera: SceneCamera
    path: Path


def read_mitsuba_scene(path: Path, *, names: Optional[Dict[str, str]] = None) -> MitsubaSceneInfo:
    """Read a Mitsuba 3 XML scene into a meshadv ``Scene`` and ``SceneCamera``.

    Args:
        path: the scene file; relative mesh file names are resolved against its folder.
        names: optional mapping from a mesh file's stem (``"desk"``) to the object name to use.

    Raises:
        FileNotFoundError: the scene or one of its meshes is missing.
        ValueError: the file is not a Mitsuba scene or uses an unsupported construct.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"scene file not found: {path}")
    try:
        root = _safe_xml.parse(path).getroot()
    except (ET.ParseError, DefusedXmlException) as exc:
        raise ValueError(f"scene file {path} is not valid XML, or uses entities/DTDs (refused): {exc}") from exc
    if root.tag != "scene":
        raise ValueError(f"{path} is not a Mitsuba scene (root element <{root.tag}>)")
    bsdfs = {b.attrib["id"]: b for b in root.findall("bsdf") if "id" in b.attrib}
    names = names or {}
    objects: List[SceneObject] = []
    counts: Dict[str, int] = {}
    for shape in root.findall("shape"):
        if shape.find("emitter") is not None:
            continue
        bsdf = shape.find("bsdf")
        ref = shape.find("ref")
        if bsdf is None and ref is not None:
            bsdf = bsdfs.get(ref.attrib.get("id", ""))
        color = _reflectance(bsdf)
        transform = parse_transform(shape.find("transform"))
        kind = shape.attrib.get("type")
        if kind in ("ply", "obj"):
            filename = next(s.attrib["value"] for s in shape.findall("string") if s.attrib.get("name") == "filename")
            mesh_path = path.parent / filename
            mesh = load_mesh(mesh_path, default_color=color)
            base = names.get(mesh_path.stem, mesh_path.stem)
        elif kind == "rectangle":
            mesh = _rectangle_mesh(color)
            base = "rectangle"
        else:
            continue
        counts[base] = counts.get(base, 0) + 1
        name = base if counts[base] == 1 else f"{base}_{counts[base]}"
        objects.append(SceneObject(name=name, mesh=mesh, transform=transform))
    camera = _read_camera(root, path)
    return MitsubaSceneInfo(scene=Scene(tuple(objects)), camera=camera, path=path)


def _read_camera(root: ET.Element, path: Path) -> SceneCamera:
    sensor = root.find("sensor")
    if sensor is None or sensor.attrib.get("type") != "perspective":
        raise ValueError(f"{path} has no perspective sensor")
    fov = next((float(f.attrib["value"]) for f in sensor.findall("float") if f.attrib.get("name") == "fov"), 45.0)
    lookat = sensor.find("transform/lookat")
    if lookat is None:
        raise ValueError(f"{path}: the sensor's to_world must be a <lookat>")
    film = sensor.find("film")
    size = {"width": 768, "height": 576}
    if film is not None:
        for node in film.findall("integer"):
            if node.attrib.get("name") in size:
                size[node.attrib["name"]] = int(node.attrib["value"])
    return SceneCamera(
        eye=tuple(_floats(lookat.attrib["origin"])),  # type: ignore[arg-type]
        at=tuple(_floats(lookat.attrib["target"])),  # type: ignore[arg-type]
        up=tuple(_floats(lookat.attrib.get("up", "0 1 0"))),  # type: ignore[arg-type]
        fov=fov,
        width=size["width"],
        height=size["height"],
    )
