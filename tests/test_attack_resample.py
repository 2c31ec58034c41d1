"""``meshadv attack`` resamples a mesh file uniformly with MeshLab by default (the paper's preprocessing), says the
face counts, keeps the adversarial mesh in the input file's frame, and ``--resample 0`` attacks the mesh as loaded
(stand-in victim)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from meshadv.cli import app
from meshadv.mesh import load_mesh, save_mesh
from meshadv.mesh.shapes import builtin_mesh

runner = CliRunner()


def _attack(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, *extra: str) -> tuple:
    pytest.importorskip("meshadv._raster")
    pytest.importorskip("pymeshlab")
    from stand_in_victims import PooledLinearClassifier

    import meshadv.victims as victims

    monkeypatch.setattr(victims, "load_victim", lambda name, **kwargs: PooledLinearClassifier())
    box = builtin_mesh("cube")
    box = box.with_vertices(box.vertices * 3.0 + torch.tensor([5.0, 0.0, 0.0]))  # off the origin, not unit size
    save_mesh(box, tmp_path / "box.ply")
    out = tmp_path / ("a" + "_".join(extra).replace("-", ""))
    result = runner.invoke(app, ["attack", str(tmp_path / "box.ply"), "--target", "7", "--views", "2",
                                 "--image-size", "32", "--steps", "2", "--quiet", "--threads", "1", *extra,
                                 "-o", str(out)])
    assert result.exit_code == 0, result.output
    return box, out, result.output, json.loads((out / "result.json").read_text())


def test_a_mesh_file_is_resampled_and_saved_back_in_its_frame(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    box, out, output, record = _attack(tmp_path, monkeypatch, "--resample", "600")
    faces = record["num_faces"]
    assert f"{box.num_faces} -> {faces} faces" in output and "--resample 0" in output
    assert 400 <= faces <= 800  # MeshLab's count is approximate
    moved = load_mesh(out / "adversarial_input_frame.ply")
    assert moved.num_faces == faces and load_mesh(out / "benign.ply").num_faces == faces
    extent = moved.vertices.max(0).values - moved.vertices.min(0).values
    assert extent.tolist() == pytest.approx([6.0, 6.0, 6.0], rel=0.05)  # the input's size and place
    assert moved.vertices[:, 0].mean().item() == pytest.approx(5.0, abs=0.3)


def test_resample_zero_attacks_the_mesh_as_loaded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    box, _, output, record = _attack(tmp_path, monkeypatch, "--resample", "0")
    assert record["num_faces"] == box.num_faces and "resampled" not in output
