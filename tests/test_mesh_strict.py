"""Malformed mesh files and bad mesh arguments raise clear errors instead of loading garbage."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from meshadv.mesh import MeshLoadError, builtin_mesh, load_mesh, load_mesh_with_report
from meshadv.mesh.normalize import normalize_mesh
from meshadv.mesh.resample import resample_mesh

PLY_HEAD = (
    "ply\nformat ascii 1.0\nelement vertex {nv}\nproperty float x\nproperty float y\nproperty float z\n"
    "element face {nf}\nproperty list uchar int vertex_indices\nend_header\n"
)
TRIANGLE = "0 0 0\n1 0 0\n0 1 0\n"


@pytest.mark.parametrize(
    ("name", "text", "match"),
    [
        ("fewer_vertices.ply", PLY_HEAD.format(nv=4, nf=1) + TRIANGLE + "3 0 1 2\n", "announces 4 vertex"),
        ("more_faces.ply", PLY_HEAD.format(nv=3, nf=1000) + TRIANGLE + "3 0 1 2\n", "1000 face"),
        ("extra_values.ply", PLY_HEAD.format(nv=3, nf=1) + TRIANGLE + "3 0 1 2\n3 0 2 1\n", "body has 5 lines"),
        ("bad_index.ply", PLY_HEAD.format(nv=3, nf=1) + TRIANGLE + "3 0 1 7\n", "vertex index 7 is out of range"),
        ("fewer_vertices.off", "OFF\n4 1 0\n" + TRIANGLE + "3 0 1 2\n", "announces 4 vertices and 1 faces"),
        ("more_faces.off", "OFF\n3 5 0\n" + TRIANGLE + "3 0 1 2\n", "announces 3 vertices and 5 faces"),
        ("extra_faces.off", "OFF\n3 1 0\n" + TRIANGLE + "3 0 1 2\n3 0 2 1\n", "has 5 data lines"),
        ("huge_index.off", "OFF\n3 1 0\n" + TRIANGLE + "3 0 1 18446744073709551615\n", "out of range"),
        ("short_face.off", "OFF\n3 1 0\n" + TRIANGLE + "3 0 1\n", "needs n >= 3 indices"),
        ("zero_index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", r"zero_index.obj:4: OBJ vertex indices start at 1"),
        ("short_vertex.obj", "v 0 1\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", r"short_vertex.obj:1: a vertex needs 3 numbers"),
        ("big_index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "vertex index 4 is out of range"),
        ("relative.obj", "v 0 0 0\nf -1 -2 -3\n", "relative index -2"),
    ],
)
def test_malformed_text_files_name_the_file_and_problem(tmp_path: Path, name: str, text: str, match: str) -> None:
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(MeshLoadError, match=match) as info:
        load_mesh(path)
    assert name in str(info.value)


def test_wellformed_text_files_still_load(tmp_path: Path) -> None:
    (tmp_path / "ok.ply").write_text(PLY_HEAD.format(nv=3, nf=1) + TRIANGLE + "3 0 1 2\n")
    (tmp_path / "ok.off").write_text("OFF\n# comment\n3 1 0\n" + TRIANGLE + "3 0 1 2\n")
    (tmp_path / "ok.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -1\n")
    for name in ("ok.ply", "ok.off", "ok.obj"):
        mesh = load_mesh(tmp_path / name)
        assert mesh.num_faces == 1
        corners = mesh.vertices[mesh.faces[0]]  # the file's triangle, with its winding (normal along +z)
        assert sorted(map(tuple, corners.tolist())) == [(0.0, 0.0, 0.0), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0)], name
        assert float(torch.cross(corners[1] - corners[0], corners[2] - corners[0], dim=0)[2]) > 0, name


def _obj_with_kd(tmp_path: Path, kd: str) -> Path:
    (tmp_path / "m.mtl").write_text(f"newmtl a\n{kd}\n")
    path = tmp_path / "x.obj"
    path.write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n")
    return path


@pytest.mark.parametrize(("kd", "match"), [("Kd -5 inf nan", "must be finite"), ("Kd 0 0", "needs 3 numbers")])
def test_bad_mtl_colours_are_refused(tmp_path: Path, kd: str, match: str) -> None:
    with pytest.raises(MeshLoadError, match=rf"m\.mtl:2: Kd.*{match}|m\.mtl:2: Kd {match}"):
        load_mesh(_obj_with_kd(tmp_path, kd))


def test_out_of_range_mtl_colours_are_clamped_with_a_warning(tmp_path: Path) -> None:
    mesh, report = load_mesh_with_report(_obj_with_kd(tmp_path, "Kd -5 0.5 7"))
    torch.testing.assert_close(mesh.face_colors, torch.tensor([[0.0, 0.5, 1.0]]))
    assert any("clamped" in w for w in report.warnings)


@pytest.mark.parametrize("extent", [float("inf"), 1e39, float("nan"), 0.0])
def test_normalize_mesh_refuses_extents_that_overflow(extent: float) -> None:
    with pytest.raises(ValueError, match="^extent must be"):
        normalize_mesh(builtin_mesh("cube"), extent=extent)


def test_normalize_mesh_wrong_types_are_type_errors() -> None:
    with pytest.raises(TypeError, match="^mesh must be a Mesh"):
        normalize_mesh(None)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="^extent must be a real number"):
        normalize_mesh(builtin_mesh("cube"), extent="1")  # type: ignore[arg-type]


def test_a_nan_vertex_never_reaches_meshlab() -> None:
    cube = builtin_mesh("cube")
    verts = cube.vertices.clone()
    verts[0, 0] = float("nan")
    with pytest.raises(ValueError, match="^vertices must be finite: 1 vertices hold NaN or infinite coordinates"):
        resample_mesh(cube.with_vertices(verts), target_faces=100)
