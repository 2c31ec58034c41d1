"""The paper's figures from a results database whose artefacts are not on this machine: the report regenerates only
the jobs a figure uses, checks them against the stored records, and the figure helpers draw what they claim
(heatmap colour range, crop, camera position, sign of the flow / curvature and flow / camera-distance correlations);
regeneration pins what a job ran with (pinned_spec)."""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path
from typing import Tuple

import numpy as np
import pytest

from meshadv.experiments import ResultStore
from meshadv.experiments.config import expand_jobs, parse_config
from meshadv.experiments.figures import (
    camera_eye,
    crop_to_content,
    curvature_scatter,
    flow_face_colors,
    mean_curvature_np,
)
from meshadv.experiments.regenerate import load_assumed, pinned_spec
from meshadv.experiments.report import ArtifactSource, settings_mix, write_report
from meshadv.experiments.report_figures import grid_cells
from sweep_fixtures import probe_jobs, run_probe_sweep


def _ellipsoid() -> Tuple[np.ndarray, np.ndarray]:
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3)
    return np.asarray(sphere.vertices) * np.array([1.0, 0.5, 0.3]), np.asarray(sphere.faces)


@pytest.fixture()
def moved_db(tmp_path: Path) -> Path:
    """A probe sweep (3 classes x 2 configurations x 2 targets, shape) whose artefact folders are gone, as on a
    machine that has only the committed database; configuration 1 of every class has one failed target, so the grid
    picks configuration 0 (all targets succeeded)."""
    def fails(job: dict) -> bool:
        return job["config_index"] == 1 and job["target"] == ("bicycle" if job["source_class"] == "aeroplane"
                                                               else "aeroplane")

    jobs = [{**j, "success": not fails(j)} for j in probe_jobs(["aeroplane", "bicycle", "boat"], configurations=2)]
    db = run_probe_sweep(tmp_path / "r.db", jobs, tmp_path / "run")
    shutil.rmtree(tmp_path / "run")
    return db


def _set_job_ref(db: Path) -> None:
    """Store a config text naming the probe job, so regeneration runs the job function the sweep ran."""
    with ResultStore(db) as store:
        store.set_meta("config_text", '[runner]\njob = "probe_jobs:mesh_probe_job"\n')


def test_report_regenerates_only_the_jobs_its_figures_use(moved_db: Path, tmp_path: Path) -> None:
    _set_job_ref(moved_db)
    with ResultStore(moved_db, read_only=True) as store:
        rows = store.rows()
    assert len(rows) == 12
    # without a place to regenerate into, nothing is drawn from missing folders
    cells, classes, _ = grid_cells(rows, ArtifactSource(moved_db, None))
    assert cells == {} and classes == ["aeroplane", "bicycle", "boat"]
    out = write_report(moved_db, tmp_path / "report", artifacts=tmp_path / "regen")
    names = sorted(p.name for p in out.figures)
    assert names == ["curvature_v.png", "flow_heatmap_v.png", "flow_quiver_v.png", "grid_v_shape.png"]
    # the grid needs configuration 0 of each class (3 x 2 jobs); the flow figures' attack is one of them (the
    # paper's example aeroplane -> bicycle); configuration 1 is never regenerated
    chosen = {r.job_id for r in rows if r.spec["config_index"] == 0}
    assert set(out.regenerations) == chosen
    assert all(c["matches"] and not c["differences"] for c in out.regenerations.values())
    flow_job = out.correlations["v"]["job_id"]
    spec = next(r.spec for r in rows if r.job_id == flow_job)
    assert (spec["source_class"], spec["target"], spec["config_index"]) == ("aeroplane", "bicycle", 0)
    text = (tmp_path / "report" / "regeneration.md").read_text()
    assert "success equal in 6/6" in text and "in 6/6" in text
    readme = (tmp_path / "report" / "README.md").read_text()
    assert "grid_v_shape.png): the paper's Fig. 2" in readme and "flow_quiver_v.png): the paper's Fig. 3" in readme
    assert "6 reproduce their stored success" in readme
    # a second report reuses the regenerated folders and their checks (nothing is run again)
    stamps = {p: p.stat().st_mtime_ns for p in (tmp_path / "regen").rglob("regeneration.json")}
    assert len(stamps) == 6
    again = write_report(moved_db, tmp_path / "report2", artifacts=tmp_path / "regen")
    assert set(again.regenerations) == chosen
    assert {p: p.stat().st_mtime_ns for p in (tmp_path / "regen").rglob("regeneration.json")} == stamps
    # the grid from regenerated renders: every diagonal cell is a benign render, every off-diagonal an attack
    source = ArtifactSource(moved_db, tmp_path / "regen")
    cells, classes, failed = grid_cells(rows, source)
    assert failed == set()
    assert set(cells) == {(a, b) for a in classes for b in classes}
    assert all(cells[(c, c)].name == "benign_v0.png" for c in classes)
    assert all(cells[(a, b)].name == "after_v0.png" for a in classes for b in classes if a != b)


