"""Sweep jobs take a textured file as ``meshadv attack`` does: a tiny sweep of a generated OBJ + MTL + PNG and an
untextured PLY (stand-in victim, 32 px, 2 steps) draws the texture, keeps it through the artefacts, the kept
perturbation, the Mitsuba transfer, a regeneration, a study's render and a resume; the untextured file loads per face
as before; ``meshes.shading`` reaches the jobs; a database started loading per face keeps doing so."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any, Dict, List

import numpy as np
import pytest
import torch
from PIL import Image
from stand_in_victims import PooledLinearClassifier
from surface_assets import box_textured

from meshadv.experiments import ResultStore, SerialBackend, run_sweep
from meshadv.experiments.config import expand_jobs, parse_config
from meshadv.mesh import builtin_mesh, load_mesh, normalize_mesh, save_mesh
from meshadv.mesh.structure import Mesh
from meshadv.mesh.surface_mesh import SurfaceMesh, load_surface_mesh, save_surface_mesh
from meshadv.render import native_available

pytestmark = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")

JOB = "meshadv.experiments.jobs:run_attack_job"


@pytest.fixture
def stand_in(monkeypatch: pytest.MonkeyPatch) -> None:
    import meshadv.victims as victims
    from meshadv.experiments import jobs

    monkeypatch.setattr(victims, "load_victim", lambda *args, **kwargs: PooledLinearClassifier())
    monkeypatch.setattr(jobs, "_VICTIM_CACHE", {})


def _files(tmp_path: Path) -> Dict[str, Path]:
    textured, plain = tmp_path / "ball.obj", tmp_path / "chair.ply"
    save_surface_mesh(box_textured(), textured)  # OBJ + MTL + ball_texture.png
    save_mesh(builtin_mesh("chair"), plain)
    return {"bottle": textured, "chair": plain}


def _config(files: Dict[str, Path], **meshes: Any) -> Dict[str, Any]:
    return {
        "experiment": {"name": "surface"},
        "meshes": {"source": "files", "files": [{"path": str(p), "class": c} for c, p in files.items()], **meshes},
        "render": {"image_size": 32, "configurations": 1, "distance": 3.0, "elevation": [15, 25]},
        "victims": {"names": ["pooled"]},
        "attack": {"perturbations": ["shape"], "benign_correct_only": False,
                   "shape": {"steps": 2, "method": "adam", "lr": 0.01}},
    }


def _run(db: Path, jobs: List[Dict[str, Any]], out: Path) -> Any:
    with ResultStore(db) as store:
        return run_sweep(store, jobs, JOB, out_root=out, backend=SerialBackend(), max_attempts=1, progress=False)


def _png(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64) / 255.0


def test_a_sweep_attacks_a_textured_file_with_its_texture_and_resumes(tmp_path: Path, stand_in: None) -> None:
    from meshadv.experiments.jobs import PINNED_DEFAULTS_KEY, load_job_mesh
    from meshadv.experiments.rebuild import rebuild_job
    from meshadv.render import ViewSet
    from meshadv.render.setup import RenderSetup

    files = _files(tmp_path)
    jobs = expand_jobs(parse_config(_config(files)))
    assert len(jobs) == 2 and all("shading" not in j["mesh"] and "surface" not in j["mesh"] for j in jobs)
    db, out = tmp_path / "results.db", tmp_path / "run"
    first = _run(db, jobs, out)
    assert first.done == 2 and first.failed == 0
    with ResultStore(db) as store:
        assert store.get_meta(PINNED_DEFAULTS_KEY)["surface_meshes"] is True
        rows = {r.spec["source_class"]: r for r in store.rows("done")}
    ball, chair = rows["bottle"], rows["chair"]
    assert ball.record["mesh_surface"] is True
    texture = load_surface_mesh(files["bottle"]).texture
    # the job's benign and adversarial meshes carry the file's texture as it is
    folder = Path(ball.out_dir)
    assert ball.record["artifacts"]["benign_surface"] == "benign.obj"
    for name in ("benign.obj", ball.record["artifacts"]["adversarial_obj"]):
        torch.testing.assert_close(load_surface_mesh(folder / name).texture, texture, atol=0.6 / 255, rtol=0)
    # its benign render is the textured surface's, not the per-face colours'
    surface = load_job_mesh(ball.spec["mesh"], "shape")
    assert isinstance(surface, SurfaceMesh) and surface.shading == "flat"
    setup, views = RenderSetup(image_size=32), ViewSet.from_records(ball.spec["views"])
    with torch.no_grad():
        from meshadv.render.surface_reflectance import reflectance_of

        drawn, _ = setup.render(surface.vertices.unsqueeze(0), surface.faces, reflectance_of(surface), views)
        per_face, _ = setup.render(surface.vertices.unsqueeze(0), surface.faces, surface.face_colors, views)
    benign_png = _png(folder / "benign_v0.png")
    as_png = drawn[0].permute(1, 2, 0).numpy()
    assert np.abs(benign_png - as_png).max() < 1.5 / 255
    assert np.abs(benign_png - per_face[0].permute(1, 2, 0).numpy()).mean() > 0.01
    # the untextured file loads per face, as the job loader always loaded it
    plain = load_job_mesh(chair.spec["mesh"], "shape")
    before = normalize_mesh(load_mesh(files["chair"], max_faces=20000), z_up=False)[0]
    assert type(plain) is Mesh and chair.record["artifacts"].get("benign_surface") is None
    for field in ("vertices", "faces", "face_colors"):
        assert torch.equal(getattr(plain, field), getattr(before, field))
    # the database alone rebuilds the textured job's folder: the kept vertex move on the textured benign mesh
    rebuilt = rebuild_job(db, ball, tmp_path / "rebuilt")
    again = load_surface_mesh(rebuilt / ball.record["artifacts"]["adversarial_obj"])
    attacked = load_surface_mesh(folder / ball.record["artifacts"]["adversarial_obj"])
    torch.testing.assert_close(again.texture, texture, atol=0.6 / 255, rtol=0)
    torch.testing.assert_close(again.vertices, attacked.vertices, atol=2e-3, rtol=0)
    assert np.abs(_png(rebuilt / "benign_v0.png") - benign_png).max() < 1.5 / 255
    # the Mitsuba transfer of the sweep draws the textured job's texture (adversarial and benign control)
    if importlib.util.find_spec("mitsuba") is not None:
        from meshadv.transfer.controlled import cases_from_store, controlled_transfer

        cases = {c.true_class: c for c in cases_from_store(db, only_successful=False)}
        assert isinstance(cases["bottle"].mesh, SurfaceMesh) and cases["bottle"].mesh.texture is not None
        assert isinstance(cases["bottle"].benign_mesh, SurfaceMesh) and type(cases["chair"].mesh) is Mesh
        result = controlled_transfer([cases["bottle"]], spp=16, max_depth=2,
                                     victim_loader=lambda name: PooledLinearClassifier())
        assert result[0].mean_abs_image_difference < 0.06
    # regenerating the textured job reruns it on its textured surface and reproduces its record
    from meshadv.experiments.regenerate import regenerate_job

    again_run = regenerate_job(db, ball.job_id, tmp_path / "regenerated")
    assert again_run.differences == [] and again_run.record["mesh_surface"] is True
    torch.testing.assert_close(load_surface_mesh(again_run.out_dir / "benign.obj").texture, texture, atol=0.6 / 255,
                               rtol=0)
    # a study draws the textured job's missing render again from its OBJ, texture and shading included
    from dataclasses import replace

    from meshadv.study.selection import job_render

    assert ball.record["mesh_shading"] == "flat" and "mesh_shading" not in chair.record
    moved = tmp_path / "moved"
    moved.mkdir()
    for path in folder.iterdir():  # the folder without its renders (the texture PNG stays)
        if path.is_file() and path.name not in (*ball.record["artifacts"]["benign_images"], "benign_v0.png"):
            (moved / path.name).write_bytes(path.read_bytes())
    redrawn = job_render(replace(ball, out_dir=str(moved)), "benign", tmp_path / "cache")
    assert np.abs(_png(redrawn) - benign_png).max() < 1.5 / 255
    # resuming runs nothing and keeps the records
    second = _run(db, jobs, out)
    assert second.ran == 0 and second.skipped == 2
    with ResultStore(db) as store:
        assert {r.spec["source_class"]: r.record for r in store.rows("done")}["bottle"] == ball.record


def test_a_texture_map_sweep_keeps_and_rebuilds_the_attacked_texels(tmp_path: Path, stand_in: None) -> None:
    from meshadv.experiments.rebuild import rebuild_job

    textured = {"bottle": _files(tmp_path)["bottle"]}
    config = _config(textured)
    config["attack"].update(perturbations=["texture-map"], targets=["chair"],
                            **{"texture-map": {"steps": 2, "method": "adam", "lr": 0.05}})
    jobs = expand_jobs(parse_config(config))
    assert [j["perturbation"] for j in jobs] == ["texture-map"]
    db = tmp_path / "results.db"
    summary = _run(db, jobs, tmp_path / "run")
    assert summary.done == 1 and summary.failed == 0
    with ResultStore(db) as store:
        (row,) = store.rows("done")
        packed, _ = store.perturbation(row.job_id)
    assert packed.kind == "texture"
    assert row.record["distance"] == row.record["distances"]["texel_rmse"] > 0
    attacked = load_surface_mesh(Path(row.out_dir) / row.record["artifacts"]["adversarial_obj"])
    original = load_surface_mesh(textured["bottle"]).texture
    assert float((attacked.texture - original).abs().max()) > 0.01  # the texels moved
    rebuilt = rebuild_job(db, row, tmp_path / "rebuilt")
    again = load_surface_mesh(rebuilt / row.record["artifacts"]["adversarial_obj"])
    torch.testing.assert_close(again.texture, attacked.texture, atol=1.5 / 255, rtol=0)
    torch.testing.assert_close(again.vertices, attacked.vertices, atol=1e-6, rtol=0)


def test_meshes_shading_reaches_the_jobs_and_refuses_per_face_jobs(tmp_path: Path) -> None:
    from meshadv.experiments.jobs import load_job_mesh

    files = _files(tmp_path)
    jobs = expand_jobs(parse_config(_config(files, shading="smooth")))
    assert {j["mesh"]["shading"] for j in jobs} == {"smooth"}
    for job in jobs:
        mesh = load_job_mesh(job["mesh"], "shape")
        assert isinstance(mesh, SurfaceMesh) and mesh.shading == "smooth"
        assert (mesh.texture is not None) == (job["source_class"] == "bottle")
    config = _config(files, shading="smooth")
    config["attack"]["perturbations"] = ["shape", "texture"]
    with pytest.raises(ValueError, match="meshes.shading = 'smooth' needs attack.perturbations without 'texture'"):
        parse_config(config)
    with pytest.raises(ValueError, match="meshes.shading must be flat or smooth, got 'phong'"):
        parse_config(_config(files, shading="phong"))
    # a texture job (per-face colours) of the textured file attacks its per-face mesh
    assert type(load_job_mesh(jobs[0]["mesh"], "texture")) is Mesh


def test_a_database_started_loading_per_face_keeps_loading_per_face(tmp_path: Path, stand_in: None) -> None:
    from meshadv.experiments.jobs import PINNED_DEFAULTS_KEY, load_job_mesh, pin_defaults
    from meshadv.experiments.regenerate import pinned_spec

    files = _files(tmp_path)
    jobs = [j for j in expand_jobs(parse_config(_config(files))) if j["source_class"] == "bottle"]
    db = tmp_path / "results.db"
    _run(db, jobs, tmp_path / "run")
    with ResultStore(db) as store:
        # as a database written before the pin existed: finished jobs, no surface_meshes pin, records without it
        pins = store.get_meta(PINNED_DEFAULTS_KEY)
        store.set_meta(PINNED_DEFAULTS_KEY, {k: v for k, v in pins.items() if k != "surface_meshes"})
        assert pin_defaults(store, jobs)["surface_meshes"] is False
        row = store.rows("done")[0]
    pending = pinned_spec(jobs[0], None, {"surface_meshes": False})[0]
    assert type(load_job_mesh(pending["mesh"], "shape")) is Mesh
    old_record = {k: v for k, v in row.record.items() if k != "mesh_surface"}
    assert pinned_spec(row.spec, old_record)[0]["mesh"]["surface"] is False
    assert pinned_spec(row.spec, row.record)[0]["mesh"]["surface"] is True
    with pytest.raises(ValueError, match=r"assume\['surface_meshes'\] must be true or false"):
        pinned_spec(row.spec, None, {"surface_meshes": "yes"})
