"""Sweep files that take their rendering configurations from a PASCAL3D+ rendering set."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from meshadv.datasets.rendering_set import FORMAT, VERSION, packaged_rendering_set_path
from meshadv.experiments.config import expand_jobs, parse_config


def _view(azimuth: float) -> dict[str, Any]:
    return {"distance": 4.0, "azimuth": azimuth, "elevation": 10.0, "tilt": 0.0, "viewing_angle": 30.0,
            "light_directions": [[0.0, 0.0, -1.0]], "light_colors": [[0.5, 0.5, 0.5]], "ambient": [0.5, 0.5, 0.5]}


def _write_set(path: Path, records: list[tuple[str, str, float]]) -> Path:
    doc = {"format": FORMAT, "version": VERSION, "complete": True, "config": {}, "classes": {},
           "renderings": [{"class": cls, "mesh": mesh, "candidate": i, "view": _view(az)}
                          for i, (cls, mesh, az) in enumerate(records)]}
    path.write_text(json.dumps(doc))
    return path


def _config(**render: Any) -> dict[str, Any]:
    return {"meshes": {"classes": ["chair", "sofa"]}, "render": {"image_size": 64, **render},
            "victims": {"names": ["efficientnet_lite0"]}, "attack": {"types": ["texture"]}}


RECORDS = [("chair", "pascal3d/chair/03.ply", 10.0), ("sofa", "pascal3d/sofa/01.ply", 20.0),
           ("chair", "pascal3d/chair/01.ply", 30.0), ("chair", "pascal3d/chair/03.ply", 40.0),
           ("sofa", "pascal3d/sofa/02.ply", 50.0), ("bottle", "pascal3d/bottle/01.ply", 60.0)]


def test_jobs_take_mesh_and_view_from_the_set_in_order(tmp_path: Path) -> None:
    """Each class's configurations are its kept records in set order; jobs run configuration-major (configuration 0
    of every class first), so a partial sweep covers every class."""
    _write_set(tmp_path / "set.json", RECORDS)
    cfg = parse_config(_config(rendering_set="set.json", configurations=2), base_dir=tmp_path)
    jobs = expand_jobs(cfg)
    assert len(jobs) == 4  # 2 classes x 2 configurations x 1 target (the other class) x 1 type
    got = [(j["source_class"], j["mesh"]["path"], j["views"][0]["azimuth"], j["config_index"], j["target"])
           for j in jobs]
    assert got == [
        ("chair", "pascal3d/chair/03.ply", 10.0, 0, "sofa"),
        ("sofa", "pascal3d/sofa/01.ply", 20.0, 0, "chair"),
        ("chair", "pascal3d/chair/01.ply", 30.0, 1, "sofa"),
        ("sofa", "pascal3d/sofa/02.ply", 50.0, 1, "chair"),
    ]
    assert all(j["mesh"]["source"] == "pascal3d" and j["image_size"] == 64 for j in jobs)


def test_models_restrict_the_records(tmp_path: Path) -> None:
    _write_set(tmp_path / "set.json", RECORDS)
    raw = _config(rendering_set="set.json", configurations=1)
    raw["meshes"]["models"] = {"chair": ["01"]}
    jobs = expand_jobs(parse_config(raw, base_dir=tmp_path))
    assert [(j["mesh"]["path"], j["views"][0]["azimuth"]) for j in jobs] == [
        ("pascal3d/chair/01.ply", 30.0), ("pascal3d/sofa/01.ply", 20.0)]


def test_bad_rendering_set_configs(tmp_path: Path) -> None:
    _write_set(tmp_path / "set.json", RECORDS)
    with pytest.raises(ValueError, match="fewer than render.configurations"):
        expand_jobs(parse_config(_config(rendering_set="set.json", configurations=3), base_dir=tmp_path))
    with pytest.raises(FileNotFoundError, match="missing.json"):
        expand_jobs(parse_config(_config(rendering_set="missing.json", configurations=1), base_dir=tmp_path))
    with pytest.raises(ValueError, match="render.rendering_set"):
        parse_config(_config(rendering_set=3))
    raw = _config(rendering_set="set.json")
    raw["meshes"] = {"source": "builtin", "builtin": [{"name": "chair", "class": "chair"}]}
    with pytest.raises(ValueError, match="meshes.source"):
        parse_config(raw, base_dir=tmp_path)
    _write_set(tmp_path / "abs.json", [("chair", "/abs/chair.ply", 0.0), ("sofa", "/abs/sofa.ply", 0.0)])
    with pytest.raises(ValueError, match="relative"):
        expand_jobs(parse_config(_config(rendering_set="abs.json", configurations=1), base_dir=tmp_path))


def test_packaged_set_expands_to_the_papers_72_per_class() -> None:
    if not packaged_rendering_set_path().is_file():  # pragma: no cover - raises instead
        pytest.fail("packaged set missing")
    raw = {"render": {"rendering_set": "packaged"}, "victims": {"names": ["efficientnet_lite0"]},
           "attack": {"types": ["shape", "texture"]}}
    jobs = expand_jobs(parse_config(raw))
    assert len(jobs) == 7 * 72 * 2 * 6  # classes x configurations x types x targets: Table 1's protocol
    assert len({(j["mesh"]["path"], json.dumps(j["views"][0])) for j in jobs}) == 7 * 72


def test_victim_caps_protocols_grid_and_per_class_targets(tmp_path: Path) -> None:
    """paper_medium's keys: a per-victim configuration cap, an extra protocol on a subset, the 3 x 3 multi-view grid
    and one multi-view target per class."""
    _write_set(tmp_path / "set.json", RECORDS)
    raw = _config(rendering_set="set.json", configurations=2)
    raw["victims"] = {"names": ["v0", "v2"], "configurations": {"v2": 1}}
    raw["attack"] = {"types": ["texture"], "texture": {"steps": 5},
                     "protocols": {"paper": {"configurations": 1, "victims": ["v0"], "texture": {"steps": 50}}}}
    raw["multiview"] = {"enabled": True, "grid": True, "view_counts": [5, 10], "azimuth_ranges": [[45, 60], [15, 75]],
                        "eval_views": 2, "types": ["shape"], "victims": ["v0"], "targets": {"chair": "sofa"}}
    jobs = expand_jobs(parse_config(raw, base_dir=tmp_path))
    single = [j for j in jobs if j["kind"] == "single"]
    main = [(j["victim"], j["config_index"]) for j in single if "protocol" not in j]
    assert sorted(main) == sorted([("v0", 0), ("v0", 1), ("v2", 0)] * 2)  # 2 classes; v2 capped at 1 configuration
    paper = [j for j in single if j.get("protocol") == "paper"]
    assert [(j["victim"], j["config_index"], j["attack"]["steps"]) for j in paper] == [("v0", 0, 50)] * 2
    mv = [j for j in jobs if j["kind"] == "multiview"]
    assert {(j["num_views"], tuple(j["azimuth_range"])) for j in mv} == {
        (5, (45.0, 60.0)), (5, (15.0, 75.0)), (10, (45.0, 60.0)), (10, (15.0, 75.0))}
    assert {(j["source_class"], j["target"], j["victim"]) for j in mv} == {("chair", "sofa", "v0")}
    with pytest.raises(ValueError, match="victims.configurations"):
        parse_config({**raw, "victims": {"names": ["v0"], "configurations": {"v0": 0}}}, base_dir=tmp_path)
    assert {j["benign_correct_only"] for j in mv} == {False}  # multi-view jobs attack every mesh by default
    filtered = {**raw, "multiview": {**raw["multiview"], "benign_correct_only": True}}
    assert {j["benign_correct_only"] for j in expand_jobs(parse_config(filtered, base_dir=tmp_path))
            if j["kind"] == "multiview"} == {True}
    with pytest.raises(ValueError, match="multiview.benign_correct_only"):
        parse_config({**raw, "multiview": {**raw["multiview"], "benign_correct_only": "yes"}}, base_dir=tmp_path)
    listed = {**raw, "multiview": {**raw["multiview"], "targets": {"chair": ["sofa", "chair", "bottle"]}}}
    assert sorted({j["target"] for j in expand_jobs(parse_config(listed, base_dir=tmp_path))
                   if j["kind"] == "multiview"}) == ["bottle", "sofa"]  # a class is never its own target
    for bad in ({"chair": []}, {"chair": 3}, "sofa"):
        with pytest.raises(ValueError, match="multiview.targets must be"):
            parse_config({**raw, "multiview": {**raw["multiview"], "targets": bad}}, base_dir=tmp_path)
    with pytest.raises(ValueError, match="attack.benign_correct_only must be true or false, got 0"):
        parse_config({**raw, "attack": {**raw["attack"], "benign_correct_only": 0}}, base_dir=tmp_path)


def test_paper_medium_has_the_issue_scale() -> None:
    """configs/paper_medium.toml: >= 1,344 targeted attacks (14 configurations per class for Lite0, so that at least
    12 stay once the benign-wrong ones are skipped; 4 for Lite2), the paper's protocol on 2 configurations per
    class, and Table 2 for every class over the 3 x 3 grid."""
    from meshadv.experiments.config import load_config

    jobs = expand_jobs(load_config(Path(__file__).parents[1] / "configs" / "paper_medium.toml"))
    main = [j for j in jobs if j["kind"] == "single" and "protocol" not in j]
    assert len(main) == 7 * 6 * 2 * (14 + 4) == 1512
    per_class = {(j["victim"], j["source_class"]): set() for j in main}
    for j in main:
        per_class[(j["victim"], j["source_class"])].add(j["config_index"])
    assert {v: len(c) for (v, _), c in per_class.items()} == {"efficientnet_lite0": 14, "efficientnet_lite2": 4}
    assert len([j for j in jobs if j.get("protocol") == "paper"]) == 7 * 2 * 6 * 2
    mv = [j for j in jobs if j["kind"] == "multiview"]
    assert len({j["source_class"] for j in mv}) == 7 and len(mv) == 7 * 9 * 2
    # class-balanced order: configuration 0 of all 7 classes for Lite0 (2 types x 6 targets each), then for Lite2,
    # then configuration 1
    first, second = jobs[:7 * 2 * 6], jobs[7 * 2 * 6:7 * 2 * 6 * 2]
    for part, victim in ((first, "efficientnet_lite0"), (second, "efficientnet_lite2")):
        assert {(j["config_index"], j["victim"]) for j in part} == {(0, victim)}
        assert len({j["source_class"] for j in part}) == 7
    assert (jobs[2 * len(first)]["config_index"], jobs[2 * len(first)]["victim"]) == (1, "efficientnet_lite0")
    # the main setting is the recommended minimal-distortion attack; the paper's protocol stays Adam, 5 x 1000 steps
    assert {(j["perturbation"], j["attack"].get("method"), j["attack"]["steps"]) for j in main + mv} == {
        ("shape", "ddn", 300), ("texture", "ddn", 100)}
    assert {(j["attack"].get("method", "adam"), j["attack"]["steps"], j["attack"]["binary_search_steps"])
            for j in jobs if j.get("protocol") == "paper"} == {("adam", 1000, 5)}


def test_paper_medium_robust_runs_the_robust_attack_at_the_issue_scale() -> None:
    """configs/paper_medium_robust.toml: >= 300 shape attacks for Table 3 and the 3 x 3 Table 2 grid on every
    shared model with two targets per class, the paper's first (the benign filter leaves 12-19 of the 50 meshes
    per cell), every job benign-filtered and carrying the robust attack's options (robust_options("shape",
    "ddn")) at ddn's 300 steps."""
    from meshadv.attacks.robust_settings import robust_options
    from meshadv.experiments.config import load_config

    jobs = expand_jobs(load_config(Path(__file__).parents[1] / "configs" / "paper_medium_robust.toml"))
    single = [j for j in jobs if j["kind"] == "single"]
    mv = [j for j in jobs if j["kind"] == "multiview"]
    assert len(single) >= 300 and {j["perturbation"] for j in jobs} == {"shape"}
    cells: dict[tuple[int, tuple[float, ...]], int] = {}
    for j in mv:
        key = (j["num_views"], tuple(j["azimuth_range"]))
        cells[key] = cells.get(key, 0) + 1
    assert len(cells) == 9 and set(cells.values()) == {50 * 2}
    paper_targets = {"aeroplane": "bicycle", "bicycle": "boat", "boat": "bottle", "bottle": "chair",
                     "chair": "sofa", "diningtable": "sofa", "sofa": "chair"}
    for cls, target in paper_targets.items():
        mine = [j["target"] for j in mv if j["source_class"] == cls and j["num_views"] == 5]
        assert len(set(mine)) == 2 and mine[0] == target
    assert all(len(j["eval_views"]) == 20 for j in mv)
    assert {j["benign_correct_only"] for j in jobs} == {True}
    robust = robust_options("shape", "ddn")
    for j in jobs:
        assert j["attack"]["method"] == "ddn" and j["attack"]["steps"] == 300
        assert {k: j["attack"][k] for k in robust} == robust