def test_regeneration_reports_a_record_it_does_not_reproduce(moved_db: Path, tmp_path: Path) -> None:
    _set_job_ref(moved_db)
    with ResultStore(moved_db, read_only=True) as store:
        row = next(r for r in store.rows() if r.spec["config_index"] == 0 and r.spec["source_class"] == "boat")
    with sqlite3.connect(moved_db) as con:  # the database says something the job does not reproduce
        con.execute("UPDATE jobs SET record = ? WHERE job_id = ?",
                    (json.dumps({**row.record, "distance": row.record["distance"] * 2}), row.job_id))
    out = write_report(moved_db, tmp_path / "report", artifacts=tmp_path / "regen")
    check = out.regenerations[row.job_id]
    assert not check["matches"] and check["differences"][0].startswith("distance:")
    assert sum(c["matches"] for c in out.regenerations.values()) == 5
    assert "in 5/6" in (tmp_path / "report" / "regeneration.md").read_text()


def test_pinned_spec_pins_what_the_record_says_else_the_assumed_defaults(tmp_path: Path) -> None:
    spec = {"perturbation": "shape", "attack": {"method": "ddn", "steps": 300, "antialias": 2,
                                                "method_options": {"gamma": 0.2}}}
    record = {"victim_optimize": False,
              "attack_config": {"perturbation": "shape", "steps": 300, "lr": 0.001, "method": "ddn",
                                "method_options": {"gamma": 0.2, "step_size": 1e-3, "anneal": "cosine"}}}
    out, notes = pinned_spec(spec, record)
    assert notes == [] and out["victim_optimize"] is False
    # the options the record lacks (edge_gradient, visibility_gradient) take the values the record ran with; one the
    # rule no longer takes (anneal, at its neutral value) is left out
    assert out["attack"]["method_options"] == {"gamma": 0.2, "step_size": 1e-3, "edge_gradient": 1.0,
                                               "visibility_gradient": "nmr"}
    assert out["attack"]["antialias"] == 2 and out["attack"]["lr"] == 0.001 and "perturbation" not in out["attack"]
    assert spec["attack"]["method_options"] == {"gamma": 0.2}  # the stored spec is not modified
    # an old record pins nothing: the assumed defaults fill in, the spec's own options still win
    assume = {"victim_optimize": True,
              "attack": {"shape": {"method": "ddn", "method_options": {"gamma": 0.05, "smoothness": 1.0}}}}
    out, notes = pinned_spec(spec, {"success": True}, assume)
    assert notes == [] and out["victim_optimize"] is True
    assert out["attack"]["method_options"] == {"gamma": 0.2, "smoothness": 1.0, "edge_gradient": 1.0,
                                               "visibility_gradient": "nmr"}
    own = {**spec, "attack": {**spec["attack"], "method_options": {"edge_gradient": 0.1}}}
    assert pinned_spec(own, record)[0]["attack"]["method_options"]["edge_gradient"] == 0.1  # the spec's own wins
    texture = {"perturbation": "texture", "attack": {"method": "ddn"}}
    texture_record = {"attack_config": {"method": "ddn", "method_options": {"gamma": 0.1}}}
    assert pinned_spec(texture, texture_record)[0]["attack"]["method_options"] == {"gamma": 0.1}
    # a job of another update rule (the paper's protocol: Adam, no method key) does not get ddn's options
    protocol = {"perturbation": "shape", "attack": {"steps": 1000, "binary_search_steps": 5}}
    out, notes = pinned_spec(protocol, {"success": True}, assume)
    assert out["attack"] == protocol["attack"] and len(notes) == 1 and "attack options" in notes[0]
    out, notes = pinned_spec(spec, {"success": True})
    assert len(notes) == 2 and "victim_optimize" not in out and out["attack"] == spec["attack"]
    with pytest.raises(ValueError, match=r"^assume has unknown keys \['victim'\]"):
        pinned_spec(spec, None, {"victim": True})
    with pytest.raises(ValueError, match="victim_optimize"):
        pinned_spec(spec, None, {"victim_optimize": "yes"})
    bad = tmp_path / "a.json"
    bad.write_text("[1]")
    with pytest.raises(ValueError, match="JSON object"):
        load_assumed(bad)
    good = tmp_path / "b.json"
    good.write_text(json.dumps({"_comment": "why", **assume}))
    assert load_assumed(good) == assume


