"""An extra protocol's attacks paired with the main attack's on the same inputs (meshadv.experiments.protocols)."""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any, Dict, Optional

from meshadv.experiments import ResultStore, job_id
from meshadv.experiments.protocols import protocol_pairs, protocol_section, protocol_summary
from meshadv.experiments.report import write_report


def _job(target: str, success: bool, distance: float, *, protocol: Optional[str] = None, config: int = 0,
         perturbation: str = "shape", victim: str = "v", displacement: float = 0.01, cpu: float = 10.0,
         method: str = "ddn", **spec_extra: Any) -> Dict[str, Any]:
    """A finished single-view job as the report reads it."""
    measure = "laplacian_pair_mean" if perturbation == "shape" else "color_rmse"
    spec = {"kind": "single", "mesh": {"source": "pascal3d", "path": "pascal3d/chair/01.ply", "class": "chair"},
            "config_index": config, "seed": 0, "victim": victim, "perturbation": perturbation,
            "source_class": "chair", "target": target, **spec_extra}
    if protocol:
        spec["protocol"] = protocol
    distances = {measure: distance}
    if perturbation == "shape":
        distances["max_displacement"] = displacement
    record = {"success": success, "distances": distances, "cpu_time": cpu, "time": cpu + 1.0,
              "steps_to_success": 7 if success else None, "attack_config": {"method": method}}
    return {"spec": spec, "record": record}


def test_pairs_match_victim_type_instance_and_target() -> None:
    jobs = [
        _job("sofa", True, 1e-5), _job("sofa", True, 4e-5, protocol="paper", method="adam"),
        _job("boat", True, 2e-5), _job("boat", False, 9e-5, protocol="paper", method="adam"),
        _job("bottle", True, 1e-5, protocol="paper"),  # no main attack of this target: not paired
        _job("sofa", True, 1e-5, config=1),  # another instance, no extra protocol there
        _job("sofa", True, 1e-5, victim="w", protocol="paper"),  # another victim: no main counterpart
        _job("sofa", True, 1e-5, perturbation="texture", protocol="paper"),  # another type: none either
    ]
    pairs = protocol_pairs(jobs)
    assert [(p.target, p.main.distance, p.extra.distance) for p in pairs] == [("boat", 2e-5, 9e-5),
                                                                              ("sofa", 1e-5, 4e-5)]
    assert all(p.protocol == "paper" and p.instance == "pascal3d/chair/01.ply#0" for p in pairs)
    assert (pairs[1].main.method, pairs[1].extra.method) == ("ddn", "adam")


def test_skipped_multiview_and_unfinished_jobs_are_left_out() -> None:
    skipped = _job("sofa", False, 0.0, protocol="paper")
    skipped["record"]["skipped"] = True
    multiview = _job("sofa", True, 1e-5, protocol="paper", kind="multiview")
    unfinished = {"spec": _job("sofa", True, 1e-5, protocol="paper")["spec"], "record": None}
    assert protocol_pairs([_job("sofa", True, 1e-5), skipped, multiview, unfinished]) == []


def test_summary_counts_medians_and_ratios_over_attacks_both_reached() -> None:
    jobs = [_job("sofa", True, 1e-5, displacement=0.01, cpu=10.0),
            _job("sofa", True, 3e-5, protocol="paper", displacement=0.2, cpu=500.0, method="adam"),
            _job("boat", True, 4e-5, displacement=0.03, cpu=20.0),
            _job("boat", True, 2e-5, protocol="paper", displacement=0.1, cpu=400.0, method="adam"),
            _job("table", False, 5e-5, cpu=30.0),
            _job("table", True, 6e-5, protocol="paper", displacement=0.3, cpu=600.0, method="adam")]
    (summary,) = protocol_summary(protocol_pairs(jobs))
    assert (summary.pairs, summary.instances, summary.main_successes, summary.extra_successes) == (3, 1, 2, 3)
    assert (summary.both, summary.extra_lower) == (2, 1)  # boat: 2e-5 < 4e-5; sofa: 3e-5 > 1e-5
    assert math.isclose(summary.main_distance, 2.5e-5) and math.isclose(summary.extra_distance, 2.5e-5)
    assert math.isclose(summary.distance_ratio, (3.0 + 0.5) / 2)  # median of the two ratios
    assert math.isclose(summary.main_displacement, 0.02) and math.isclose(summary.extra_displacement, 0.15)
    assert (summary.main_cpu_s, summary.extra_cpu_s) == (20.0, 500.0)  # over every pair, the miss included
    assert (summary.main_method, summary.extra_method) == ("ddn", "adam")


def test_texture_summary_has_no_displacement() -> None:
    jobs = [_job("sofa", True, 0.01, perturbation="texture"),
            _job("sofa", True, 0.05, perturbation="texture", protocol="paper")]
    (summary,) = protocol_summary(protocol_pairs(jobs))
    assert math.isnan(summary.main_displacement) and math.isnan(summary.extra_displacement)
    assert math.isclose(summary.distance_ratio, 5.0)


def test_section_writes_the_summary_every_pair_and_a_csv(tmp_path: Path) -> None:
    jobs = [_job("sofa", True, 1e-5), _job("sofa", False, 4e-5, protocol="paper"),
            _job("sofa", True, 0.01, perturbation="texture"),
            _job("sofa", True, 0.05, perturbation="texture", protocol="paper")]
    text, files = protocol_section(jobs, tmp_path)
    assert [f.name for f in files] == ["protocols.md", "protocols.csv"]
    assert "| v | shape | paper | ddn, ddn | 1 (1) | 1/1 | 0/1 | 0 | 0/0 |" in text
    detail = (tmp_path / "protocols.md").read_text()
    assert "**no**" in detail  # the protocol's miss stands out
    assert detail.count("attack by attack") == 2  # one table per type
    rows = list(csv.DictReader(io.StringIO((tmp_path / "protocols.csv").read_text())))
    assert len(rows) == 2 and rows[0]["main_success"] == "True" and rows[0]["extra_success"] == "False"
    assert rows[1]["main_max_displacement"] == ""  # texture: no displacement


def test_no_extra_protocol_no_section(tmp_path: Path) -> None:
    assert protocol_section([_job("sofa", True, 1e-5)], tmp_path) == ("", [])
    assert list(tmp_path.iterdir()) == []


def test_report_includes_the_section_when_the_sweep_ran_a_protocol(tmp_path: Path) -> None:
    db = tmp_path / "results.db"
    jobs = [_job("sofa", True, 1e-5), _job("sofa", True, 4e-5, protocol="paper", method="adam")]
    with ResultStore(db) as store:
        store.add_jobs([j["spec"] for j in jobs])
        for j in jobs:
            store.mark_running(job_id(j["spec"]))
            store.mark_done(job_id(j["spec"]), j["record"])
    out = write_report(db, tmp_path / "report", figures=False)
    assert tmp_path / "report" / "protocols.md" in out.tables
    readme = (tmp_path / "report" / "README.md").read_text()
    assert "An extra protocol beside the main attack" in readme and "| v | shape | paper | ddn, adam |" in readme
