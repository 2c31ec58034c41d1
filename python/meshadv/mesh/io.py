"""Loading meshes from OBJ, OFF, PLY, STL and GLB/glTF through trimesh, and saving them as PLY or OBJ + MTL.

Loading cleans the mesh (merges bit-identical vertices, drops degenerate and duplicate faces and unreferenced
vertices) in an order-preserving way and reports what changed in a :class:`LoadReport`; scene files are flattened
with their node transforms. Unusable files raise :class:`~meshadv.mesh.errors.MeshLoadError` naming the file.
"""

from __future__ import annotations

import importlib
import io as _io
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence, Union

import numpy as np
import trimesh

from meshadv import __version__, _validate
from meshadv.mesh import _obj, _ply, _strict
from meshadv.util.atomic import write_bytes_atomic
from meshadv.mesh.cleanup import clean_arrays
from meshadv.mesh.errors import MeshLoadError
from meshadv.mesh.structure import Mesh

PathLike = Union[str, "os.PathLike[str]"]

#: Default limit on the number of triangles a loaded file may have.
DEFAULT_MAX_FACES = 2_000_000
#: Colour given to faces the file does not colour (the renderer's default grey reflectance).
DEFAULT_COLOR = (0.7, 0.7, 0.7)
#: File extensions :func:`load_mesh` accepts.
LOAD_FORMATS = (".obj", ".off", ".ply", ".stl", ".glb", ".gltf")
#: File extensions :func:`save_mesh` writes.
SAVE_FORMATS = (".ply", ".obj")


def max_file_bytes() -> int:
    """The largest mesh file :func:`load_mesh` reads, in bytes (1 GiB), checked before anything is read: the native
    core's ``MAX_MESH_FILE_BYTES``, the render binary's limit too."""
    return int(importlib.import_module("meshadv._raster").MAX_MESH_FILE_BYTES)


@dataclass(frozen=True)
class LoadReport:
    """What :func:`load_mesh_with_report` found and changed.

    Attributes:
        path: the file read.
        file_format: its extension without the dot.
        num_geometries: triangle geometries flattened into the mesh (more than 1 for multi-part scenes).
        input_vertices: vertices in the file (summed over geometries).
        input_faces: triangles in the file (polygons counted after triangulation).
        merged_vertices: vertices merged into an earlier vertex with the same position.
        degenerate_faces: faces dropped for a repeated corner or zero area.
        unreferenced_vertices: vertices dropped because no face used them.
        duplicate_faces: faces dropped because an earlier face has the same three vertices.
        color_source: ``"ply-exact"``, ``"face"``, ``"vertex"``, ``"material"``, ``"texture"``, ``"default"`` or
            ``"mixed"`` (different geometries coloured differently).
        warnings: anything else worth knowing (missing material library, ignored non-mesh geometry, ...).
    """

    path: Path
    file_format: str
    num_geometries: int
    input_vertices: int
    input_faces: int
    merged_vertices: int
    degenerate_faces: int
    unreferenced_vertices: int
    duplicate_faces: int
    color_source: str
    warnings: "tuple[str, ...]" = ()

    @property
    def changed(self) -> bool:
        """True when clean-up removed or merged anything."""
        return bool(self.merged_vertices or self.degenerate_faces or self.unreferenced_vertices or self.duplicate_faces)

    def summary(self) -> str:
        """A one-line human-readable account of the load."""
        parts = [f"{self.path.name}: {self.input_vertices} vertices, {self.input_faces} faces"]
        if self.num_geometries > 1:
            parts.append(f"{self.num_geometries} geometries flattened")
        if self.changed:
            parts.append(
                f"merged {self.merged_vertices} duplicate vertices, dropped {self.degenerate_faces} degenerate "
                f"faces, {self.duplicate_faces} duplicate faces and {self.unreferenced_vertices} unreferenced vertices"
            )
        else:
            parts.append("unchanged by clean-up")
        parts.append(f"colours: {self.color_source}")
        return "; ".join(parts + list(self.warnings))