def test_flow_heatmap_colours_span_zero_to_the_largest_flow() -> None:
    import matplotlib

    v, f = _ellipsoid()
    va = v.copy()
    moved = f[0]
    va[moved] += np.array([0.0, 0.0, 0.3])  # one face's three vertices move by 0.3, nothing else moves
    rgb, vmax = flow_face_colors(v, va, f)
    cmap = matplotlib.colormaps["inferno"]
    assert vmax == pytest.approx(0.3)
    assert rgb[0] == pytest.approx(np.asarray(cmap(1.0)[:3]))
    untouched = ~np.isin(f, moved).any(axis=1)
    assert np.allclose(rgb[untouched], cmap(0.0)[:3])
    rgb, vmax = flow_face_colors(v, v, f)
    assert vmax == 1.0 and np.allclose(rgb, cmap(0.0)[:3])


def test_crop_to_content_keeps_the_object_and_drops_the_background() -> None:
    img = np.ones((200, 300, 3))
    img[50:70, 100:180] = 0.2
    crop = crop_to_content(img)
    assert crop.shape[0] == crop.shape[1] < 200
    assert (crop < 1.0).any(axis=-1).sum() == 20 * 80  # every object pixel is still there
    assert crop_to_content(np.ones((10, 10, 3))).shape == (10, 10, 3)
    with pytest.raises(ValueError, match="image"):
        crop_to_content(np.ones((10, 10)))


def test_camera_eye_follows_the_contract() -> None:
    assert camera_eye({"distance": 2.0, "azimuth": 90.0, "elevation": 0.0}) == pytest.approx([2.0, 0.0, 0.0])
    assert camera_eye({"distance": 3.0, "azimuth": 0.0, "elevation": 0.0}) == pytest.approx([0.0, 0.0, -3.0])
    assert camera_eye({"distance": 1.0, "azimuth": 40.0, "elevation": 90.0}) == pytest.approx([0.0, 1.0, 0.0])


def test_curvature_and_camera_correlations_have_the_constructed_sign(tmp_path: Path) -> None:
    v, f = _ellipsoid()
    curv = mean_curvature_np(v, f)
    normals = v / np.linalg.norm(v, axis=1, keepdims=True)
    _, more = curvature_scatter(v, v + 0.01 * curv[:, None] * normals, f, tmp_path / "a.png", curvature=curv)
    _, less = curvature_scatter(v, v + 0.01 / curv[:, None] * normals, f, tmp_path / "b.png", curvature=curv)
    assert more["spearman"] > 0.9 and less["spearman"] < -0.9
    eye = np.array([0.0, 0.0, -4.0])
    dist = np.linalg.norm(v - eye, axis=1)
    _, near = curvature_scatter(v, v + 0.01 * (6.0 - dist)[:, None] * normals, f, tmp_path / "c.png", eye=eye)
    _, far = curvature_scatter(v, v + 0.01 * (dist - 2.0)[:, None] * normals, f, tmp_path / "d.png", eye=eye)
    assert near["spearman_camera_distance"] < -0.9 < 0.9 < far["spearman_camera_distance"]
    assert "spearman_camera_distance" not in more
    with pytest.raises(ValueError, match="eye"):
        curvature_scatter(v, v, f, tmp_path / "e.png", eye=np.zeros(2))


