"""Surface meshes (meshadv.mesh.surface_mesh): a textured mesh generated here round-trips through OBJ + MTL + PNG and
GLB with its UV seam, texture and render; a texture optimised through render_surface survives save and load; PLY
vertex colours load; bad files are errors naming the file and field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from seamed_grid import seamed_grid

from meshadv.mesh import MeshLoadError, face_adjacency, vertex_edges
from meshadv.mesh.structure import Mesh
from meshadv.mesh.surface_mesh import SurfaceMesh, load_surface_mesh, save_surface_mesh
from meshadv.render import Camera, Lights, native_available, render_surface


def _textured_grid(n: int = 6) -> SurfaceMesh:
    """An n x n grid with heights, a 16 x 20 texture, and a UV seam down the middle (the right half reads shifted
    copies of its UVs)."""
    g = torch.Generator().manual_seed(0)
    verts, faces_t, uvs, uv_faces = seamed_grid(n, g, 0.2)
    # 8-bit exact texels, so that a PNG round trip is exact.
    texture = torch.randint(0, 256, (16, 20, 3), generator=g).float() / 255.0
    return SurfaceMesh(Mesh(verts, faces_t, torch.full((faces_t.shape[0], 3), 0.5)), uvs, uv_faces, texture)


def _corner_uvs(sm: SurfaceMesh) -> dict:
    """Each face corner's (position, uv), keyed by position: independent of vertex and UV row order."""
    pos = sm.mesh.vertices[sm.mesh.faces].reshape(-1, 3).numpy().round(5)
    uv = sm.uvs[sm.uv_faces].reshape(-1, 2).numpy().round(5)
    return sorted(map(tuple, np.concatenate([pos, uv], 1).tolist()))


@pytest.mark.parametrize("ext", [".obj", ".glb"])
def test_a_textured_mesh_round_trips_with_its_seam_and_texture(tmp_path: Path, ext: str) -> None:
    sm = _textured_grid()
    written = save_surface_mesh(sm, tmp_path / f"grid{ext}")
    if ext == ".obj":
        assert {p.name for p in written} == {"grid.obj", "grid.mtl", "grid_texture.png"}
    back = load_surface_mesh(tmp_path / f"grid{ext}")
    # Welded geometry: one vertex per position although the seam splits UVs (the Laplacian sees one surface).
    assert back.mesh.num_vertices == sm.mesh.num_vertices
    assert back.mesh.num_faces == sm.mesh.num_faces
    # A 6 x 6 grid: 85 edges, 65 of them between two faces, also across the UV seam.
    assert vertex_edges(back.mesh.faces).shape[0] == 85
    assert face_adjacency(back.mesh.faces).shape[0] == 65
    assert back.uvs[back.uv_faces].reshape(-1, 2).unique(dim=0).shape[0] > sm.mesh.num_vertices  # seam UV rows
    assert _corner_uvs(back) == _corner_uvs(sm)
    torch.testing.assert_close(back.texture, sm.texture, atol=0.6 / 255, rtol=0)


@pytest.mark.skipif(not native_available(), reason="the native module meshadv._raster is not built")
def test_a_texture_optimised_through_the_renderer_is_saved_and_rendered_the_same(tmp_path: Path) -> None:
    sm = _textured_grid()
    camera, lights = Camera.spherical(3.0, azimuth=10.0, elevation=20.0), Lights.default()
    target = torch.zeros(1, 3, 32, 32)
    target[..., :16] = 1.0  # left half white, right half black
    texture = sm.texture.clone().requires_grad_(True)
    opt = torch.optim.Adam([texture], lr=0.05)

    def draw(s: SurfaceMesh, tex: torch.Tensor) -> torch.Tensor:
        out = render_surface(
            s.mesh.vertices,
            s.mesh.faces,
            camera,
            lights,
            32,
            texture=tex,
            uvs=s.uvs,
            uv_faces=s.uv_faces,
            shading="flat",
        )
        return out.image * out.alpha

    first = float(((draw(sm, texture.detach()) - target) ** 2).mean())
    for _ in range(30):
        opt.zero_grad()
        loss = ((draw(sm, texture) - target) ** 2).mean()
        loss.backward()
        opt.step()
        with torch.no_grad():
            texture.clamp_(0, 1)
    assert float(loss.detach()) < 0.7 * first
    attacked = sm.with_texture(texture)
    save_surface_mesh(attacked, tmp_path / "attacked.obj")
    back = load_surface_mesh(tmp_path / "attacked.obj")
    with torch.no_grad():
        a, b = draw(attacked, attacked.texture), draw(back, back.texture)
    assert float((a - b).abs().max()) < 3.0 / 255  # 8-bit PNG quantisation only