def _check_binary_stl(path: Path) -> None:
    """Refuse a binary STL whose size does not match its triangle count (a truncated download)."""
    size = path.stat().st_size
    with path.open("rb") as handle:
        head = handle.read(4096)
    if head[:5].lower() == b"solid" and b"facet" in head:
        return  # ASCII STL
    if size < 84:
        raise MeshLoadError(f"{path}: truncated STL file ({size} bytes, shorter than the 84-byte header)")
    count = int.from_bytes(head[80:84], "little")
    if size != 84 + 50 * count:
        raise MeshLoadError(
            f"{path}: truncated or malformed binary STL: header announces {count} triangles "
            f"({84 + 50 * count} bytes) but the file has {size} bytes"
        )


def _trimesh_load(path: Path, ext: str) -> object:
    if ext == ".stl":
        _check_binary_stl(path)
    if ext == ".off":
        _strict.check_off(path.read_text(errors="replace"), path)
    if ext == ".ply":
        _strict.check_ascii_ply(path.read_bytes(), path)
    if ext == ".obj":
        text = path.read_text(errors="replace")
        _strict.check_obj(text, path)
        # Material statements removed: one geometry, faces in file order (colours are recovered separately).
        return trimesh.load(
            _io.StringIO(_obj.strip_materials(text)), file_type="obj", process=False, maintain_order=True
        )
    return trimesh.load(str(path), process=False)


def _flatten(loaded: object, path: Path) -> "tuple[list[trimesh.Trimesh], list[str]]":
    warnings: "list[str]" = []
    if isinstance(loaded, trimesh.Trimesh):
        return [loaded], warnings
    if isinstance(loaded, trimesh.Scene):
        parts = []
        for geom in loaded.dump():  # copies with the scene-graph transforms applied
            if isinstance(geom, trimesh.Trimesh):
                parts.append(geom)
            else:
                warnings.append(f"ignored a non-triangle geometry ({type(geom).__name__})")
        return parts, warnings
    raise MeshLoadError(f"{path}: the file has no faces (trimesh read a {type(loaded).__name__}, not a mesh)")


def _part_colors(part: trimesh.Trimesh, default: np.ndarray, is_ply: bool) -> "tuple[np.ndarray, str]":
    num_faces = len(part.faces)
    if is_ply:
        exact = _ply.exact_face_colors(part.metadata)
        if exact is not None and len(exact) == num_faces:
            return exact, "ply-exact"
    visual = part.visual
    kind = getattr(visual, "kind", None)
    try:
        if kind == "face":
            return np.asarray(visual.face_colors, dtype=np.float32)[:, :3] / 255.0, "face"
        if kind == "vertex":
            vc = np.asarray(visual.vertex_colors, dtype=np.float32)[:, :3] / 255.0
            return vc[np.asarray(part.faces)].mean(axis=1), "vertex"
        if kind == "texture":
            has_image = getattr(getattr(visual, "material", None), "image", None) is not None
            color_visual = visual.to_color()
            vc = np.asarray(color_visual.vertex_colors, dtype=np.float32)
            if vc.ndim == 2 and len(vc) == len(part.vertices):
                return vc[np.asarray(part.faces), :3].mean(axis=1) / 255.0, "texture" if has_image else "material"
            main = np.asarray(color_visual.main_color, dtype=np.float32)[:3] / 255.0
            return np.broadcast_to(main, (num_faces, 3)).copy(), "material"
    except Exception:  # noqa: BLE001 - a broken visual must not make the geometry unusable
        pass
    return np.broadcast_to(default, (num_faces, 3)).copy(), "default"