def test_multiview_jobs_are_cell_major_and_parts_select() -> None:
    """Table 2's jobs run the first (view count, azimuth range) cell of every class before the next cell, and
    select_parts keeps one part of the sweep in order, refusing a part the sweep does not have."""
    from meshadv.experiments.config import job_part, load_config, select_parts

    jobs = expand_jobs(load_config(Path(__file__).parents[1] / "configs" / "paper_medium.toml"))
    mv = select_parts(jobs, ["multiview"])
    assert mv == [j for j in jobs if j["kind"] == "multiview"] and len(mv) == 126
    first_cell = mv[:7 * 2]  # 7 classes x 2 types
    assert {(j["num_views"], tuple(j["azimuth_range"])) for j in first_cell} == {(5, (45.0, 60.0))}
    assert len({j["source_class"] for j in first_cell}) == 7
    assert [j["num_views"] for j in mv] == sorted(j["num_views"] for j in mv)
    paper = select_parts(jobs, ["paper", "main"])
    assert {job_part(j) for j in paper} == {"paper", "main"} and len(paper) == 1512 + 168
    with pytest.raises(ValueError, match=r"parts \['table2'\].*'multiview'"):
        select_parts(jobs, ["table2"])


def test_multiview_jobs_with_several_meshes_per_class_cover_every_cell_first() -> None:
    """With several meshes per class, Table 2's jobs run the first mesh of every class in every cell (cell-major)
    before any class's second mesh, so a sweep stopped part-way has attacks in every cell."""
    from meshadv.experiments.config import load_config, select_parts

    jobs = select_parts(expand_jobs(load_config(Path(__file__).parents[1] / "configs" / "paper_medium_robust.toml")),
                        ["multiview"])
    assert len(jobs) == 50 * 2 * 9
    first_round = jobs[:7 * 2 * 9]  # 7 classes x 2 targets x 9 cells
    assert {Path(j["mesh"]["path"]).stem for j in first_round} == {"01"}
    assert len({(j["num_views"], tuple(j["azimuth_range"]), j["source_class"], j["target"])
                for j in first_round}) == len(first_round)
    cells = [(j["num_views"], tuple(j["azimuth_range"])) for j in first_round]
    grid = [(n, r) for n in (5, 10, 15) for r in ((45.0, 60.0), (35.0, 70.0), (15.0, 75.0))]
    assert cells == [cell for cell in grid for _ in range(7 * 2)]
    assert Path(jobs[7 * 2 * 9]["mesh"]["path"]).stem == "02"


