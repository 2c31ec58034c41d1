"""``meshadv attack`` on textured and vertex-coloured files: ``--shading``, vertex colours through the outputs, and
the Mitsuba transfer of the result with its texture or colours and shading (generated meshes, stand-in victim)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image
from stand_in_victims import PooledLinearClassifier
from surface_assets import box_textured, vertex_coloured
from typer.testing import CliRunner

from meshadv.mesh.surface_mesh import SurfaceMesh, load_surface_mesh, save_surface_mesh
from meshadv.render import native_available

pytestmark = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")

SIZE = 48


@pytest.fixture
def stand_in(monkeypatch: pytest.MonkeyPatch) -> None:
    import meshadv.victims as victims

    monkeypatch.setattr(victims, "load_victim", lambda *args, **kwargs: PooledLinearClassifier())


def _cli(*args: str) -> Any:
    from meshadv.cli import app

    return CliRunner().invoke(app, [str(a) for a in args])


def _attack(source: Path, out: Path, *extra: str, perturbation: str = "shape") -> Any:
    return _cli("attack", source, "--perturbation", perturbation, "--target", "728", "--steps", "2", "--views", "1",
                "--azimuths", "30:30", "--image-size", SIZE, "--quiet", "--method", "adam", "--lr", "0.01",
                "--cap", "none", "--benign-wrong-ok", "--resample", "0", "-o", out, *extra)  # extra's --resample wins


def _png(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64) / 255.0


def _render(source: Path, out: Path, *extra: str) -> np.ndarray:
    run = _cli("render", source, "--views", "1", "--azimuths", "30:30", "--image-size", SIZE, "-o", out, *extra)
    assert run.exit_code == 0, run.output
    return _png(out / "view_0.png")


@pytest.mark.parametrize("perturbation", ["shape", "texture-map"])
def test_the_attack_draws_a_textured_file_under_the_asked_shading_as_render_does(
        tmp_path: Path, stand_in: None, perturbation: str) -> None:
    source = tmp_path / "box.obj"
    save_surface_mesh(box_textured("cube"), source)
    before = {}
    for shading in ("flat", "smooth"):
        out = tmp_path / shading
        run = _attack(source, out, "--shading", shading, perturbation=perturbation)
        assert run.exit_code == 0, run.output
        record = json.loads((out / "result.json").read_text())
        assert record["shading"] == shading
        before[shading] = _png(out / "before_v0.png")
        # the attack's benign render is the one `meshadv render` draws of the file under the same shading
        np.testing.assert_allclose(before[shading], _render(source, tmp_path / f"r_{shading}", "--shading", shading),
                                   atol=1.5 / 255, rtol=0)
        again = load_surface_mesh(out / "adversarial.obj")
        assert again.texture is not None and again.texture.shape == (16, 16, 3)
    # the two shadings differ on a cube (its smooth normals are the corners' diagonals)
    assert np.abs(before["flat"] - before["smooth"]).mean() > 0.01


def test_the_default_shading_is_what_the_file_asks_for(tmp_path: Path, stand_in: None) -> None:
    plain, with_normals = tmp_path / "plain.obj", tmp_path / "normals.obj"
    surface = box_textured()
    save_surface_mesh(surface, plain)
    normals = torch.nn.functional.normalize(surface.vertices, dim=1)  # a sphere's normals
    save_surface_mesh(SurfaceMesh(surface.mesh, surface.uvs, surface.uv_faces, surface.texture, normals=normals,
                                  normal_faces=surface.faces), with_normals)
    for source, expected in ((plain, "flat"), (with_normals, "smooth")):
        run = _attack(source, tmp_path / expected)
        assert run.exit_code == 0, run.output
        assert json.loads((tmp_path / expected / "result.json").read_text())["shading"] == expected


def test_bad_shading_options_are_errors_naming_the_option(tmp_path: Path, stand_in: None) -> None:
    source = tmp_path / "ball.obj"
    save_surface_mesh(box_textured(), source)
    run = _attack(source, tmp_path / "a", "--shading", "phong")
    assert run.exit_code == 2 and "--shading must be flat or smooth" in run.output
    run = _attack(source, tmp_path / "b", "--shading", "smooth", perturbation="texture")
    assert run.exit_code == 2 and "--shading smooth needs --perturbation shape or texture-map" in run.output


def test_vertex_colours_survive_load_attack_save_load(tmp_path: Path, stand_in: None) -> None:
    painted = vertex_coloured()
    source = tmp_path / "painted.ply"
    save_surface_mesh(painted, source)
    loaded = load_surface_mesh(source)
    assert loaded.vertex_colors is not None and loaded.texture is None
    out = tmp_path / "out"
    run = _attack(source, out)
    assert run.exit_code == 0, run.output
    # the attack draws the interpolated vertex colours, as `meshadv render` does (not per-face means)
    np.testing.assert_allclose(_png(out / "before_v0.png"), _render(source, tmp_path / "r"), atol=1.5 / 255, rtol=0)
    record = json.loads((out / "result.json").read_text())
    assert record["shading"] == "flat"
    text = (out / "adversarial.obj").read_text()
    assert sum(line.startswith("v ") and len(line.split()) == 7 for line in text.splitlines()) == loaded.num_vertices
    for name in ("adversarial.obj", "adversarial.ply", "adversarial_input_frame.obj", "adversarial.glb"):
        again = load_surface_mesh(out / name)
        assert again.num_vertices == loaded.num_vertices, name
        torch.testing.assert_close(again.vertex_colors, loaded.vertex_colors, atol=0.6 / 255, rtol=0)
    # what other tools read: trimesh's vertex colours of the OBJ, in the input file's frame
    tm = trimesh.load(out / "adversarial_input_frame.obj", force="mesh", process=False)
    np.testing.assert_allclose(np.asarray(tm.visual.vertex_colors)[:, :3] / 255.0, loaded.vertex_colors.numpy(),
                               atol=0.6 / 255)
    moved = load_surface_mesh(out / "adversarial_input_frame.obj").vertices
    assert float((moved - loaded.vertices).abs().max()) < 0.05  # the input file's frame, not [-1, 1]


def test_smooth_shading_of_a_plain_mesh_draws_its_faces_colours_per_vertex(tmp_path: Path, stand_in: None) -> None:
    from meshadv.mesh import builtin_mesh, save_mesh

    source = tmp_path / "plain.ply"
    save_mesh(builtin_mesh("sphere"), source)
    out = tmp_path / "out"
    run = _attack(source, out, "--shading", "smooth")
    assert run.exit_code == 0, run.output
    assert json.loads((out / "result.json").read_text())["shading"] == "smooth"
    np.testing.assert_allclose(_png(out / "before_v0.png"), _render(source, tmp_path / "r", "--shading", "smooth"),
                               atol=1.5 / 255, rtol=0)
    assert load_surface_mesh(out / "adversarial.obj").vertex_colors is not None


@pytest.mark.parametrize(("asset", "shading"), [("textured", "smooth"), ("textured", "flat"), ("painted", "smooth")])
def test_the_transfer_of_the_result_draws_its_texture_or_colours_under_its_shading(
        tmp_path: Path, stand_in: None, asset: str, shading: str) -> None:
    pytest.importorskip("mitsuba")
    from meshadv.transfer.controlled import case_from_attack_folder, transfer_attack_folder
    from meshadv.transfer.mitsuba_spec import MeshObject

    surface = box_textured() if asset == "textured" else vertex_coloured()
    source = tmp_path / ("ball.obj" if asset == "textured" else "ball.ply")
    save_surface_mesh(surface, source)
    out = tmp_path / "out"
    run = _attack(source, out, "--shading", shading)
    assert run.exit_code == 0, run.output
    case = case_from_attack_folder(out)
    for mesh in (case.mesh, case.benign_mesh):
        assert isinstance(mesh, SurfaceMesh) and mesh.shading == shading
        obj = MeshObject.from_mesh(mesh)
        assert (obj.texture is not None) == (asset == "textured")
        assert (obj.vertex_colors is not None) == (asset == "painted")
        assert (obj.normals is not None) == (shading == "smooth")
    rows = transfer_attack_folder(out, spp=32, max_depth=2, victim_loader=lambda name: PooledLinearClassifier())
    ours, theirs = _png(out / "after_v0.png"), _png(out / "mitsuba_v0.png")
    inside = (ours < 0.99).any(-1) & (theirs < 0.99).any(-1)
    diff = np.abs(ours - theirs).mean(-1)[inside]
    # the same texture or colours and normals: agreement up to edges and Monte-Carlo noise of the ambient term
    assert np.median(diff) < 0.05, np.median(diff)
    assert rows[0].mean_abs_image_difference < 0.06


@pytest.mark.parametrize("asset", ["textured", "painted"])
def test_resampling_carries_the_texture_or_colours_and_keeps_the_look(tmp_path: Path, stand_in: None,
                                                                      asset: str) -> None:
    surface = box_textured() if asset == "textured" else vertex_coloured()
    source = tmp_path / ("ball.obj" if asset == "textured" else "ball.ply")
    save_surface_mesh(surface, source)
    out = tmp_path / "out"
    run = _attack(source, out, "--resample", "3000")
    assert run.exit_code == 0, run.output
    assert "resampled uniformly with MeshLab" in run.output
    assert ("texture carried onto a 1024x1024 atlas" in run.output) == (asset == "textured")
    assert ("vertex colours carried" in run.output) == (asset == "painted")
    dense = load_surface_mesh(out / "adversarial.obj")
    assert 2000 < dense.num_faces < 4000 and dense.num_faces != surface.num_faces
    assert (dense.texture is not None) == (asset == "textured")
    assert (dense.vertex_colors is not None) == (asset == "painted")
    before, original = _png(out / "before_v0.png"), _render(source, tmp_path / "r")
    drawn = (before < 0.99).any(-1) & (original < 0.99).any(-1)
    assert np.abs(before - original).mean(-1)[drawn].mean() < 0.03


def test_the_texture_map_attack_takes_the_textured_file_as_loaded(tmp_path: Path, stand_in: None) -> None:
    source = tmp_path / "ball.obj"
    save_surface_mesh(box_textured(), source)
    run = _attack(source, tmp_path / "out", "--resample", "3000", perturbation="texture-map")
    assert run.exit_code == 0, run.output
    assert "attacked as loaded" in run.output and "resampled uniformly" not in run.output
    assert load_surface_mesh(tmp_path / "out" / "adversarial.obj").texture.shape == (16, 16, 3)


@pytest.mark.parametrize(("asset", "shading"), [("textured", "smooth"), ("painted", "flat"), ("painted", "smooth")])
def test_transfer_check_compares_a_files_texture_or_colours_under_its_shading(tmp_path: Path, asset: str,
                                                                              shading: str) -> None:
    pytest.importorskip("mitsuba")
    surface = box_textured() if asset == "textured" else vertex_coloured()
    source = tmp_path / ("ball.obj" if asset == "textured" else "ball.ply")
    save_surface_mesh(surface, source)
    run = _cli("transfer", "check", source, "--size", 48, "--spp", 64, "--shading", shading, "-o", tmp_path / "c")
    assert run.exit_code == 0, run.output
    check = json.loads((tmp_path / "c" / "check.json").read_text())
    assert check["mask_iou"] > 0.97
    assert check["mean_abs_difference"] < 0.03 and check["p95_abs_difference"] < 0.1
    # both sides draw the file's surface: the same mesh with its per-face colours only draws another image
    from meshadv.mesh import save_mesh

    save_mesh(surface.mesh, tmp_path / "per_face.ply")
    run = _cli("transfer", "check", tmp_path / "per_face.ply", "--size", 48, "--spp", 4, "-o", tmp_path / "f")
    assert run.exit_code == 0, run.output
    ours, per_face = _png(tmp_path / "c" / "meshadv.png"), _png(tmp_path / "f" / "meshadv.png")
    assert np.abs(ours - per_face).mean() > 0.004  # identical (0) if the per-face path drew both
    run = _cli("transfer", "check", source, "--shading", "phong")
    assert run.exit_code == 2 and "--shading must be flat or smooth" in run.output
