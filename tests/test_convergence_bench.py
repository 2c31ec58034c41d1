"""benchmarks/convergence_bench.py: per-setting options, instance selection and the curves it stores (no attack run)."""

from __future__ import annotations

import argparse
import json
import sqlite3
from pathlib import Path
from types import ModuleType
from typing import Optional

import pytest
from benchmark_scripts import load_benchmark


def _bench() -> ModuleType:
    return load_benchmark("convergence_bench")


def test_method_and_attack_options_reach_the_attack() -> None:
    cb = _bench()
    attack = cb.make_attack("ddn", "shape", {"gamma": 0.5, "smoothness": 0.3}, {"loss": "cw"})
    config = attack.config()
    assert config["method"] == "ddn" and config["steps"] == 300 and config["loss"] == "cw"
    assert config["method_options"]["gamma"] == 0.5 and config["method_options"]["smoothness"] == 0.3
    assert cb.make_attack("ddn", "shape").config()["method_options"]["gamma"] == 0.05
    with pytest.raises(ValueError, match="method_options"):
        cb.make_attack("small", "shape", {"gamma": 0.5})
    with pytest.raises(ValueError, match="gamma"):
        cb.make_attack("ddn", "shape", {"gamma": 2.0}).config()


def test_command_line_parsers_reject_bad_values() -> None:
    cb = _bench()
    assert cb._instance("sofa/1") == ("sofa", 1)
    assert cb._json_object('{"gamma": 0.9}') == {"gamma": 0.9}
    for bad in ("sofa", "car/0", "sofa/x"):
        with pytest.raises(argparse.ArgumentTypeError, match="CLASS/INDEX"):
            cb._instance(bad)
    for bad, match in (("[1]", "must be a JSON object"), ("{gamma: 1}", "not valid JSON")):
        with pytest.raises(argparse.ArgumentTypeError, match=match):
            cb._json_object(bad)


def test_options_need_their_own_database(tmp_path: Path) -> None:
    cb = _bench()
    with pytest.raises(SystemExit, match="own --db"):
        cb.main(["--methods", "ddn", "--method-options", '{"gamma": 0.9}'])


def test_only_keeps_the_chosen_instances() -> None:
    cb = _bench()
    every = cb.instances(2, cb.CLASSES)
    chosen = cb.instances(2, cb.CLASSES, [("sofa", 1), ("bottle", 0)])
    assert [(c, i) for c, i, _ in chosen] == [("bottle", 0), ("sofa", 1)]  # the benchmark's order
    assert all(job in every for job in chosen)


def test_curves_record_first_success_improvements_and_best_margin() -> None:
    cb = _bench()
    history = [{"margin": [-2.0, -1.0], "distance": [0.5, 0.1]},
               {"margin": [0.3, -0.4], "distance": [0.4, 0.2]},
               {"margin": [0.1, -0.9], "distance": [0.2, 0.3]},
               {"margin": [0.2, None], "distance": [0.3, None]}]
    first, second = cb._curves(history, 2)
    assert first == {"first": 2, "improvements": [[2, 0.4], [3, 0.2]], "best_margin": 0.3}
    assert second == {"first": None, "improvements": [], "best_margin": -0.4}


def _row(cls: str, pair_means: list, perturbation: str = "shape", displacements: Optional[list] = None,
         method: str = "ddn") -> dict:
    """A finished row of 10 steps whose targets first hold at step 2 with the given least distances (``None``:
    never held); shape curves store the Eq. 4 sum, 2E = 10 pairs."""
    scale = 10.0 if perturbation == "shape" else 1.0
    curves = [{"first": None, "improvements": []} if d is None else {"first": 2, "improvements": [[2, d * scale]]}
              for d in pair_means]
    moved = displacements or [0.0] * len(pair_means)
    return {"method": method, "perturbation": perturbation, "class": cls, "index": 0,
            "targets": [f"t{k}" for k in range(len(pair_means))], "num_edges": 5, "history_len": 10,
            "wall_time": 1.0, "curves": curves, "final_success": [d is not None for d in pair_means],
            "final_distances": [{"max_displacement": m} for m in moved]}


