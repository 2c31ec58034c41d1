"""Meshes with surface attributes: a UV texture image, vertex colours and vertex normals, loaded from OBJ + MTL
(``map_Kd``, ``v x y z r g b`` vertex colours), glTF/GLB (base-colour texture, ``COLOR_0``) and PLY (vertex colours),
and saved as
OBJ + MTL + PNG, GLB or PLY.

The geometry is welded (one vertex per distinct position), so adjacency, the Laplacian and shape perturbations see
one surface; UVs and normals keep their own per-corner index (``uv_faces``, ``normal_faces``), so a UV seam is two UV
rows of one vertex. Conventions (UV origin at the bottom-left of the image, texture row 0 at the top): docs/TEXTURES.md.
"""

from __future__ import annotations

import io
import os
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Optional, Union

import numpy as np
import torch
import trimesh
from PIL import Image, UnidentifiedImageError

from meshadv._validate import MAX_TEXTURE_COORDINATE
from meshadv.mesh import _gltf
from meshadv.mesh.errors import MeshLoadError
from meshadv.mesh.normalize import NormalizeTransform, normalize_mesh
from meshadv.mesh.structure import Mesh
from meshadv.util.atomic import write_bytes_atomic

__all__ = ["SurfaceMesh", "load_surface_mesh", "save_any_mesh", "save_surface_mesh"]

PathLike = Union[str, "os.PathLike[str]"]

#: Largest accepted texture side in texels.
MAX_TEXTURE_SIDE = 16384