def load_mesh_with_report(
    path: PathLike,
    *,
    max_faces: int = DEFAULT_MAX_FACES,
    default_color: Sequence[float] = DEFAULT_COLOR,
) -> "tuple[Mesh, LoadReport]":
    """Load a mesh file into a clean :class:`Mesh` and report what was changed.

    Args:
        path: an ``.obj``, ``.off``, ``.ply``, ``.stl``, ``.glb`` or ``.gltf`` file.
        max_faces: refuse files with more triangles than this.
        default_color: RGB in ``[0, 1]`` for faces the file does not colour.

    Returns:
        ``(mesh, report)``; the mesh is on the CPU, vertices in the file's coordinates.

    Raises:
        TypeError: ``path`` is not a str or os.PathLike (a bytes path), ``default_color`` not 3 numbers.
        FileNotFoundError: ``path`` does not exist.
        ValueError: bad ``max_faces``, or a ``default_color`` value outside ``[0, 1]``.
        MeshLoadError: (a ``ValueError``) unsupported extension, a file larger than :func:`max_file_bytes`,
            unreadable or truncated file, no faces, non-finite coordinates, out-of-range face indices, or more
            than ``max_faces`` faces.

    Example:
        >>> mesh, report = load_mesh_with_report("chair/01.ply")  # doctest: +SKIP
        >>> print(report.summary())  # doctest: +SKIP
    """
    path = _validate.path("path", path)
    if isinstance(max_faces, bool) or not isinstance(max_faces, int) or max_faces < 1:
        raise ValueError(f"max_faces must be a positive integer, got {max_faces!r}")
    default = np.asarray(_validate.color("default_color", default_color), dtype=np.float32)
    if not path.exists():
        raise FileNotFoundError(f"mesh file not found: {path}")
    if not path.is_file():
        raise MeshLoadError(f"{path}: not a regular file")
    ext = path.suffix.lower()
    if ext not in LOAD_FORMATS:
        raise MeshLoadError(f"{path}: unsupported mesh format {ext!r}; expected one of {', '.join(LOAD_FORMATS)}")
    size = path.stat().st_size
    if size == 0:
        raise MeshLoadError(f"{path}: the file is empty")
    limit = max_file_bytes()
    if size > limit:
        raise MeshLoadError(f"{path}: the file ({size} bytes) is larger than the {limit}-byte limit")

    try:
        loaded = _trimesh_load(path, ext)
    except MeshLoadError:
        raise
    except Exception as exc:  # noqa: BLE001 - trimesh raises many types for bad files; name the file
        raise MeshLoadError(
            f"{path}: cannot read this {ext[1:].upper()} file, it is malformed or truncated "
            f"({type(exc).__name__}: {exc})"
        ) from exc
    parts, warnings = _flatten(loaded, path)
    input_faces = sum(len(p.faces) for p in parts)
    input_vertices = sum(len(p.vertices) for p in parts)
    if input_faces == 0:
        raise MeshLoadError(f"{path}: the file has no faces (a point cloud or an empty mesh cannot be rendered)")
    if input_faces > max_faces:
        raise MeshLoadError(f"{path}: {input_faces} faces exceed the limit max_faces={max_faces}")

    verts_list, faces_list, colors_list, sources = [], [], [], []
    offset = 0
    for part in parts:
        verts = np.asarray(part.vertices, dtype=np.float64)
        faces = np.asarray(part.faces, dtype=np.int64).reshape(-1, 3)
        if faces.size and (faces.min() < 0 or faces.max() >= len(verts)):
            raise MeshLoadError(
                f"{path}: a face index is out of range (indices span [{faces.min()}, {faces.max()}] "
                f"for {len(verts)} vertices)"
            )
        colors, source = _part_colors(part, default, ext == ".ply")
        verts_list.append(verts)
        faces_list.append(faces + offset)
        colors_list.append(colors.astype(np.float32))
        sources.append(source)
        offset += len(verts)
    vertices = np.concatenate(verts_list)
    faces = np.concatenate(faces_list)
    colors = np.concatenate(colors_list)

    if ext == ".obj":
        text = path.read_text(errors="replace")
        obj_colors, triangles, obj_warnings = _obj.face_colors_in_file_order(text, path.parent, default)
        warnings += obj_warnings
        if obj_colors is not None:
            if triangles == len(faces):
                colors, sources = obj_colors, ["material"]
            else:
                warnings.append(
                    f"OBJ materials describe {triangles} triangles but {len(faces)} were read; colours ignored"
                )

    finite = np.isfinite(vertices).all(axis=1)
    if not finite.all():
        raise MeshLoadError(f"{path}: {int((~finite).sum())} vertices have non-finite (NaN or infinite) coordinates")
    vertices32 = vertices.astype(np.float32)
    if not np.isfinite(vertices32).all():
        raise MeshLoadError(f"{path}: coordinates overflow float32")
    colors = np.nan_to_num(colors, nan=0.0).astype(np.float32)

    vertices32, faces, colors, counts = clean_arrays(vertices32, faces, colors)
    if len(faces) == 0:
        raise MeshLoadError(f"{path}: every face is degenerate (repeated corner or zero area)")
    unique_sources = sorted(set(sources))
    report = LoadReport(
        path=path,
        file_format=ext[1:],
        num_geometries=len(parts),
        input_vertices=input_vertices,
        input_faces=input_faces,
        merged_vertices=counts.merged_vertices,
        degenerate_faces=counts.degenerate_faces,
        unreferenced_vertices=counts.unreferenced_vertices,
        duplicate_faces=counts.duplicate_faces,
        color_source=unique_sources[0] if len(unique_sources) == 1 else "mixed",
        warnings=tuple(warnings),
    )
    return Mesh.from_numpy(vertices32, faces, colors), report


