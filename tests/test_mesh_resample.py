"""Tests of MeshLab resampling: shape kept (Hausdorff), density raised, isolation of crashes, the disk cache."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pymeshlab
import pytest
import torch

from meshadv.mesh import (
    Mesh,
    MeshProcessingError,
    builtin_mesh,
    default_cache_dir,
    is_watertight,
    load_mesh,
    resample_mesh,
    resample_mesh_with_info,
)
from meshadv.mesh.resample import run_isolated


def hausdorff(a: Mesh, b: Mesh, samples: int = 20000) -> float:
    """Two-sided Hausdorff distance: MeshLab samples one surface and measures exact distances to the other."""
    ms = pymeshlab.MeshSet()
    for mesh in (a, b):
        v, f, _ = mesh.numpy()
        ms.add_mesh(pymeshlab.Mesh(v.astype(np.float64), f.astype(np.int32)))
    big = pymeshlab.PureValue(10.0 * a.bbox_diagonal())
    kw = {"samplevert": True, "sampleface": True, "samplenum": samples, "maxdist": big}
    d_ab = ms.get_hausdorff_distance(sampledmesh=0, targetmesh=1, **kw)["max"]
    d_ba = ms.get_hausdorff_distance(sampledmesh=1, targetmesh=0, **kw)["max"]
    return max(d_ab, d_ba)


def test_hausdorff_helper_detects_a_change() -> None:
    sphere = builtin_mesh("sphere")
    bigger = sphere.with_vertices(sphere.vertices * 1.05)
    assert hausdorff(sphere, sphere) < 1e-6
    assert hausdorff(sphere, bigger) == pytest.approx(0.05, rel=0.02)


@pytest.mark.parametrize("method", ["uniform", "isotropic"])
def test_resample_generated_shape_keeps_shape(tmp_path: Path, method: str) -> None:
    torus = builtin_mesh("torus")
    dense, info = resample_mesh_with_info(torus, target_faces=8000, method=method, cache_dir=tmp_path)
    assert info.method == method and not info.cache_hit
    assert dense.num_faces > torus.num_faces
    assert 0.6 * 8000 < dense.num_faces < 1.5 * 8000
    measured = hausdorff(torus, dense) / torus.bbox_diagonal()
    assert measured < 0.01
    assert info.hausdorff == pytest.approx(measured, rel=0.2, abs=2e-4)
    assert is_watertight(dense.faces)


@pytest.mark.parametrize("model", [("chair", "01"), ("diningtable", "01")])
def test_resample_real_open_meshes(shared_data: Path, tmp_path: Path, model: "tuple[str, str]") -> None:
    cls, stem = model
    mesh = load_mesh(shared_data / "pascal3d" / cls / f"{stem}.ply")
    assert not is_watertight(mesh.faces)
    dense, info = resample_mesh_with_info(mesh, target_faces=4 * mesh.num_faces, cache_dir=tmp_path)
    assert info.method == "isotropic"  # auto picks isotropic remeshing for open meshes
    assert dense.num_faces > 2 * mesh.num_faces
    measured = hausdorff(mesh, dense) / mesh.bbox_diagonal()
    assert measured < 0.01
    assert info.hausdorff == pytest.approx(measured, rel=0.2, abs=2e-4)


def test_resample_edge_length_controls_density(tmp_path: Path) -> None:
    sphere = builtin_mesh("sphere")
    coarse = resample_mesh(sphere, edge_length=0.1, method="isotropic", cache_dir=tmp_path)
    fine = resample_mesh(sphere, edge_length=0.05, method="isotropic", cache_dir=tmp_path)
    assert 2.5 < fine.num_faces / coarse.num_faces < 6.0  # about 4x for half the edge length
    edges = fine.vertices[fine.faces[:, [0, 1]]].diff(dim=1).norm(dim=-1)
    assert float(edges.median()) == pytest.approx(0.05, rel=0.3)


def test_cache_is_hit_on_second_call(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MESHADV_CACHE", str(tmp_path / "root"))
    assert default_cache_dir() == tmp_path / "root" / "resample"
    bottle = builtin_mesh("bottle")
    first, info1 = resample_mesh_with_info(bottle, target_faces=3000)
    assert not info1.cache_hit and info1.cache_path is not None and info1.cache_path.is_file()
    assert info1.cache_path.is_relative_to(tmp_path / "root" / "resample")
    second, info2 = resample_mesh_with_info(bottle, target_faces=3000)
    assert info2.cache_hit and info2.cache_path == info1.cache_path
    assert torch.equal(first.vertices, second.vertices) and torch.equal(first.faces, second.faces)
    # Other parameters or another input miss the cache.
    _, info3 = resample_mesh_with_info(bottle, target_faces=2000)
    assert not info3.cache_hit and info3.cache_path != info1.cache_path
    moved = bottle.with_vertices(bottle.vertices * 1.01)
    _, info4 = resample_mesh_with_info(moved, target_faces=3000)
    assert not info4.cache_hit
    # A corrupt cache entry is recomputed, not trusted.
    info1.cache_path.write_bytes(b"garbage")
    third, info5 = resample_mesh_with_info(bottle, target_faces=3000)
    assert not info5.cache_hit and torch.equal(third.faces, first.faces)
    _, info6 = resample_mesh_with_info(bottle, target_faces=3000, use_cache=False)
    assert not info6.cache_hit and info6.cache_path is None


def test_colors_are_carried_to_new_faces(tmp_path: Path) -> None:
    sphere = builtin_mesh("sphere")
    centroids = sphere.vertices[sphere.faces].mean(dim=1)
    red, blue = torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 0.0, 1.0])
    colors = torch.where((centroids[:, 0] > 0).unsqueeze(1), red, blue)
    dense = resample_mesh(sphere.with_face_colors(colors), target_faces=5000, cache_dir=tmp_path)
    new_centroids = dense.vertices[dense.faces].mean(dim=1)
    far = new_centroids[:, 0].abs() > 0.2
    expected = torch.where((new_centroids[:, 0] > 0).unsqueeze(1), red, blue)
    assert torch.equal(dense.face_colors[far], expected[far])


def test_crash_becomes_exception() -> None:
    with pytest.raises(MeshProcessingError, match="SIGSEGV"):
        run_isolated({"op": "crash"})


def test_timeout_becomes_exception() -> None:
    with pytest.raises(MeshProcessingError, match="timed out"):
        run_isolated({"op": "sleep", "seconds": 30}, timeout=1.0)


def test_worker_failures_are_reported(tmp_path: Path) -> None:
    with pytest.raises(MeshProcessingError, match="max_cells=100000"):
        resample_mesh_with_info(
            builtin_mesh("sphere"), edge_length=0.01, method="uniform", cache_dir=tmp_path, max_cells=100_000
        )
    with pytest.raises(MeshProcessingError, match="empty mesh"):
        # A cell far larger than the shape: marching cubes finds no surface.
        resample_mesh(builtin_mesh("cube"), edge_length=50.0, method="uniform", cache_dir=tmp_path)
    with pytest.raises(MeshProcessingError, match="failed|crashed"):
        resample_mesh(builtin_mesh("sphere"), target_faces=3000, cache_dir=tmp_path, memory_limit_mb=64)
    assert not list(tmp_path.rglob("*.npz"))  # failures are not cached


def test_bad_arguments(tmp_path: Path) -> None:
    sphere = builtin_mesh("sphere")
    with pytest.raises(ValueError, match="method"):
        resample_mesh(sphere, method="poisson", cache_dir=tmp_path)
    with pytest.raises(ValueError, match="not both"):
        resample_mesh(sphere, target_faces=100, edge_length=0.1, cache_dir=tmp_path)
    with pytest.raises(ValueError, match="target_faces"):
        resample_mesh(sphere, target_faces=0, cache_dir=tmp_path)
    with pytest.raises(ValueError, match="edge_length"):
        resample_mesh(sphere, edge_length=-1.0, cache_dir=tmp_path)
    empty = Mesh(torch.zeros(0, 3), torch.zeros(0, 3, dtype=torch.int64), torch.zeros(0, 3))
    with pytest.raises(ValueError, match="^mesh has no faces"):
        resample_mesh(empty, cache_dir=tmp_path)
