"""Sweep files, the `sweep` / `report` commands, and every figure produced from a tiny sweep."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from meshadv.experiments import ResultStore, job_id
from meshadv.experiments.config import expand_jobs, load_config, parse_config
from meshadv.experiments.figures import curvature_scatter, flow_heatmaps, flow_quiver, mean_curvature_np
from meshadv.experiments.report import write_report
from sweep_fixtures import probe_jobs, run_probe_sweep, sweep_cli

TINY = """
[experiment]
name = "tiny"
seeds = [0]
output = "run"

[meshes]
source = "pascal3d"
classes = ["boat", "chair", "sofa"]

[render]
image_size = 32
configurations = 2
elevation = [10, 20]

[victims]
names = ["v1"]

[attack]
types = ["shape", "texture"]

[attack.shape]
steps = 5

[multiview]
enabled = true
view_counts = [2, 3]
azimuth_ranges = [[45, 60], [35, 70]]
eval_views = 4
types = ["shape"]
classes = ["chair"]

[runner]
job = "probe_jobs:mesh_probe_job"
max_attempts = 1
"""


def test_expansion_counts_and_determinism(tmp_path: Path) -> None:
    (tmp_path / "a.toml").write_text(TINY)
    cfg = load_config(tmp_path / "a.toml")
    jobs = expand_jobs(cfg)
    single = [j for j in jobs if j["kind"] == "single"]
    multi = [j for j in jobs if j["kind"] == "multiview"]
    assert len(single) == 3 * 2 * 1 * 2 * 2  # meshes x configurations x victims x types x targets (x 1 seed)
    assert len(multi) == 1 * 1 * 1 * 2 * 2  # chair x victim x shape x targets x view settings
    assert all(j["target"] != j["source_class"] for j in jobs)
    assert {len(j["views"]) for j in multi} == {2, 3} and {len(j["eval_views"]) for j in multi} == {4}
    assert all(10 <= j["views"][0]["elevation"] <= 20 for j in single)
    assert single[0]["attack"] == {"method": "ddn", "steps": 5} and single[0]["mesh"]["path"] == "pascal3d/boat/01.ply"
    ids = [job_id(j) for j in jobs]
    assert len(set(ids)) == len(ids)
    assert ids == [job_id(j) for j in expand_jobs(load_config(tmp_path / "a.toml"))]
    import tomllib

    import yaml

    (tmp_path / "b.yaml").write_text(yaml.safe_dump(tomllib.loads(TINY)))
    assert ids == [job_id(j) for j in expand_jobs(load_config(tmp_path / "b.yaml"))]
    assert cfg.db == tmp_path / "run" / "results.db"


@pytest.mark.parametrize(
    ("raw", "match"),
    [
        ({"victims": {"names": ["v"]}, "bogus": {}}, r"unknown config section \[bogus\]"),
        ({}, "victims.names"),
        ({"victims": {"names": ["v"]}, "meshes": {"classes": ["cat"]}}, r"^meshes.classes must be PASCAL3D\+ classes"),
        ({"victims": {"names": ["v"]}, "attack": {"types": ["colour"]}}, "attack.types"),
        ({"victims": {"names": ["v"]}, "render": {"azimuth": [10, 0]}}, "render.azimuth"),
        ({"victims": {"names": ["v"]}, "runner": {"max_attempts": 0}}, "^runner.max_attempts must be"),
    ],
)
def test_config_errors_name_the_key(raw: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        parse_config(raw)


def test_load_config_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="missing.toml"):
        load_config(tmp_path / "missing.toml")
    (tmp_path / "x.json").write_text("{}")
    with pytest.raises(ValueError, match="^config must be a .toml"):
        load_config(tmp_path / "x.json")


def test_tiny_sweep_commands_tables_and_figures(tmp_path: Path) -> None:
    (tmp_path / "tiny.toml").write_text(TINY)
    runner = CliRunner()
    res = runner.invoke(sweep_cli(), ["sweep", str(tmp_path / "tiny.toml"), "--dry-run"])
    assert res.exit_code == 0, res.output
    assert "28 jobs (24 single-view, 4 multi-view)" in res.output
    res = runner.invoke(sweep_cli(), ["sweep", str(tmp_path / "tiny.toml"), "--backend", "serial", "--no-progress"])
    assert res.exit_code == 0, res.output
    assert "28/28 done" in res.output
    db = tmp_path / "run" / "results.db"
    with ResultStore(db) as store:
        assert store.get_meta("name") == "tiny" and "[multiview]" in store.get_meta("config_text")
    res = runner.invoke(sweep_cli(), ["sweep", str(tmp_path / "tiny.toml"), "--backend", "serial", "--no-progress"])
    assert "ran 0, skipped 28" in res.output
    out = tmp_path / "report"
    res = runner.invoke(sweep_cli(), ["report", str(db), "-o", str(out)])
    assert res.exit_code == 0, res.output
    for name in ("table1.md", "table1.csv", "table2.md", "table2.csv", "settings.json", "README.md",
                 "paper_comparison.md"):
        assert (out / name).is_file(), name
    comparison = (out / "paper_comparison.md").read_text()
    assert "| ours: v1 | shape | laplacian_pair_mean (paper's measure) |" in comparison
    assert "| paper: DenseNet | shape |" in comparison and "## Beside the paper" in (out / "README.md").read_text()
    table1 = (out / "table1.md").read_text()
    assert "| v1 | shape | laplacian_pair_mean | yes |" in table1 and "| v1 | shape | laplacian_sum | no |" in table1
    assert "| v1 | texture | color_rmse | yes |" in table1
    assert "100.0%" in table1
    # the distortion tail: columns beside the cases, consistent with them, and the sentence naming what compares
    assert "| successes: median dist | successes: p90 dist | successes: max dist | successes above the paper's " \
           "worst |" in table1
    assert "The columns that compare with the paper's Table 1 are" in (out / "README.md").read_text()
    assert "The columns that compare with the paper are" in comparison
    import csv as csv_module

    checked = 0
    for row in csv_module.DictReader((out / "table1.csv").read_text().splitlines()):
        if row["tail_n"] in ("", "0"):
            continue
        assert float(row["tail_median"]) <= float(row["tail_p90"]) <= float(row["tail_max"])
        assert float(row["tail_max"]) >= float(row["average_distance"]) >= 0.0
        assert (row["tail_threshold"] != "nan") == (row["paper_measure"] == "True")
        checked += 1
    assert checked >= 3  # shape in both conventions and texture
    assert "45°–60°" in (out / "table2.md").read_text()
    assert "class -> target" in (out / "table2_per_class.md").read_text()
    # per class pair: each single-view job once, the same total as table1's instances x targets
    pairs = list(csv_module.DictReader((out / "table1_pairs.csv").read_text().splitlines()))
    assert sum(int(r["attacks"]) for r in pairs) == 24
    assert "### Table 1 by source and target class" in (out / "README.md").read_text()
    assert not (out / "table1_benign_correct.md").exists()  # every attacked benign render was classified right
    figs = {p.name for p in (out / "figures").glob("*.png")}
    assert figs == {"grid_v1_shape.png", "grid_v1_texture.png", "flow_heatmap_v1.png", "flow_quiver_v1.png",
                    "curvature_v1.png"}
    for name in figs:
        img = np.asarray(Image.open(out / "figures" / name).convert("L"), dtype=np.float64)
        assert img.shape[0] > 100 and img.std() > 1.0, f"{name} is blank"
    settings = json.loads((out / "settings.json").read_text())
    assert settings["counts"]["done"] == 28 and "python" in settings["report_versions"]
    # paths that travel with the folders: the database from the report, the config from the database
    assert settings["database"] == "../run/results.db"
    with ResultStore(db) as store:
        assert store.get_meta("config_path") == "../tiny.toml"
    assert "Pearson" in (out / "README.md").read_text()


def test_only_single_view_attacks_on_misclassified_renders_add_the_benign_correct_table() -> None:
    """A multi-view job on a misclassified benign render (they are not filtered) does not split Table 1."""
    from types import SimpleNamespace

    from meshadv.experiments.report import attacked_misclassified

    def row(kind: str, correct: bool, skipped: bool = False) -> SimpleNamespace:
        return SimpleNamespace(spec={"kind": kind}, record={"benign_correct": correct, "skipped": skipped})

    assert not attacked_misclassified([row("single", True), row("multiview", False), row("single", False, True)])
    assert attacked_misclassified([row("single", True), row("single", False)])


def test_report_counts_failed_and_unsuccessful_jobs(tmp_path: Path) -> None:
    jobs = [{**j, "success": j["source_class"] == "boat"} for j in probe_jobs(["boat", "chair"])]
    run_probe_sweep(tmp_path / "r.db", jobs, tmp_path)
    out = write_report(tmp_path / "r.db", tmp_path / "rep", figures=False)
    assert out.counts["successes"] == 1 and out.figures == []
    csv = (tmp_path / "rep" / "table1.csv").read_text().splitlines()
    row = dict(zip(csv[0].split(","), csv[1].split(",")))
    assert float(row["best_success_rate"]) == pytest.approx(0.5)
    with pytest.raises(FileNotFoundError, match="nope.db"):
        write_report(tmp_path / "nope.db", tmp_path / "rep")
    assert not (tmp_path / "rep" / "transfer.md").exists()
    # Mitsuba transfer rows in the same database join the report.
    from meshadv.transfer.results import save_transfer_rows

    row = {"case_id": "c", "victim": "v", "true_class": "boat", "target": "chair", "perturbation": "shape", "view": 0,
           "success_meshadv": True, "success_mitsuba": False, "untargeted_meshadv": True, "untargeted_mitsuba": True}
    save_transfer_rows(tmp_path / "r.db", [row], experiment="controlled")
    from meshadv.commands.report import write_full_report

    write_full_report(tmp_path / "r.db", tmp_path / "rep", figures=False)
    transfer = (tmp_path / "rep" / "transfer.md").read_text()
    assert "Transfer to Mitsuba 3" in transfer and "chair" in transfer
    assert "Transfer to Mitsuba 3" in (tmp_path / "rep" / "README.md").read_text()
    # A report only reads: the database file stays byte-identical and no file appears beside it.
    before, beside = (tmp_path / "r.db").read_bytes(), sorted(p.name for p in tmp_path.glob("r.db*"))
    result = CliRunner().invoke(sweep_cli(), ["report", str(tmp_path / "r.db"), "-o", str(tmp_path / "rep2"),
                                         "--no-figures"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "r.db").read_bytes() == before
    assert sorted(p.name for p in tmp_path.glob("r.db*")) == beside


def _ellipsoid() -> tuple:
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3)
    v = np.asarray(sphere.vertices) * np.array([1.0, 0.5, 0.3])
    return v, np.asarray(sphere.faces)


def test_curvature_correlation_is_measured(tmp_path: Path) -> None:
    v, f = _ellipsoid()
    curv = mean_curvature_np(v, f)
    assert curv.std() > 0
    # On an ellipsoid the mean curvature is largest at the tips of the long axis.
    assert curv[np.argmax(np.abs(v[:, 0]))] > curv[np.argmax(np.abs(v[:, 2]))]
    normals = v / np.linalg.norm(v, axis=1, keepdims=True)
    _, corr = curvature_scatter(v, v + 0.01 * curv[:, None] * normals, f, tmp_path / "c.png")
    assert corr["pearson"] == pytest.approx(1.0, abs=1e-6) and corr["spearman"] > 0.99
    rng = np.random.default_rng(0)
    _, corr = curvature_scatter(v, v + 0.01 * rng.normal(size=v.shape), f, tmp_path / "d.png", curvature=curv)
    assert abs(corr["pearson"]) < 0.3
    with pytest.raises(ValueError, match="curvature"):
        curvature_scatter(v, v, f, tmp_path / "e.png", curvature=curv[:-1])


def test_flow_figures_validate_and_draw(tmp_path: Path) -> None:
    v, f = _ellipsoid()
    va = v.copy()
    va[:10] += 0.05
    a = flow_heatmaps(v, va, f, tmp_path / "h.png", view=(30.0, 10.0), renderer="matplotlib")
    b = flow_quiver(v, va, f, tmp_path / "q.png", region=40)
    for path in (a, b):
        assert np.asarray(Image.open(path).convert("L")).std() > 1.0
    with pytest.raises(ValueError, match="vertices_adv"):
        flow_heatmaps(v, va[:-1], f, tmp_path / "x.png", view=(0.0, 0.0))
    with pytest.raises(ValueError, match="renderer"):
        flow_heatmaps(v, va, f, tmp_path / "x.png", view=(0.0, 0.0), renderer="opengl")
    with pytest.raises(ValueError, match="region"):
        flow_quiver(v, va, f, tmp_path / "x.png", region=0)


def test_view_record_follows_the_camera_convention() -> None:
    from meshadv.experiments.sweep_views import view_record

    rec = view_record(4.0, 90.0, 0.0)
    # eye = d (cos el sin az, sin el, -cos el cos az): azimuth 90 puts the camera on +x; the default light is there too
    assert rec["light_directions"][0] == pytest.approx([1.0, 0.0, 0.0], abs=1e-6)
    rec = view_record(4.0, 0.0, 90.0, light_azimuth=180.0, light_elevation=0.0)
    assert rec["light_directions"][0] == pytest.approx([0.0, 0.0, 1.0], abs=1e-6)
    assert rec["distance"] == 4.0 and rec["elevation"] == 90.0