@dataclass(frozen=True)
class SurfaceMesh:
    """A welded triangle mesh with optional UV texture, vertex colours and vertex normals.

    Attributes:
        mesh: the geometry (:class:`Mesh`, welded) with per-face colours: the mean reflectance of each face (texture
            at its UV centroid times its vertex colours), what the flat per-face path renders.
        uvs: (T,2) float32 texture coordinates (origin bottom-left) or None.
        uv_faces: (M,3) int64 rows of ``uvs`` per face corner, or None.
        texture: (Ht,Wt,3) float32 RGB reflectance in [0,1], row 0 at the top, or None.
        vertex_colors: (N,3) float32 RGB per welded vertex, or None.
        normals: (Nn,3) float32 unit normals, or None.
        normal_faces: (M,3) int64 rows of ``normals`` per face corner, or None.
        shading: what the file asks for: ``"smooth"`` when it carries vertex normals, else ``"flat"``.

    Raises:
        ValueError: attribute shapes that do not match the geometry, corner rows out of range, non-finite values, or
            an empty texture; the message names the field.
    """

    mesh: Mesh
    uvs: Optional[torch.Tensor] = None
    uv_faces: Optional[torch.Tensor] = None
    texture: Optional[torch.Tensor] = None
    vertex_colors: Optional[torch.Tensor] = None
    normals: Optional[torch.Tensor] = None
    normal_faces: Optional[torch.Tensor] = None
    shading: str = "flat"

    def __post_init__(self) -> None:
        m, n = self.mesh.num_faces, self.mesh.num_vertices
        if (self.uvs is None) != (self.uv_faces is None) or (self.texture is None) != (self.uvs is None):
            raise ValueError("uvs, uv_faces and texture must be given together")
        if (self.normals is None) != (self.normal_faces is None):
            raise ValueError("normals and normal_faces must be given together")
        if self.shading not in ("flat", "smooth"):
            raise ValueError(f"shading must be 'flat' or 'smooth', got {self.shading!r}")
        for name, rows, corners, width in (
            ("uvs", self.uvs, self.uv_faces, 2),
            ("normals", self.normals, self.normal_faces, 3),
        ):
            if rows is None:
                continue
            if rows.dim() != 2 or rows.shape[1] != width or rows.shape[0] == 0:
                raise ValueError(f"{name} must have shape (K,{width}) with K >= 1, got {tuple(rows.shape)}")
            if not bool(torch.isfinite(rows).all()):
                raise ValueError(f"{name} contains NaN or Inf")
            if name == "uvs" and float(rows.abs().max()) > MAX_TEXTURE_COORDINATE:
                raise ValueError(f"uvs must lie within +-{MAX_TEXTURE_COORDINATE:g}, got {float(rows.abs().max()):g}")
            cname = "uv_faces" if name == "uvs" else "normal_faces"
            if tuple(corners.shape) != (m, 3):
                raise ValueError(f"{cname} must have shape ({m},3), one row per face, got {tuple(corners.shape)}")
            if int(corners.min()) < 0 or int(corners.max()) >= rows.shape[0]:
                raise ValueError(f"{cname} refers to rows outside [0, {rows.shape[0]}) of {name}")
        if self.texture is not None:
            t = self.texture
            if t.dim() != 3 or t.shape[2] != 3 or t.shape[0] == 0 or t.shape[1] == 0:
                raise ValueError(f"texture must have shape (Ht,Wt,3) with Ht, Wt >= 1, got {tuple(t.shape)}")
            if not bool(torch.isfinite(t).all()):
                raise ValueError("texture contains NaN or Inf")
        if self.vertex_colors is not None and tuple(self.vertex_colors.shape) != (n, 3):
            raise ValueError(f"vertex_colors must have shape ({n},3), got {tuple(self.vertex_colors.shape)}")

    def with_vertices(self, vertices: torch.Tensor) -> SurfaceMesh:
        """The same surface on moved vertices (a shape perturbation keeps the texture, UVs and colours; normals
        from the file are dropped for ``smooth`` shading to follow the new shape)."""
        mesh = Mesh(vertices.detach().to(torch.float32), self.mesh.faces, self.mesh.face_colors)
        return replace(self, mesh=mesh, normals=None, normal_faces=None)

    def with_texture(self, texture: torch.Tensor) -> SurfaceMesh:
        """The same mesh with another (Ht,Wt,3) texture (clamped to [0,1]); the per-face colours of ``mesh`` become
        the new texture's (as :func:`load_surface_mesh` computes them)."""
        texture = texture.detach().to(torch.float32).clamp(0.0, 1.0)
        if self.uvs is None:
            return replace(self, texture=texture)
        as_np = lambda t: None if t is None else t.detach().cpu().numpy()  # noqa: E731
        colors = _mean_face_colors(as_np(self.mesh.vertices), as_np(self.mesh.faces), as_np(self.uvs),
                                   as_np(self.uv_faces), as_np(texture), as_np(self.vertex_colors))
        mesh = Mesh(self.mesh.vertices, self.mesh.faces, torch.as_tensor(colors, dtype=torch.float32))
        return replace(self, mesh=mesh, texture=texture)

    def with_mesh(self, mesh: Mesh, rotation: Optional[np.ndarray] = None) -> SurfaceMesh:
        """The surface on another geometry of the same faces: texture, UVs and colours are kept; the file's normals
        are turned by ``rotation`` (a (3,3) rotation, the one that moved the vertices) or, without it, dropped
        (they do not follow an arbitrary move).

        Raises:
            ValueError: ``mesh`` has another number of faces or vertices, or ``rotation`` is not (3,3).
        """
        if mesh.num_faces != self.mesh.num_faces or mesh.num_vertices != self.mesh.num_vertices:
            raise ValueError(f"mesh must have {self.mesh.num_vertices} vertices and {self.mesh.num_faces} faces, got "
                             f"{mesh.num_vertices} and {mesh.num_faces}")
        if rotation is None:
            return replace(self, mesh=mesh, normals=None, normal_faces=None)
        if self.normals is None:
            return replace(self, mesh=mesh)
        r = np.asarray(rotation, dtype=np.float64)
        if r.shape != (3, 3):
            raise ValueError(f"rotation must have shape (3,3), got {r.shape}")
        turned = torch.as_tensor(self.normals.detach().double().cpu().numpy() @ r.T, dtype=torch.float32)
        return replace(self, mesh=mesh, normals=turned)

    def normalized(self, *, z_up: bool = False) -> tuple[SurfaceMesh, NormalizeTransform]:
        """The surface normalised into ``[-1, 1]`` (:func:`~meshadv.mesh.normalize.normalize_mesh`, a similarity),
        with its texture, UVs, vertex colours and normals (turned with the mesh), and the transform.

        Example:
            >>> unit, transform = load_surface_mesh("textured.obj").normalized()  # doctest: +SKIP
        """
        mesh, transform = normalize_mesh(self.mesh, z_up=z_up)
        return self.with_mesh(mesh, transform.rotation), transform

    def to_original(self, transform: NormalizeTransform) -> SurfaceMesh:
        """The surface mapped back into the frame ``transform`` normalised it from (vertices and normals); the
        inverse of :meth:`normalized`."""
        vertices = transform.to_original(self.mesh.vertices.detach().double()).float()
        mesh = Mesh(vertices, self.mesh.faces, self.mesh.face_colors)
        return self.with_mesh(mesh, transform.rotation.T)

    # The geometry, so that a SurfaceMesh stands where a Mesh does (an attack, an evaluation).
    @property
    def vertices(self) -> torch.Tensor:
        """(N,3) vertex positions of ``mesh``."""
        return self.mesh.vertices

    @property
    def faces(self) -> torch.Tensor:
        """(M,3) faces of ``mesh``."""
        return self.mesh.faces

    @property
    def face_colors(self) -> torch.Tensor:
        """(M,3) per-face colours of ``mesh`` (the texture's mean per face)."""
        return self.mesh.face_colors

    @property
    def num_vertices(self) -> int:
        """Number of vertices."""
        return self.mesh.num_vertices

    @property
    def num_faces(self) -> int:
        """Number of faces."""
        return self.mesh.num_faces


