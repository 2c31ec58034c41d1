"""Tests of mesh loading (every format, clean-up report, clear errors) and of saving with exact round trips."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pymeshlab
import pytest
import torch
import trimesh

from meshadv.mesh import (
    Mesh,
    MeshLoadError,
    Pascal3DCatalog,
    builtin_mesh,
    load_mesh,
    load_mesh_with_report,
    save_mesh,
)
from meshadv.mesh.cleanup import degenerate_face_mask


def _shared_mesh_files(root: Path) -> "list[Path]":
    catalog = Pascal3DCatalog(root / "pascal3d")
    files = [path for cls in catalog.classes() for path in catalog.models(cls)]
    return files + [root / "bunny" / "stanford-bunny.ply"]


def test_load_every_shared_mesh(shared_data: Path) -> None:
    files = _shared_mesh_files(shared_data)
    assert len(files) == 51
    for path in files:
        mesh, report = load_mesh_with_report(path)
        v, f, c = mesh.numpy()
        assert np.isfinite(v).all(), path
        assert mesh.num_faces > 0 and f.min() >= 0 and f.max() < mesh.num_vertices, path
        assert not degenerate_face_mask(v, f).any(), path
        assert len(np.unique(f)) == mesh.num_vertices, f"{path}: unreferenced vertices left"
        assert len(np.unique(v, axis=0)) == mesh.num_vertices, f"{path}: duplicate vertices left"
        assert report.input_faces - report.degenerate_faces - report.duplicate_faces == mesh.num_faces, path
        assert len(np.unique(np.sort(f, axis=1), axis=0)) == mesh.num_faces, f"{path}: duplicate faces left"
        assert report.input_vertices - report.merged_vertices - report.unreferenced_vertices == mesh.num_vertices
        np.testing.assert_allclose(c, 0.7, atol=1e-6)
        assert report.color_source == "default" and report.file_format == "ply"


def test_shared_mesh_matches_trimesh_geometry(shared_data: Path) -> None:
    path = shared_data / "pascal3d" / "chair" / "01.ply"
    mesh = load_mesh(path)
    raw = trimesh.load(str(path), process=True)  # trimesh's own clean-up, for comparison
    raw.update_faces(raw.unique_faces() & raw.nondegenerate_faces())
    # Same surface: equal bounds and equal total area once duplicate and degenerate faces are gone.
    np.testing.assert_allclose(mesh.bounds().numpy(), raw.bounds, rtol=1e-6)
    assert float(mesh.face_areas().sum()) == pytest.approx(raw.area, rel=1e-5)


def _colored_mesh() -> Mesh:
    base = builtin_mesh("torus")
    rng = np.random.default_rng(3)
    verts = base.vertices + torch.as_tensor(rng.normal(scale=0.01, size=(base.num_vertices, 3)), dtype=torch.float32)
    colors = torch.as_tensor(rng.random((base.num_faces, 3)), dtype=torch.float32)
    colors[:10] = colors[0]  # repeated colours share a material
    return Mesh(verts, base.faces, colors)


@pytest.mark.parametrize("suffix", [".ply", ".obj"])
def test_save_and_reload_is_exact(tmp_path: Path, suffix: str) -> None:
    mesh = _colored_mesh()
    written = save_mesh(mesh, tmp_path / "sub" / f"adv{suffix}")
    assert written[0] == tmp_path / "sub" / f"adv{suffix}" and all(p.is_file() for p in written)
    again, report = load_mesh_with_report(written[0])
    assert not report.changed
    assert torch.equal(again.vertices, mesh.vertices)
    assert torch.equal(again.faces, mesh.faces)
    assert torch.equal(again.face_colors, mesh.face_colors)
    assert not list((tmp_path / "sub").glob("*.tmp"))


def test_saved_ply_is_standard(tmp_path: Path) -> None:
    mesh = _colored_mesh()
    path = save_mesh(mesh, tmp_path / "adv.ply")[0]
    plain = trimesh.load(str(path), process=False)
    np.testing.assert_array_equal(plain.faces, mesh.faces.numpy())
    expected = np.round(mesh.face_colors.numpy() * 255).astype(np.uint8)
    np.testing.assert_array_equal(plain.visual.face_colors[:, :3], expected)
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(path))
    assert ms.current_mesh().face_number() == mesh.num_faces
    assert ms.current_mesh().has_face_color()


def test_saved_obj_has_one_material_per_colour(tmp_path: Path) -> None:
    mesh = _colored_mesh()
    obj_path, mtl_path = save_mesh(mesh, tmp_path / "adv.obj")
    assert mtl_path == tmp_path / "adv.mtl"
    n_colors = len(np.unique(mesh.face_colors.numpy(), axis=0))
    assert mtl_path.read_text().count("newmtl") == n_colors
    scene = trimesh.load(str(obj_path))  # trimesh's own reader (groups faces by material)
    total = sum(len(g.faces) for g in scene.geometry.values()) if isinstance(scene, trimesh.Scene) else len(scene.faces)
    assert total == mesh.num_faces


def test_save_rejects_unknown_extension(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="path must end"):
        save_mesh(builtin_mesh("cube"), tmp_path / "x.stl")


def test_save_clamps_obj_colours(tmp_path: Path) -> None:
    cube = builtin_mesh("cube")
    colors = torch.linspace(-0.5, 1.5, cube.num_faces * 3).reshape(-1, 3)
    again = load_mesh(save_mesh(cube.with_face_colors(colors), tmp_path / "c.obj")[0])
    assert torch.equal(again.face_colors, colors.clamp(0, 1))


def test_load_stl_merges_vertices(tmp_path: Path) -> None:
    path = tmp_path / "box.stl"
    trimesh.creation.box(extents=(1, 2, 3)).export(str(path))
    mesh, report = load_mesh_with_report(path)
    assert (mesh.num_vertices, mesh.num_faces) == (8, 12)
    assert report.merged_vertices == 28 and report.input_vertices == 36
    np.testing.assert_allclose(mesh.bounds().numpy(), [[-0.5, -1, -1.5], [0.5, 1, 1.5]])


def test_load_off_triangulates_polygons(tmp_path: Path) -> None:
    path = tmp_path / "quad.off"
    path.write_text("OFF\n5 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n7 7 7\n4 0 1 2 3\n")
    mesh, report = load_mesh_with_report(path)
    assert mesh.num_faces == 2 and mesh.num_vertices == 4
    assert report.unreferenced_vertices == 1
    assert float(mesh.face_areas().sum()) == pytest.approx(1.0)


def test_load_glb_scene_flattens_with_transforms(tmp_path: Path) -> None:
    red = trimesh.creation.box(extents=(1, 1, 1))
    red.visual.face_colors = [255, 0, 0, 255]
    blue = trimesh.creation.box(extents=(1, 1, 1))
    blue.visual.face_colors = [0, 0, 255, 255]
    scene = trimesh.Scene()
    shift = np.eye(4)
    shift[:3, 3] = [3.0, 0.0, 0.0]
    scene.add_geometry(red, node_name="red", geom_name="red")
    scene.add_geometry(blue, node_name="blue", geom_name="blue", transform=shift)
    path = tmp_path / "scene.glb"
    scene.export(str(path))
    mesh, report = load_mesh_with_report(path)
    assert report.num_geometries == 2 and mesh.num_faces == 24 and mesh.num_vertices == 16
    np.testing.assert_allclose(mesh.bounds().numpy(), [[-0.5, -0.5, -0.5], [3.5, 0.5, 0.5]], atol=1e-6)
    centroids = mesh.vertices[mesh.faces].mean(dim=1)
    far = centroids[:, 0] > 1.5
    assert torch.allclose(mesh.face_colors[far], torch.tensor([0.0, 0.0, 1.0]))
    assert torch.allclose(mesh.face_colors[~far], torch.tensor([1.0, 0.0, 0.0]))


def test_load_reports_cleanup(tmp_path: Path) -> None:
    path = tmp_path / "dirty.obj"
    path.write_text(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 0 0\nv 5 5 5\nv 0 0 1\nf 1 2 3\nf 1 4 6\nf 1 2 4\nf 2 3 2\nf 3 2 1\n"
    )
    mesh, report = load_mesh_with_report(path)
    counts = (report.merged_vertices, report.degenerate_faces, report.unreferenced_vertices, report.duplicate_faces)
    assert counts == (1, 2, 1, 1)
    assert report.changed and "merged 1" in report.summary()
    assert mesh.num_faces == 2 and mesh.num_vertices == 4


def test_obj_colours_from_materials_in_file_order(tmp_path: Path) -> None:
    (tmp_path / "m.mtl").write_text("newmtl a\nKd 0.25 0.5 0.75\nnewmtl b\nKd 1 0 0.125\n")
    (tmp_path / "m.obj").write_text(
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 0 1\n"
        "usemtl b\nf 1 2 3\nusemtl a\nf 2 4 3 5\nusemtl b\nf 1 2 5\n"
    )
    mesh, report = load_mesh_with_report(tmp_path / "m.obj")
    assert report.color_source == "material"
    expected = torch.tensor([[1, 0, 0.125], [0.25, 0.5, 0.75], [0.25, 0.5, 0.75], [1, 0, 0.125]])
    assert torch.equal(mesh.face_colors, expected)
    assert torch.equal(mesh.faces[0], torch.tensor([0, 1, 2]))


def test_obj_missing_material_library_warns(tmp_path: Path) -> None:
    (tmp_path / "m.obj").write_text("mtllib gone.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl x\nf 1 2 3\n")
    mesh, report = load_mesh_with_report(tmp_path / "m.obj", default_color=(0.1, 0.2, 0.3))
    assert any("gone.mtl" in w for w in report.warnings)
    assert torch.allclose(mesh.face_colors, torch.tensor([[0.1, 0.2, 0.3]]))


def _truncated_ply(tmp_path: Path) -> Path:
    path = tmp_path / "ok.ply"
    save_mesh(builtin_mesh("sphere"), path)
    data = path.read_bytes()
    bad = tmp_path / "truncated.ply"
    bad.write_bytes(data[: len(data) - 1000])
    return bad


def _truncated_export(tmp_path: Path, name: str) -> Path:
    path = tmp_path / name
    trimesh.creation.icosphere(subdivisions=1).export(str(path))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    return path


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "make, match",
    [
        (_truncated_ply, "malformed or truncated"),
        (lambda t: _truncated_export(t, "cut.glb"), "malformed or truncated"),
        (lambda t: _truncated_export(t, "cut.off"), "malformed or truncated"),
        (lambda t: _write(t, "oob.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n"), "out of"),
        (lambda t: _write(t, "nan.obj", "v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n"), "non-finite"),
        (lambda t: _write(t, "inf.off", "OFF\n3 1 0\n0 0 0\ninf 0 0\n0 1 0\n3 0 1 2\n"), "non-finite"),
        (lambda t: _write(t, "points.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n"), "no faces"),
        (lambda t: _write(t, "flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"), "degenerate"),
        (lambda t: _write(t, "empty.ply", ""), "empty"),
        (lambda t: _write(t, "mesh.xyz", "0 0 0\n"), "unsupported"),
        (lambda t: _write(t, "junk.glb", "glTF this is not binary gltf"), "malformed or truncated"),
    ],
)
def test_malformed_files_give_clear_errors(tmp_path: Path, make: object, match: str) -> None:
    path = make(tmp_path)
    with pytest.raises(MeshLoadError, match=match) as info:
        load_mesh(path)
    assert path.name in str(info.value)
    assert isinstance(info.value, ValueError)


def test_truncated_binary_stl(tmp_path: Path) -> None:
    path = tmp_path / "box.stl"
    trimesh.creation.box().export(str(path))
    path.write_bytes(path.read_bytes()[:300])
    with pytest.raises(MeshLoadError, match="box.stl: truncated"):
        load_mesh(path)


def test_face_limit(tmp_path: Path) -> None:
    path = save_mesh(builtin_mesh("sphere"), tmp_path / "s.ply")[0]
    with pytest.raises(MeshLoadError, match="max_faces=1000"):
        load_mesh(path, max_faces=1000)
    assert load_mesh(path, max_faces=1280).num_faces == 1280
    with pytest.raises(ValueError, match="max_faces"):
        load_mesh(path, max_faces=0)


def test_missing_file_and_bad_arguments(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="nope.ply"):
        load_mesh(tmp_path / "nope.ply")
    path = save_mesh(builtin_mesh("cube"), tmp_path / "c.ply")[0]
    with pytest.raises(ValueError, match="default_color"):
        load_mesh(path, default_color=(1, 2))


def test_vertex_colours_are_averaged_per_face(tmp_path: Path) -> None:
    sphere = trimesh.creation.icosphere(subdivisions=2)
    red = sphere.vertices[:, 0] > 0
    rgba = np.zeros((len(sphere.vertices), 4), dtype=np.uint8)
    rgba[:, 3] = 255
    rgba[red, 0] = 255
    sphere.visual.vertex_colors = rgba
    path = tmp_path / "vc.ply"
    sphere.export(str(path))
    mesh, report = load_mesh_with_report(path)
    assert report.color_source == "vertex"
    corners_red = torch.as_tensor(red)[mesh.faces].float().mean(dim=1)
    assert torch.allclose(mesh.face_colors[:, 0], corners_red)
    assert torch.equal(mesh.face_colors[:, 1:], torch.zeros(mesh.num_faces, 2))
