"""glTF files written here byte by byte (no exporter in between), so that the tests control every accessor: a
textured primitive with ``COLOR_0`` of any component type and count, as ``.glb`` or as ``.gltf`` (JSON with the
buffer embedded)."""

from __future__ import annotations

import base64
import io
import json
import struct
from pathlib import Path
from typing import Any, Optional

import numpy as np
from PIL import Image

_COMPONENT = {np.dtype(np.float32): 5126, np.dtype(np.uint8): 5121, np.dtype(np.uint16): 5123}


def write_glb(path: Path, positions: np.ndarray, faces: np.ndarray, *, uvs: Optional[np.ndarray] = None,
              texture: Optional[np.ndarray] = None, colors: Optional[np.ndarray] = None,
              color_type: Optional[str] = None, factor: Optional[list] = None) -> Path:
    """Write one triangle primitive (binary ``.glb``, or ``.gltf`` JSON by ``path``'s suffix): float ``POSITION``,
    uint32 indices, ``TEXCOORD_0`` (``uvs`` with meshadv's origin at the bottom-left, flipped to glTF's top-left), a
    PNG ``baseColorTexture`` (``texture``, (H,W,3) uint8), and ``COLOR_0`` of ``colors``' dtype (uint8 / uint16
    normalised, float32) and count, of type ``color_type`` (default VEC3 or VEC4 from its width); ``factor``: the
    material's ``baseColorFactor``."""
    blobs: list[bytes] = []
    views: list[dict[str, Any]] = []
    accessors: list[dict[str, Any]] = []

    def add_view(data: bytes) -> int:
        offset = sum(len(b) for b in blobs)
        blobs.append(data + b"\0" * (-len(data) % 4))
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(data)})
        return len(views) - 1

    def add_accessor(array: np.ndarray, kind: str, **extra: Any) -> int:
        view = add_view(np.ascontiguousarray(array).tobytes())
        accessors.append({"bufferView": view, "componentType": _COMPONENT.get(array.dtype, 5125),
                          "count": int(array.shape[0]), "type": kind, **extra})
        return len(accessors) - 1

    pos = positions.astype(np.float32)
    attributes = {"POSITION": add_accessor(pos, "VEC3", min=pos.min(0).tolist(), max=pos.max(0).tolist())}
    primitive: dict[str, Any] = {"attributes": attributes, "mode": 4,
                                 "indices": add_accessor(faces.astype(np.uint32).reshape(-1), "SCALAR")}
    tree: dict[str, Any] = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
                            "nodes": [{"mesh": 0}], "meshes": [{"primitives": [primitive]}]}
    if uvs is not None:
        flipped = np.stack([uvs[:, 0], 1.0 - uvs[:, 1]], 1).astype(np.float32)
        attributes["TEXCOORD_0"] = add_accessor(flipped, "VEC2")
    if texture is not None:
        png = io.BytesIO()
        Image.fromarray(texture, "RGB").save(png, format="PNG")
        tree["images"] = [{"bufferView": add_view(png.getvalue()), "mimeType": "image/png"}]
        tree["samplers"] = [{}]
        tree["textures"] = [{"source": 0, "sampler": 0}]
        tree["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0.0}}]
        primitive["material"] = 0
    if factor is not None:
        tree.setdefault("materials", [{"pbrMetallicRoughness": {}}])
        tree["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] = factor
        primitive["material"] = 0
    if colors is not None:
        kind = color_type or ("VEC3" if colors.shape[1] == 3 else "VEC4")
        extra = {} if colors.dtype == np.float32 else {"normalized": True}
        attributes["COLOR_0"] = add_accessor(colors, kind, **extra)
    binary = b"".join(blobs)
    tree.update(buffers=[{"byteLength": len(binary)}], bufferViews=views, accessors=accessors)
    if path.suffix == ".gltf":  # one JSON file, the buffer embedded as a data URI
        tree["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(binary).decode()
        path.write_text(json.dumps(tree))
        return path
    text = json.dumps(tree).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942) + binary
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body)
    return path