def test_attack_job_records_what_it_ran_with(tmp_path: Path) -> None:
    from meshadv.attacks import make_attack
    from meshadv.experiments.jobs import run_attack_job
    from sweep_fixtures import tiny_builtin_config

    config = tiny_builtin_config("pin", steps=2, perturbations=("shape",))
    config["attack"]["shape"] = {"steps": 2, "method": "ddn", "method_options": {"gamma": 0.1}}
    spec = expand_jobs(parse_config(config))[0]
    (tmp_path / "a").mkdir()
    record = run_attack_job(spec, tmp_path / "a")
    expected = make_attack("shape", seed=spec["seed"], steps=2, method="ddn", method_options={"gamma": 0.1}).config()
    assert record["attack_config"] == expected
    assert record["attack_config"]["method_options"]["gamma"] == 0.1
    assert "smoothness" in record["attack_config"]["method_options"]  # a default the spec does not name
    assert record["victim_optimize"] is True
    from meshadv.experiments.provenance import compute_environment

    assert record["compute"] == compute_environment()  # the CPU and kernels its float rounding depends on
    (tmp_path / "b").mkdir()
    assert run_attack_job({**spec, "victim_optimize": False}, tmp_path / "b")["victim_optimize"] is False
    with pytest.raises(ValueError, match="victim_optimize"):
        run_attack_job({**spec, "victim_optimize": "no"}, tmp_path / "b")


def test_settings_mix_flags_a_group_run_with_two_settings(moved_db: Path) -> None:
    with ResultStore(moved_db, read_only=True) as store:
        rows = [r for r in store.rows() if r.state == "done"]
    assert settings_mix(rows) == []  # no record says anything: one "not recorded" setting
    first = {"attack_config": {"method": "ddn", "seed": 0, "method_options": {"gamma": 0.05}}, "victim_optimize": True}
    for i, r in enumerate(rows):  # the seed alone does not make a different setting
        r.record.update(first if i % 2 else {**first, "attack_config": {**first["attack_config"], "seed": 7}})
    assert settings_mix(rows) == []
    # a cap ceiling added later, recorded unbounded, is the same setting as the records that predate it
    cap = {"max_displacement": 0.02}
    for i, r in enumerate(rows):
        r.record["attack_config"] = {**r.record["attack_config"],
                                     "perceptibility_cap": {**cap, "edge_strain_max": None} if i % 2 else cap}
    assert settings_mix(rows) == []
    rows[1].record["attack_config"] = {**rows[1].record["attack_config"],
                                       "perceptibility_cap": {**cap, "edge_strain_max": 1.0}}
    assert len(settings_mix(rows)) == 1
    rows[1].record["attack_config"] = {**rows[1].record["attack_config"], "perceptibility_cap": cap}
    rows[0].record["victim_optimize"] = False
    (line,) = settings_mix(rows)
    assert line.startswith("- WARNING: v, shape: the attacks ran with 2 different") and "11, 1 attacks" in line