def test_sweep_only_names_the_option_on_a_bad_part(tmp_path: Path) -> None:
    """``meshadv sweep --only`` with a part the sweep lacks is a usage error naming --only, before any job runs."""
    from meshadv.cli import app
    from typer.testing import CliRunner

    config = Path(__file__).parents[1] / "configs" / "paper_medium.toml"
    result = CliRunner().invoke(app, ["sweep", str(config), "--only", "table2", "--db", str(tmp_path / "r.db"),
                                      "--dry-run"])
    assert result.exit_code == 2 and "--only" in result.output and "table2" in result.output
    assert not (tmp_path / "r.db").exists()


def test_select_where_keeps_the_jobs_matching_every_condition() -> None:
    """``--where`` conditions pick jobs by spec entries (dotted for nested ones, numbers by their text,
    ``protocol=main`` for the main setting) in the sweep's order; a key no job has is refused, naming it."""
    from meshadv.experiments.config import load_config, parse_where, select_parts, select_where

    jobs = expand_jobs(load_config(Path(__file__).parents[1] / "configs" / "paper_medium.toml"))
    picked = select_where(jobs, parse_where(["source_class=sofa", "target=bicycle", "protocol=paper",
                                             "config_index=0"]))
    assert [(j["perturbation"], j["mesh"]["class"]) for j in picked] == [("shape", "sofa"), ("texture", "sofa")]
    assert picked == [j for j in select_parts(jobs, ["paper"]) if j["source_class"] == "sofa"
                      and j["target"] == "bicycle" and j["config_index"] == 0]
    main_chairs = select_where(jobs, parse_where(["protocol=main", "mesh.class=chair", " perturbation = shape"]))
    assert len(main_chairs) == (14 + 4) * 6 and {j.get("protocol") for j in main_chairs} == {None}
    assert select_where(jobs, parse_where(["target=unicorn"])) == []
    with pytest.raises(ValueError, match="no job of this sweep has 'colour'"):
        select_where(jobs, parse_where(["colour=red"]))
    with pytest.raises(ValueError, match="expected KEY=VALUE"):
        parse_where(["sofa"])


def test_sweep_where_runs_only_the_matching_jobs_and_names_the_option(tmp_path: Path, shared_data: Path) -> None:
    """``meshadv sweep --where`` counts only the matching jobs, and a bad condition is a usage error naming
    --where before any database is made (the config's meshes are the shared PASCAL3D+ files)."""
    from meshadv.cli import app
    from typer.testing import CliRunner

    config = Path(__file__).parents[1] / "configs" / "paper_medium.toml"
    base = ["sweep", str(config), "--db", str(tmp_path / "r.db"), "--dry-run"]
    result = CliRunner().invoke(app, [*base, "--only", "paper", "--where", "target=bicycle", "--where",
                                      "perturbation=shape"])
    assert result.exit_code == 0 and result.output.startswith("12 jobs (12 single-view, 0 multi-view)")
    for bad in ("sofa", "colour=red"):
        result = CliRunner().invoke(app, [*base, "--where", bad])
        assert result.exit_code == 2 and "--where" in result.output
    assert not (tmp_path / "r.db").exists()