def test_ply_vertex_colours_load_per_welded_vertex(tmp_path: Path) -> None:
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    colors = np.array([[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255], [255, 255, 255, 255]], dtype=np.uint8)
    trimesh.Trimesh(verts, faces, vertex_colors=colors, process=False).export(tmp_path / "c.ply")
    sm = load_surface_mesh(tmp_path / "c.ply")
    assert sm.texture is None and sm.vertex_colors is not None
    for k in range(4):
        row = int(np.flatnonzero((sm.mesh.vertices.numpy() == verts[k]).all(1))[0])
        np.testing.assert_allclose(sm.vertex_colors[row].numpy(), colors[k, :3] / 255.0, atol=1e-6)


def _write_obj(folder: Path, body: str, mtl: str | None = None, image: bytes | None = None) -> Path:
    obj = folder / "m.obj"
    obj.write_text(("mtllib m.mtl\nusemtl a\n" if mtl is not None else "") + body)
    if mtl is not None:
        (folder / "m.mtl").write_text(mtl)
    if image is not None:
        (folder / "tex.png").write_bytes(image)
    return obj


_QUAD = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"


@pytest.mark.parametrize(
    ("body", "mtl", "image", "message"),
    [
        (_QUAD, "newmtl a\nmap_Kd tex.png\n", None, r"map_Kd: the texture image .*tex.png does not exist"),
        (_QUAD, "newmtl a\nmap_Kd tex.png\n", b"not a png", r"map_Kd: the texture image .*cannot be read"),
        (_QUAD.replace("vt 1 0", "vt nan 0"), None, None, r"vt: needs two finite values"),
        (_QUAD.replace("3/3", "3/7"), None, None, r"f: vt index 7 outside the 3 vt lines"),
        (_QUAD.replace("vt 1 0", "vt 1e30 0"), None, None, r"line 5: vt: texture coordinates beyond \+-1e\+06"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1//4 2//1 3//1\nvn 0 0 1\n", None, None, r"f: vn index 4"),
    ],
)
def test_bad_textured_files_are_errors_naming_the_file_and_field(
    tmp_path: Path, body: str, mtl: str | None, image: bytes | None, message: str
) -> None:
    obj = _write_obj(tmp_path, body, mtl, image)
    with pytest.raises(MeshLoadError, match=message) as err:
        load_surface_mesh(obj)
    assert str(obj) in str(err.value) or "m.mtl" in str(err.value)


def test_a_zero_size_texture_or_mismatched_attributes_are_errors_naming_the_field() -> None:
    sm = _textured_grid(3)
    with pytest.raises(ValueError, match="texture must have shape"):
        SurfaceMesh(sm.mesh, sm.uvs, sm.uv_faces, torch.zeros(0, 4, 3))
    with pytest.raises(ValueError, match="uv_faces must have shape"):
        SurfaceMesh(sm.mesh, sm.uvs, sm.uv_faces[:-1], sm.texture)
    with pytest.raises(ValueError, match="uv_faces refers to rows"):
        SurfaceMesh(sm.mesh, sm.uvs[:3], sm.uv_faces, sm.texture)
    with pytest.raises(ValueError, match="uvs contains NaN"):
        SurfaceMesh(sm.mesh, torch.full_like(sm.uvs, float("nan")), sm.uv_faces, sm.texture)
    with pytest.raises(ValueError, match="uvs must lie within"):
        SurfaceMesh(sm.mesh, torch.full_like(sm.uvs, 3e38), sm.uv_faces, sm.texture)
    with pytest.raises(ValueError, match="vertex_colors must have shape"):
        SurfaceMesh(sm.mesh, vertex_colors=torch.zeros(2, 3))


@pytest.mark.skipif(not native_available(), reason="the native module meshadv._raster is not built")
def test_meshadv_render_draws_a_textured_file_with_its_texture(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from meshadv.cli import app
    from PIL import Image

    sm = _textured_grid()
    black = sm.with_texture(torch.zeros_like(sm.texture))
    white = sm.with_texture(torch.ones_like(sm.texture))
    means = {}
    for name, surface in (("black", black), ("white", white)):
        save_surface_mesh(surface, tmp_path / f"{name}.obj")
        for shading in ("flat", "smooth"):
            out = tmp_path / f"{name}_{shading}"
            result = CliRunner().invoke(
                app,
                [
                    "render",
                    str(tmp_path / f"{name}.obj"),
                    "--views",
                    "1",
                    "--azimuths",
                    "0:0",
                    "--elevation",
                    "60",
                    "--image-size",
                    "32",
                    "--shading",
                    shading,
                    "--background",
                    "0.5,0.5,0.5",
                    "-o",
                    str(out),
                ],
            )
            assert result.exit_code == 0, result.output
            means[name, shading] = float(np.asarray(Image.open(out / "view_0.png"), dtype=np.float64).mean() / 255)
    # The texture decides the colour (a per-face grey would give both files the same image).
    assert means["black", "flat"] < 0.45 < 0.55 < means["white", "flat"]
    assert means["black", "smooth"] < 0.45 < 0.55 < means["white", "smooth"]
    result = CliRunner().invoke(
        app, ["render", str(tmp_path / "black.obj"), "--shading", "phong", "-o", str(tmp_path / "x")]
    )
    assert result.exit_code == 2 and "--shading" in result.output


def test_normalising_keeps_the_texture_colours_and_turns_the_normals_with_the_mesh() -> None:
    from meshadv.mesh.normalize import Z_UP_TO_Y_UP
    from meshadv.render import vertex_normals

    sm = _textured_grid()
    verts = sm.mesh.vertices * 3.0 + torch.tensor([1.0, -2.0, 0.5])
    normals = vertex_normals(verts, sm.mesh.faces)[0]  # the area-weighted normals of the file's vertices
    colors = torch.rand(sm.mesh.num_vertices, 3, generator=torch.Generator().manual_seed(1))
    file_mesh = SurfaceMesh(Mesh(verts, sm.mesh.faces, sm.mesh.face_colors), sm.uvs, sm.uv_faces, sm.texture,
                            colors, normals, sm.mesh.faces, "smooth")
    unit, transform = file_mesh.normalized(z_up=True)
    assert float(unit.vertices.abs().max()) == pytest.approx(1.0)
    for name in ("uvs", "uv_faces", "texture", "vertex_colors", "normal_faces"):
        assert torch.equal(getattr(unit, name), getattr(file_mesh, name)), name
    assert unit.shading == "smooth"
    # turned with the mesh: still the area-weighted normals of the (rotated) vertices, not the file's directions
    torch.testing.assert_close(unit.normals, vertex_normals(unit.vertices, unit.faces)[0], atol=1e-5, rtol=0)
    torch.testing.assert_close(unit.normals, normals @ torch.as_tensor(Z_UP_TO_Y_UP, dtype=torch.float32).T)
    assert float((unit.normals - normals).abs().max()) > 0.5
    back = unit.to_original(transform)
    torch.testing.assert_close(back.vertices, verts, atol=1e-5, rtol=0)
    torch.testing.assert_close(back.normals, normals, atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="rotation must have shape"):
        unit.with_mesh(unit.mesh, np.eye(2))
    with pytest.raises(ValueError, match="mesh must have"):
        unit.with_mesh(Mesh(verts[:3], torch.tensor([[0, 1, 2]]), sm.mesh.face_colors[:1]))


def test_obj_vertex_colours_beside_a_texture_round_trip(tmp_path: Path) -> None:
    sm = _textured_grid()
    colors = torch.randint(0, 256, (sm.mesh.num_vertices, 3), generator=torch.Generator().manual_seed(2)) / 255.0
    painted = SurfaceMesh(sm.mesh, sm.uvs, sm.uv_faces, sm.texture, colors.float())
    save_surface_mesh(painted, tmp_path / "p.obj")
    back = load_surface_mesh(tmp_path / "p.obj")
    assert back.texture is not None and back.vertex_colors is not None
    torch.testing.assert_close(back.vertex_colors, painted.vertex_colors, atol=1e-6, rtol=0)
    # the per-face colours are the texture's times the vertex colours, as the loader computes them
    torch.testing.assert_close(back.face_colors, painted.with_texture(painted.texture).face_colors, atol=1e-5,
                               rtol=0)
    save_surface_mesh(painted, tmp_path / "p.ply")
    torch.testing.assert_close(load_surface_mesh(tmp_path / "p.ply").vertex_colors, painted.vertex_colors,
                               atol=0.6 / 255, rtol=0)
    with pytest.raises(ValueError, match=r"\.obj, \.glb or \.ply"):
        save_surface_mesh(painted, tmp_path / "p.stl")


def test_nan_obj_vertex_colours_are_an_error_naming_the_file_and_field(tmp_path: Path) -> None:
    obj = _write_obj(tmp_path, "v 0 0 0 1 0 0\nv 1 0 0 nan 1 0\nv 0 1 0 0 0 1\nf 1 2 3\n")
    with pytest.raises(MeshLoadError, match=r"m\.obj: line 2: vertex colors: NaN"):
        load_surface_mesh(obj)


@pytest.mark.skipif(not native_available(), reason="the native module meshadv._raster is not built")
def test_meshadv_render_shades_smooth_with_the_files_normals_turned_with_the_mesh(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from PIL import Image
    from meshadv.cli import app
    from meshadv.commands._common import make_views

    sm = _textured_grid()
    tilted = torch.nn.functional.normalize(torch.tensor([[0.9, 0.3, 0.3]]), dim=1).expand(sm.mesh.num_vertices, 3)
    save_surface_mesh(SurfaceMesh(sm.mesh, sm.uvs, sm.uv_faces, sm.texture, normals=tilted.contiguous(),
                                  normal_faces=sm.mesh.faces), tmp_path / "n.obj")
    run = CliRunner().invoke(app, ["render", str(tmp_path / "n.obj"), "--z-up", "--views", "1", "--azimuths", "20:20",
                                   "--elevation", "50", "--image-size", "32", "-o", str(tmp_path / "r")])
    assert run.exit_code == 0, run.output
    image = torch.as_tensor(np.asarray(Image.open(tmp_path / "r" / "view_0.png"), dtype=np.float32) / 255)
    views = make_views(1, (20.0, 20.0), 50.0)
    unit, _ = load_surface_mesh(tmp_path / "n.obj").normalized(z_up=True)

    def draw(normals: torch.Tensor | None, normal_faces: torch.Tensor | None) -> torch.Tensor:
        out = render_surface(unit.vertices, unit.faces, views.camera, views.lights, 32, texture=unit.texture,
                             uvs=unit.uvs, uv_faces=unit.uv_faces, normals=normals, normal_faces=normal_faces,
                             shading="smooth")
        return out.image[0].permute(1, 2, 0)

    torch.testing.assert_close(image, draw(unit.normals, unit.normal_faces), atol=1 / 255, rtol=0)
    drawn = (image < 0.99).any(-1)
    # the file's directions unturned, or the mesh's own normals, draw another image
    for normals, normal_faces in ((tilted.contiguous(), unit.faces), (None, None)):
        assert float((image - draw(normals, normal_faces)).abs()[drawn].mean()) > 0.03


@pytest.mark.parametrize("ext", [".obj", ".glb"])
def test_the_files_own_normals_load_as_written(tmp_path: Path, ext: str) -> None:
    sm = _textured_grid()
    tilted = torch.nn.functional.normalize(torch.rand(sm.mesh.num_vertices, 3) + 0.1, dim=1)
    save_surface_mesh(SurfaceMesh(sm.mesh, sm.uvs, sm.uv_faces, sm.texture, normals=tilted,
                                  normal_faces=sm.mesh.faces), tmp_path / f"n{ext}")
    back = load_surface_mesh(tmp_path / f"n{ext}")
    assert back.shading == "smooth"
    # per face corner, keyed by position: the normals written, not ones trimesh recomputed from the faces
    expect = {tuple(p): n for p, n in zip(sm.mesh.vertices.numpy().round(5).tolist(), tilted.numpy())}
    corners = back.mesh.vertices[back.mesh.faces].reshape(-1, 3).numpy().round(5)
    got = back.normals[back.normal_faces].reshape(-1, 3).numpy()
    np.testing.assert_allclose(got, np.stack([expect[tuple(p)] for p in corners.tolist()]), atol=1e-5)