def _weld(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices with identical positions, in the order of their first occurrence: ``(welded (N,3), faces into
    it (M,3))``."""
    _, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return vertices[first[order]], rank[inverse.reshape(-1)][faces]


def _image_to_texture(image: Image.Image, path: Path, field: str) -> np.ndarray:
    """(Ht,Wt,3) float32 in [0,1] of a PIL image; errors name the file and field."""
    try:
        rgb = np.asarray(image.convert("RGB"), dtype=np.float32) / 255.0
    except (OSError, ValueError) as exc:
        raise MeshLoadError(f"{path}: {field}: the texture image cannot be decoded ({exc})") from exc
    if rgb.ndim != 3 or rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise MeshLoadError(f"{path}: {field}: the texture image has zero size {rgb.shape[:2]}")
    if max(rgb.shape[:2]) > MAX_TEXTURE_SIDE:
        raise MeshLoadError(f"{path}: {field}: texture of {rgb.shape[1]}x{rgb.shape[0]} exceeds {MAX_TEXTURE_SIDE}")
    return np.ascontiguousarray(rgb)


def _read_texture(file: Path, owner: Path, field: str) -> np.ndarray:
    """Read a texture image file referenced by ``owner``'s ``field``."""
    if not file.is_file():
        raise MeshLoadError(f"{owner}: {field}: the texture image {file} does not exist")
    try:
        with Image.open(file) as im:
            im.load()
            return _image_to_texture(im, owner, field)
    except (UnidentifiedImageError, OSError, SyntaxError) as exc:
        raise MeshLoadError(f"{owner}: {field}: the texture image {file} cannot be read ({exc})") from exc


def _obj_map_kd(path: Path) -> Optional[Path]:
    """The first ``map_Kd`` image of the materials an OBJ file references (None when there is none); errors for a
    missing MTL file or image name the OBJ file and the field."""
    text = path.read_text(errors="replace")
    for lib in re.findall(r"^\s*mtllib\s+(.+?)\s*$", text, flags=re.M):
        mtl = path.parent / lib
        if not mtl.is_file():
            raise MeshLoadError(f"{path}: mtllib: the material file {mtl} does not exist")
        for line in mtl.read_text(errors="replace").splitlines():
            parts = line.split()
            if parts and parts[0] == "map_Kd":
                if len(parts) < 2:
                    raise MeshLoadError(f"{mtl}: map_Kd: no image file named")
                return mtl.parent / parts[-1]
    return None


def _obj_has_normals(path: Path) -> bool:
    return re.search(rb"^\s*vn\s", path.read_bytes(), flags=re.M) is not None


def _check_obj_indices(path: Path) -> None:
    """Every ``f`` corner's ``vt`` / ``vn`` index within the counts of ``vt`` / ``vn`` lines, finite ``vt`` values and
    ``v`` colours (trimesh would silently drop the attribute or misread it)."""
    counts = {"v": 0, "vt": 0, "vn": 0}
    for lineno, raw in enumerate(path.read_text(errors="replace").splitlines(), 1):
        parts = raw.split()
        if not parts:
            continue
        if parts[0] in counts:
            counts[parts[0]] += 1
            if parts[0] == "v" and len(parts) > 4:  # `v x y z r g b`: trimesh would read NaN colours as 0
                try:
                    rgb = [float(x) for x in parts[4:7]]
                except ValueError as exc:
                    raise MeshLoadError(f"{path}: line {lineno}: vertex colors: not numbers: {raw.strip()!r}") from exc
                if not all(np.isfinite(rgb)):
                    raise MeshLoadError(f"{path}: line {lineno}: vertex colors: NaN or infinite colour "
                                        f"{raw.strip()!r}")
            if parts[0] == "vt":
                try:
                    values = [float(x) for x in parts[1:3]]
                except ValueError as exc:
                    raise MeshLoadError(f"{path}: line {lineno}: vt: not numbers: {raw.strip()!r}") from exc
                if len(values) < 2 or not all(np.isfinite(values)):
                    raise MeshLoadError(f"{path}: line {lineno}: vt: needs two finite values, got {raw.strip()!r}")
                if max(abs(x) for x in values) > MAX_TEXTURE_COORDINATE:
                    raise MeshLoadError(f"{path}: line {lineno}: vt: texture coordinates beyond "
                                        f"+-{MAX_TEXTURE_COORDINATE:g}, got {raw.strip()!r}")
        elif parts[0] == "f":
            for corner in parts[1:]:
                fields = corner.split("/")
                for k, name in ((1, "vt"), (2, "vn")):
                    if len(fields) > k and fields[k]:
                        i = int(fields[k])
                        if not (1 <= i <= counts[name] or -counts[name] <= i < 0):
                            raise MeshLoadError(
                                f"{path}: line {lineno}: f: {name} index {i} outside the {counts[name]} {name} "
                                "lines before it"
                            )


def _load_trimesh(path: Path) -> trimesh.Trimesh:
    """The file's one triangle mesh; a scene of one mesh is that mesh placed by its node's transform (with the
    file's normals, which trimesh's concatenation into one mesh would recompute), a scene of several their
    concatenation."""
    try:
        # Without maintain_order trimesh splits OBJ vertices per (v, vt, vn) corner, keeping UV seams.
        loaded = trimesh.load(str(path), process=False)
        if isinstance(loaded, trimesh.Scene):
            nodes = loaded.graph.nodes_geometry
            if len(nodes) == 1:
                transform, name = loaded.graph[nodes[0]]
                loaded = loaded.geometry[name]
                if not np.allclose(transform, np.eye(4)):
                    loaded = loaded.copy()
                    loaded.apply_transform(transform)
            else:
                loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for bad files
        raise MeshLoadError(f"{path}: cannot be read as a mesh ({type(exc).__name__}: {exc})") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshLoadError(f"{path}: holds no triangles")
    return loaded


def load_surface_mesh(path: PathLike) -> SurfaceMesh:
    """Load a mesh with its surface attributes.

    OBJ: ``vt`` UVs with the ``map_Kd`` image of its MTL, ``vn`` normals, ``v x y z r g b`` vertex colours (in
    ``[0, 1]``, as MeshLab and trimesh write them). GLB/glTF: the base-colour texture, UVs, normals and ``COLOR_0``
    vertex colours of the primitive (the reflectance is ``baseColorFactor`` x texture x ``COLOR_0``, as glTF defines
    it; the factor is folded into the texture, else into the vertex colours). PLY: vertex colours (and normals when
    present). Other formats: geometry only.

    Args:
        path: the mesh file.

    Returns:
        A :class:`SurfaceMesh` with welded geometry.

    Raises:
        MeshLoadError: an unreadable file, a missing or unreadable texture image or material file, a texture of zero
            size, NaN, non-numeric or out-of-range (beyond +-1e6) UVs, corner indices beyond the attribute counts, NaN
            vertex colours or a mismatched number of them (glTF: a ``COLOR_0`` of another count than ``POSITION``,
            of a type glTF does not allow, or outside ``[0, 1]``; a ``baseColorFactor`` outside ``[0, 1]``, or
            primitives of different factors beside a texture or colours); the message names the file and the field.

    Example:
        >>> sm = load_surface_mesh("textured.obj")  # doctest: +SKIP
        >>> sm.texture.shape, sm.uv_faces.shape  # doctest: +SKIP
    """
    path = Path(path)
    if not path.is_file():
        raise MeshLoadError(f"{path}: no such file")
    ext = path.suffix.lower()
    texture_file = None
    gltf = _gltf.gltf_json(path) if ext in (".glb", ".gltf") else None
    if gltf is not None:
        _gltf.check_color_accessors(gltf, path)
    if ext == ".obj":
        _check_obj_indices(path)
        texture_file = _obj_map_kd(path)
        if texture_file is not None:
            texture = _read_texture(texture_file, path, "map_Kd")
    tm = _load_trimesh(path)
    raw_v = np.asarray(tm.vertices, dtype=np.float64)
    raw_f = np.asarray(tm.faces, dtype=np.int64)
    if not np.isfinite(raw_v).all():
        raise MeshLoadError(f"{path}: vertices: NaN or infinite positions")
    verts, faces = _weld(raw_v, raw_f)
    uvs = uv_faces = tex = None
    visual = tm.visual
    if isinstance(visual, trimesh.visual.texture.TextureVisuals) and visual.uv is not None and len(visual.uv):
        uv = np.asarray(visual.uv, dtype=np.float64)
        if uv.shape != (len(raw_v), 2):
            raise MeshLoadError(f"{path}: uv: {uv.shape[0]} texture coordinates for {len(raw_v)} vertices")
        if not np.isfinite(uv).all():
            raise MeshLoadError(f"{path}: uv: NaN or infinite texture coordinates")
        if np.abs(uv).max() > MAX_TEXTURE_COORDINATE:
            raise MeshLoadError(f"{path}: uv: texture coordinates beyond +-{MAX_TEXTURE_COORDINATE:g}")
        if ext == ".obj" and texture_file is not None:
            tex = texture
        else:
            material = visual.material
            image = getattr(material, "baseColorTexture", None) or getattr(material, "image", None)
            if image is not None:
                tex = _image_to_texture(image, path, "baseColorTexture")
        if tex is not None:
            uvs, uv_faces = uv, raw_f
    colors = rgb = None
    if isinstance(visual, trimesh.visual.color.ColorVisuals) and visual.kind == "vertex":
        rgb = np.asarray(visual.vertex_colors)[:, :3].astype(np.float64) / 255.0
    elif "color" in tm.vertex_attributes:  # an OBJ's `v x y z r g b` beside a texture, in [0, 1]
        rgb = np.asarray(tm.vertex_attributes["color"], dtype=np.float64)
        rgb = rgb.reshape(len(rgb), -1)[:, :3]
    elif isinstance(visual, trimesh.visual.texture.TextureVisuals) and "color" in visual.vertex_attributes:
        rgb = _gltf.color_values(visual.vertex_attributes["color"], path)  # glTF COLOR_0 beside a material
    if gltf is not None and (tex is not None or rgb is not None):  # glTF: factor x texture x COLOR_0
        factor = _gltf.base_color_factor(gltf, path)
        if tex is not None:
            tex = tex * factor
        else:
            rgb = rgb * factor
    if rgb is not None:
        if rgb.shape[0] != len(raw_v):
            raise MeshLoadError(f"{path}: vertex colors: {rgb.shape[0]} colours for {len(raw_v)} vertices")
        if not np.isfinite(rgb).all():
            raise MeshLoadError(f"{path}: vertex colors: NaN or infinite colours")
        colors = np.zeros((len(verts), 3))
        colors[faces.reshape(-1)] = rgb[raw_f.reshape(-1)]
    # the file's normals when trimesh kept them (else smooth shading with the vertices' own normals)
    has_normals = "vertex_normals" in tm._cache or (ext == ".obj" and _obj_has_normals(path))
    normals = normal_faces = None
    if "vertex_normals" in tm._cache:
        vn = np.asarray(tm.vertex_normals, dtype=np.float64)
        if vn.shape == raw_v.shape and np.isfinite(vn).all():
            normals, normal_faces = vn, raw_f
    face_colors = _mean_face_colors(verts, faces, uvs, uv_faces, tex, colors)
    mesh = Mesh.from_numpy(verts.astype(np.float32), faces, face_colors.astype(np.float32))
    as_t = lambda a, dt=torch.float32: None if a is None else torch.tensor(np.asarray(a), dtype=dt)  # noqa: E731
    return SurfaceMesh(
        mesh=mesh,
        uvs=as_t(uvs),
        uv_faces=as_t(uv_faces, torch.long),
        texture=as_t(tex),
        vertex_colors=as_t(colors),
        normals=as_t(normals),
        normal_faces=as_t(normal_faces, torch.long),
        shading="smooth" if has_normals else "flat",
    )


def _mean_face_colors(
    verts: np.ndarray,
    faces: np.ndarray,
    uvs: Optional[np.ndarray],
    uv_faces: Optional[np.ndarray],
    texture: Optional[np.ndarray],
    colors: Optional[np.ndarray],
) -> np.ndarray:
    """(M,3) a per-face reflectance: the texture at the UV centroid (nearest texel, repeat) times the mean vertex
    colour; 0.7 grey without either."""
    out = np.full((len(faces), 3), 0.7)
    if texture is not None and uvs is not None and uv_faces is not None:
        c = uvs[uv_faces].mean(axis=1)
        h, w = texture.shape[:2]
        cols = np.floor(c[:, 0] * w).astype(np.int64) % w
        rows = np.floor((1.0 - c[:, 1]) * h).astype(np.int64) % h
        out = texture[rows, cols].astype(np.float64)
    if colors is not None:
        out = out * colors[faces].mean(axis=1) if texture is not None else colors[faces].mean(axis=1)
    return out


def _png_bytes(texture: torch.Tensor) -> bytes:
    """8-bit RGB PNG of a (Ht,Wt,3) texture in [0,1]."""
    arr = (texture.detach().clamp(0, 1).cpu().numpy() * 255.0 + 0.5).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(arr, "RGB").save(buf, format="PNG")
    return buf.getvalue()


def save_surface_mesh(surface: SurfaceMesh, path: PathLike) -> list[Path]:
    """Save a :class:`SurfaceMesh` (written atomically, file by file).

    ``.obj``: the OBJ with ``vt`` / ``vn`` and ``f v/vt/vn``, vertex colours as ``v x y z r g b`` (in ``[0, 1]``,
    which MeshLab and trimesh read), an MTL next to it naming the texture, and the texture as an 8-bit PNG
    (``<stem>_texture.png``, the print-ready image). ``.glb``: one binary glTF with the texture embedded and the vertex
    colours as 8-bit ``COLOR_0`` (vertices split where UVs or normals differ, as glTF needs). ``.ply``: the
    welded geometry with 8-bit vertex colours (the per-face colours of ``mesh`` when it has none) and no texture.

    Args:
        surface: the mesh.
        path: ``.obj``, ``.glb`` or ``.ply`` file to write.

    Returns:
        The files written.

    Raises:
        ValueError: another extension.

    Example:
        >>> save_surface_mesh(load_surface_mesh("painted.ply"), "painted.obj")  # doctest: +SKIP
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext == ".obj":
        return _save_obj(surface, path)
    if ext == ".glb":
        return _save_glb(surface, path)
    if ext == ".ply":
        return _save_ply(surface, path)
    raise ValueError(f"path: save_surface_mesh writes .obj, .glb or .ply, got {path.suffix!r}")


def save_any_mesh(mesh: Union[Mesh, SurfaceMesh], path: PathLike) -> list[Path]:
    """Save a per-face :class:`Mesh` (:func:`~meshadv.mesh.io.save_mesh`) or a :class:`SurfaceMesh`
    (:func:`save_surface_mesh`; its ``.ply`` per face when it has no vertex colours, as a PLY cannot hold a texture).

    Raises:
        ValueError: an extension the writer does not take.
    """
    from meshadv.mesh.io import save_mesh

    path = Path(path)
    if not isinstance(mesh, SurfaceMesh):
        return save_mesh(mesh.detach(), path)
    if path.suffix.lower() == ".ply" and mesh.vertex_colors is None:
        return save_mesh(mesh.mesh.detach(), path)
    return save_surface_mesh(mesh, path)


def _save_obj(surface: SurfaceMesh, path: Path) -> list[Path]:
    verts = surface.mesh.vertices.detach().cpu().numpy()
    faces = surface.mesh.faces.cpu().numpy() + 1
    lines = [f"# written by meshadv: {len(verts)} vertices, {len(faces)} faces"]
    written: list[Path] = []
    if surface.texture is not None:
        mtl, png = path.with_suffix(".mtl"), path.with_name(path.stem + "_texture.png")
        write_bytes_atomic(png, _png_bytes(surface.texture))
        write_bytes_atomic(mtl, f"newmtl surface\nKd 1 1 1\nmap_Kd {png.name}\n".encode())
        written += [png, mtl]
        lines += [f"mtllib {mtl.name}", "usemtl surface"]
    if surface.vertex_colors is None:
        lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in verts]
    else:
        rgb = surface.vertex_colors.detach().clamp(0, 1).cpu().numpy()
        lines += [f"v {x:.9g} {y:.9g} {z:.9g} {r:.6g} {g:.6g} {b:.6g}" for (x, y, z), (r, g, b) in zip(verts, rgb)]
    corner = [faces.astype(str)]
    if surface.uvs is not None:
        lines += [f"vt {u:.9g} {v:.9g}" for u, v in surface.uvs.detach().cpu().numpy()]
        corner.append((surface.uv_faces.cpu().numpy() + 1).astype(str))
    if surface.normals is not None:
        lines += [f"vn {x:.9g} {y:.9g} {z:.9g}" for x, y, z in surface.normals.detach().cpu().numpy()]
        if surface.uvs is None:
            corner.append(np.full(faces.shape, "", dtype=object))
        corner.append((surface.normal_faces.cpu().numpy() + 1).astype(str))
    for f in range(len(faces)):
        lines.append("f " + " ".join("/".join(str(c[f, k]) for c in corner) for k in range(3)))
    write_bytes_atomic(path, ("\n".join(lines) + "\n").encode())
    return [*written, path]


def _save_glb(surface: SurfaceMesh, path: Path) -> list[Path]:
    faces = surface.mesh.faces.cpu().numpy()
    keys = [faces]
    if surface.uvs is not None:
        keys.append(surface.uv_faces.cpu().numpy())
    if surface.normals is not None:
        keys.append(surface.normal_faces.cpu().numpy())
    corner_keys = np.stack([k.reshape(-1) for k in keys], axis=1)
    unique, inverse = np.unique(corner_keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    verts = surface.mesh.vertices.detach().cpu().numpy()[unique[:, 0]]
    kwargs: dict = {}
    if surface.normals is not None:
        kwargs["vertex_normals"] = surface.normals.detach().cpu().numpy()[unique[:, -1]]
    if surface.texture is not None:
        uv = surface.uvs.detach().cpu().numpy()[unique[:, 1]]
        image = Image.open(io.BytesIO(_png_bytes(surface.texture)))
        material = trimesh.visual.material.PBRMaterial(baseColorTexture=image, metallicFactor=0.0, roughnessFactor=1.0)
        kwargs["visual"] = trimesh.visual.TextureVisuals(uv=uv, material=material)
        if surface.vertex_colors is not None:  # written as COLOR_0, which glTF multiplies with the texture
            rgb = surface.vertex_colors.detach().clamp(0, 1).cpu().numpy()[unique[:, 0]]
            rgba = np.concatenate([(rgb * 255 + 0.5).astype(np.uint8), np.full((len(rgb), 1), 255, np.uint8)], 1)
            kwargs["visual"].vertex_attributes["color"] = rgba
    elif surface.vertex_colors is not None:
        rgb = surface.vertex_colors.detach().clamp(0, 1).cpu().numpy()[unique[:, 0]]
        kwargs["vertex_colors"] = (rgb * 255 + 0.5).astype(np.uint8)
    tm = trimesh.Trimesh(vertices=verts, faces=inverse.reshape(-1, 3), process=False, **kwargs)
    write_bytes_atomic(path, tm.export(file_type="glb"))
    return [path]


def _save_ply(surface: SurfaceMesh, path: Path) -> list[Path]:
    verts = surface.mesh.vertices.detach().cpu().numpy()
    faces = surface.mesh.faces.cpu().numpy()
    if surface.vertex_colors is not None:
        rgb = surface.vertex_colors.detach().clamp(0, 1).cpu().numpy()
        tm = trimesh.Trimesh(vertices=verts, faces=faces, vertex_colors=(rgb * 255 + 0.5).astype(np.uint8),
                             process=False)
    else:
        rgb = surface.mesh.face_colors.detach().clamp(0, 1).cpu().numpy()
        tm = trimesh.Trimesh(vertices=verts, faces=faces, face_colors=(rgb * 255 + 0.5).astype(np.uint8),
                             process=False)
    write_bytes_atomic(path, tm.export(file_type="ply"))
    return [path]