def test_summary_reports_the_distortion_tail() -> None:
    cb = _bench()
    a = _row("A", [k * 1e-5 for k in range(1, 7)], displacements=[k * 0.01 for k in range(1, 7)])
    b = _row("B", [7e-5, 8e-5, 9e-5, 1e-4, 1.2e-3, None], displacements=[0.07, 0.08, 0.09, 0.10, 0.11, 0.5])
    # one target first holds far above the paper's worst case and improves only at step 8
    b["curves"][4]["improvements"] = [[2, 2e-3 * 10.0], [8, 1.2e-3 * 10.0]]
    s = cb.summarize([a, b], "ddn", "shape", 10)
    tail, moved = s["tail"], s["displacement"]
    # 11 successes: 1e-5 .. 1e-4 and 1.2e-3: median the 6th, p90 at rank 9 of 0..10 (the 10th), max the broken mesh
    assert s["median_distance"] == pytest.approx(6e-5) and tail.median == pytest.approx(6e-5)
    assert tail.p90 == pytest.approx(1e-4) and tail.max == pytest.approx(1.2e-3)
    assert tail.above_n == 1 and tail.above == pytest.approx(1 / 11) and tail.threshold == pytest.approx(3e-4)
    # displacement in % of the diagonal over the 11 final successes (the failed target's 50% left out)
    assert moved.n == 11 and moved.median == pytest.approx(6.0) and moved.p90 == pytest.approx(10.0)
    early = cb.summarize([a, b], "ddn", "shape", 5)  # before step 8: the broken target is at 2e-3
    assert early["tail"].max == pytest.approx(2e-3) and early["displacement"].n == 0  # final results: full runs only
    text = cb.report([a, b], None)
    assert "| p90 distance at success | max distance at success | successes above the paper's worst case |" in text
    assert "| 0.0001 | 0.0012 | 9.1% (1/11) | 6% / 10% (11) |" in text
    assert "- ddn shape: 1: B/0 -> t4 0.0012" in text
    texture = cb.summarize([_row("C", [0.01, 0.02, 0.04, 0.05], "texture")], "ddn", "texture", 10)
    assert texture["tail"].above_n == 2 and texture["tail"].threshold == pytest.approx(0.032)
    assert texture["displacement"].n == 0


def _sweep_db(path: Path, jobs: list) -> Path:
    """A sweep results database holding the finished jobs ``(spec, record)`` (only the columns the import reads)."""
    con = sqlite3.connect(str(path))
    con.execute("CREATE TABLE jobs (job_id TEXT, spec TEXT, state TEXT, record TEXT)")
    con.executemany("INSERT INTO jobs VALUES (?, ?, 'done', ?)",
                    [(str(i), json.dumps(s), json.dumps(r)) for i, (s, r) in enumerate(jobs)])
    con.commit()
    con.close()
    return path


def test_import_sweep_takes_each_methods_complete_instances(tmp_path: Path) -> None:
    cb = _bench()

    def job(target: str, protocol: Optional[str], cls: str = "chair", victim: str = "efficientnet_lite0") -> tuple:
        attack = {"steps": 1000, "binary_search_steps": 5, "antialias": 2} if protocol else {"steps": 100}
        spec = {"kind": "single", "perturbation": "shape", "source_class": cls, "config_index": 0, "target": target,
                "victim": victim, "mesh": {"path": f"pascal3d/{cls}/01.ply"}, "attack": attack,
                **({"protocol": protocol} if protocol else {})}
        first = 40 if target != "sofa" else None
        record = {"success": first is not None, "steps_to_success": first, "steps": 5000 if protocol else 100,
                  "time": 2.0, "num_vertices": 10, "num_faces": 16,
                  "distances": {"laplacian_sum": 0.5, "laplacian_pair_mean": 1e-5, "num_edges": 24}}
        return spec, record

    others = [c for c in cb.CLASSES if c != "chair"]
    sweep = _sweep_db(tmp_path / "results.db", [
        *(job(t, "paper") for t in others),  # complete: imported
        *(job(t, None) for t in others),  # the main setting: a 'small' row, not a 'paper' one
        *(job(t, "paper", cls="sofa") for t in others[:3]),  # incomplete: left out
        *(job(t, "paper", victim="efficientnet_lite2") for t in others)])  # another victim: left out
    db = tmp_path / "bench.sqlite"
    assert cb.import_sweep(sweep, db, "paper") == 1
    (row,) = cb.load_rows(db)
    assert (row["method"], row["class"], row["index"], row["history_len"]) == ("paper", "chair", 0, 5000)
    assert row["config"] == {"steps": 1000, "binary_search_steps": 5} and row["final_success"].count(False) == 1
    assert [c["first"] for c in row["curves"]].count(40) == 5 and row["steps"] == 6 * 5000
    assert cb.import_sweep(sweep, db, "small") == 1 and len(cb.load_rows(db)) == 2
    con = sqlite3.connect(str(db))
    measured = dict(row, source=None)  # a row the benchmark measured itself is kept
    con.execute("UPDATE runs SET row = ? WHERE key = 'paper/shape/chair/0'", (json.dumps(measured),))
    con.commit()
    con.close()
    assert cb.import_sweep(sweep, db, "paper") == 0