def test_report_command_regenerates_and_names_bad_options(moved_db: Path, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from meshadv.cli import build_app

    _set_job_ref(moved_db)
    app = build_app()
    res = CliRunner().invoke(app, ["report", str(moved_db), "-o", str(tmp_path / "r"), "--no-stored"])
    assert res.exit_code == 2 and "--artifacts" in res.output
    res = CliRunner().invoke(app, ["report", str(moved_db), "-o", str(tmp_path / "r"), "--artifacts",
                                   str(tmp_path / "a"), "--assume", str(tmp_path / "missing.json")])
    assert res.exit_code == 2 and "--assume" in res.output
    res = CliRunner().invoke(app, ["report", str(moved_db), "-o", str(tmp_path / "r"), "--artifacts",
                                   str(tmp_path / "a")])
    assert res.exit_code == 0, res.output
    assert "regenerated 6 job(s) for the figures; 6 reproduce their stored record" in res.output
    assert (tmp_path / "r" / "figures" / "grid_v_shape.png").is_file()


def test_a_resumed_sweep_keeps_the_defaults_of_its_first_run(tmp_path: Path) -> None:
    from unittest import mock

    from meshadv.attacks import budget
    from meshadv.experiments import SerialBackend, run_sweep
    from meshadv.experiments.jobs import PINNED_DEFAULTS_KEY, seed_pinned_defaults
    from sweep_fixtures import tiny_builtin_config

    config = tiny_builtin_config("pins", steps=2, perturbations=("shape",))
    config["attack"]["shape"] = {"steps": 2, "method": "ddn"}
    first, second = expand_jobs(parse_config(config))[:2]
    job = "meshadv.experiments.jobs:run_attack_job"
    db = tmp_path / "r.db"
    with ResultStore(db) as store:
        run_sweep(store, [first], job, out_root=tmp_path, backend=SerialBackend(), progress=False)
        pins = store.get_meta(PINNED_DEFAULTS_KEY)
    assert pins["attack"]["shape/ddn"]["method_options"] == budget.DDN_DEFAULTS["shape"]
    assert pins["victim_optimize"] is True
    changed = {**budget.DDN_DEFAULTS["shape"], "smoothness": 7.0}
    with mock.patch.dict(budget.DDN_DEFAULTS, {"shape": changed}), ResultStore(db) as store:
        run_sweep(store, [first, second], job, out_root=tmp_path, backend=SerialBackend(), progress=False)
        records = {r.job_id: r.record for r in store.rows("done")}
    assert len(records) == 2
    smoothness = sorted(r["attack_config"]["method_options"]["smoothness"] for r in records.values())
    assert smoothness == [pins["attack"]["shape/ddn"]["method_options"]["smoothness"]] * 2  # not 7.0
    # a database pinned from an assumed-defaults file keeps the file's values over today's code
    with ResultStore(tmp_path / "s.db") as store:
        seeded = seed_pinned_defaults(store, {"victim_optimize": False,
                                              "attack": {"shape": {"method": "ddn", "lr": 0.5}}})
        assert seeded == {"victim_optimize": False, "attack": {"shape/ddn": {"method": "ddn", "lr": 0.5}}}
        run_sweep(store, [first], job, out_root=tmp_path / "s", backend=SerialBackend(), progress=False)
        (record,) = [r.record for r in store.rows("done")]
    assert record["victim_optimize"] is False and record["attack_config"]["lr"] == 0.5


def test_a_record_keeps_its_compute_and_a_mismatch_says_what_rounding_depends_on(moved_db: Path,
                                                                                  tmp_path: Path) -> None:
    """A rerun that does not reproduce its record (here: a first successful step it cannot match) says so and names
    what float rounding depends on, as recorded (an attack record's ``compute``) and here."""
    from typer.testing import CliRunner

    from meshadv.cli import app
    from meshadv.experiments.provenance import compute_environment
    from meshadv.experiments.regenerate import regenerate_job

    _set_job_ref(moved_db)
    with ResultStore(moved_db, read_only=True) as store:
        row = next(r for r in store.rows() if r.spec["config_index"] == 0 and r.spec["source_class"] == "boat")
    here = compute_environment()
    assert set(here) == {"cpu", "torch_cpu_capability", "torch_threads"}
    assert regenerate_job(moved_db, row.job_id, tmp_path / "first").matches
    stored = {**row.record, "steps_to_success": 1000,
              "compute": {"cpu": "Some Other CPU", "torch_cpu_capability": "AVX2", "torch_threads": "7"}}
    with sqlite3.connect(moved_db) as con:
        con.execute("UPDATE jobs SET record = ? WHERE job_id = ?", (json.dumps(stored), row.job_id))
    result = CliRunner().invoke(app, ["regenerate", str(moved_db), row.job_id, "-o", str(tmp_path / "second")])
    assert result.exit_code == 1, result.output
    text = " ".join(result.output.split())
    assert "steps_to_success: 1000 ->" in text and "Some Other CPU, torch kernels AVX2, 7 thread(s)" in text
    assert f"this run: {here['cpu']}, torch kernels {here['torch_cpu_capability']}" in text
