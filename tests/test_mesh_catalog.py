"""Tests of the PASCAL3D+ catalogue, the built-in shapes and the default mesh."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from meshadv.mesh import (
    BUILTIN_SHAPES,
    PASCAL3D_CLASSES,
    Pascal3DCatalog,
    builtin_mesh,
    class_mesh,
    default_mesh,
    is_watertight,
    load_mesh,
    save_mesh,
)

_OFF = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 0 1\n3 0 1 2\n"


def test_paper_classes() -> None:
    assert PASCAL3D_CLASSES == ("aeroplane", "bicycle", "boat", "bottle", "chair", "diningtable", "sofa")


def test_shared_catalogue(shared_data: Path) -> None:
    catalog = Pascal3DCatalog(shared_data / "pascal3d")
    assert catalog.classes() == list(PASCAL3D_CLASSES)
    counts = {cls: len(catalog.models(cls)) for cls in catalog.classes()}
    assert counts == {"aeroplane": 8, "bicycle": 6, "boat": 6, "bottle": 8, "chair": 10, "diningtable": 6, "sofa": 6}
    chairs = catalog.models("chair")
    assert [p.stem for p in chairs] == [f"{i:02d}" for i in range(1, 11)]
    assert catalog.model("chair", 10) == chairs[-1] and catalog.model("chair", "03") == chairs[2]
    assert Pascal3DCatalog.shared().root == catalog.root
    mesh = catalog.load("sofa", 3)
    assert float(mesh.vertices.abs().max()) == pytest.approx(1.0, abs=1e-6)


def test_release_layout_and_preferences(tmp_path: Path) -> None:
    for cls, stems in {"chair": ["01", "02", "10"], "car": ["01"], "sofa": []}.items():
        folder = tmp_path / "CAD" / cls
        folder.mkdir(parents=True)
        for stem in stems:
            (folder / f"{stem}.off").write_text(_OFF)
    (tmp_path / "CAD" / "chair" / "notes.txt").write_text("not a mesh")
    save_mesh(builtin_mesh("cube"), tmp_path / "CAD" / "chair" / "02.ply")  # PLY beats OFF for the same model
    catalog = Pascal3DCatalog(tmp_path)
    assert catalog.root == tmp_path / "CAD"
    assert catalog.classes() == ["chair", "car"]  # paper classes first, empty folders left out
    assert [p.name for p in catalog.models("chair")] == ["01.off", "02.ply", "10.off"]
    assert load_mesh(catalog.model("chair", 2)).num_faces == 12
    raw = catalog.load("car", 1, normalize=False)
    assert raw.num_faces == 1 and float(raw.vertices.max()) == 1.0
    with pytest.raises(ValueError, match="sofa"):
        catalog.models("sofa")
    with pytest.raises(ValueError, match="index 7"):
        catalog.model("chair", 7)
    with pytest.raises(FileNotFoundError, match="root"):
        Pascal3DCatalog(tmp_path / "missing")


@pytest.mark.parametrize("name", BUILTIN_SHAPES)
def test_builtin_shapes_are_normalized_and_closed(name: str) -> None:
    mesh = builtin_mesh(name)
    assert mesh.num_faces >= 12
    assert float(mesh.vertices.abs().max()) == pytest.approx(1.0, abs=1e-6)
    centre = (mesh.vertices.max(0).values + mesh.vertices.min(0).values) / 2
    assert torch.allclose(centre, torch.zeros(3), atol=1e-6)
    assert is_watertight(mesh.faces)
    assert bool((mesh.face_areas() > 0).all())


def test_builtin_shapes_are_y_up() -> None:
    for name in ("bottle", "chair"):
        extent = builtin_mesh(name).bounds().diff(dim=0)[0]
        assert int(extent.argmax()) == 1, name  # tallest along Y


def test_builtin_color_and_unknown_name() -> None:
    assert torch.allclose(builtin_mesh("cube", color=(1.0, 0.0, 0.5)).face_colors, torch.tensor([1.0, 0.0, 0.5]))
    with pytest.raises(ValueError, match="name must be one of"):
        builtin_mesh("teapot")


def test_default_mesh_with_and_without_shared_data(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    import meshadv.mesh.shapes as shapes

    monkeypatch.setattr(shapes, "shared_data_dir", lambda: None)
    fallback = default_mesh()
    assert fallback.num_faces == builtin_mesh("chair").num_faces
    monkeypatch.setattr(shapes, "shared_data_dir", lambda: tmp_path)  # a folder without pascal3d/
    assert default_mesh().num_faces == fallback.num_faces


def test_default_mesh_uses_shared_chair(shared_data: Path) -> None:
    mesh = default_mesh()
    raw = load_mesh(shared_data / "pascal3d" / "chair" / "01.ply")
    assert mesh.num_faces == raw.num_faces
    assert float(mesh.vertices.abs().max()) == pytest.approx(1.0, abs=1e-6)
    # Z-up became Y-up: the raw Z extent is now along Y.
    ext_raw = raw.bounds().diff(dim=0)[0]
    ext_new = mesh.bounds().diff(dim=0)[0]
    ratio = ext_new[1] / ext_raw[2]
    assert torch.allclose(ext_new[[0, 2]] / ext_raw[[0, 1]], ratio.expand(2), rtol=1e-4)


def test_class_mesh_falls_back_to_builtin(monkeypatch: pytest.MonkeyPatch) -> None:
    import meshadv.mesh.shapes as shapes

    monkeypatch.setattr(shapes, "shared_data_dir", lambda: None)
    assert class_mesh("bottle").num_faces == builtin_mesh("bottle").num_faces
    with pytest.raises(FileNotFoundError, match="aeroplane"):
        class_mesh("aeroplane")


def test_class_mesh_uses_shared_models(shared_data: Path) -> None:
    mesh = class_mesh("sofa", 3)
    raw = load_mesh(shared_data / "pascal3d" / "sofa" / "03.ply")
    assert mesh.num_faces == raw.num_faces
    assert float(mesh.vertices.abs().max()) == pytest.approx(1.0, abs=1e-6)
    with pytest.raises(ValueError, match="cls 'car'"):
        class_mesh("car")