def load_mesh(
    path: PathLike,
    *,
    max_faces: int = DEFAULT_MAX_FACES,
    default_color: Sequence[float] = DEFAULT_COLOR,
) -> Mesh:
    """Load a mesh file into a clean :class:`Mesh` (see :func:`load_mesh_with_report` for details).

    Args:
        path: an ``.obj``, ``.off``, ``.ply``, ``.stl``, ``.glb`` or ``.gltf`` file.
        max_faces: refuse files with more triangles than this.
        default_color: RGB in ``[0, 1]`` for faces the file does not colour.

    Returns:
        The mesh, on the CPU.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        MeshLoadError: the file cannot be used (the message names it and says why).
    """
    return load_mesh_with_report(path, max_faces=max_faces, default_color=default_color)[0]


def save_mesh(mesh: Mesh, path: PathLike) -> "list[Path]":
    """Save a mesh with its per-face colours so that any 3D tool opens it and meshadv reloads it exactly.

    ``.ply``: binary PLY with 8-bit ``red green blue`` per face plus exact float32 colour properties.
    ``.obj``: OBJ with a ``.mtl`` of the same stem beside it, one material (``Kd``) per distinct colour.
    Files are written atomically. Reloading with :func:`load_mesh` gives the same vertices, faces (same order)
    and colours (clamped to ``[0, 1]`` for OBJ).

    Args:
        mesh: the mesh (any device; gradients are ignored).
        path: destination ending in ``.ply`` or ``.obj``; the folder is created if needed.

    Returns:
        The written files (the OBJ first, then its MTL).

    Raises:
        ValueError: unsupported extension, or non-finite vertices.
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in SAVE_FORMATS:
        raise ValueError(f"path must end in one of {', '.join(SAVE_FORMATS)}, got {str(path)!r}")
    vertices, faces, colors = mesh.numpy()
    if not np.isfinite(vertices).all():
        raise ValueError("mesh.vertices has non-finite values; refusing to save")
    path.parent.mkdir(parents=True, exist_ok=True)
    comment = f"written by meshadv {__version__}"
    if ext == ".ply":
        write_bytes_atomic(path, _ply.encode_ply(vertices, faces, colors, comment))
        return [path]
    mtl_path = path.with_suffix(".mtl")
    obj_text, mtl_text = _obj.encode_obj(vertices, faces, colors, mtl_path.name, comment)
    write_bytes_atomic(mtl_path, mtl_text.encode("utf-8"))
    write_bytes_atomic(path, obj_text.encode("utf-8"))
    return [path, mtl_path]
