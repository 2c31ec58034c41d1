"""benchmarks/attack_defaults_bench.py: the numbers it reads from a run folder and its table (no attack run)."""

from __future__ import annotations

import json
from pathlib import Path

from benchmark_scripts import load_benchmark


def _folder(tmp_path: Path) -> Path:
    folder = tmp_path / "bottle_04_default"
    folder.mkdir()
    record = {
        "succeeded": [False], "inside_cap": [True], "interrupted": False, "steps": 300,
        "success": [[True, True, True, True, False]], "eval_success": [[True, False, False, True, False, False,
                                                                        False, False]],
        "held_out_rate": [0.25], "wall_time": 419.5, "num_faces": 4003,
        "distances": [{"max_displacement": 0.0048, "normal_change_p95_deg": 6.3, "edge_strain_p95": 0.026,
                       "laplacian_pair_mean": 3.46e-6,
                       "ssim_held_out_min": 0.907}],
    }
    (folder / "result.json").write_text(json.dumps(record))
    rows = [{"success_mitsuba": v < 1, "untargeted_mitsuba": v == 2, "benign_correct_mitsuba": v != 3}
            for v in range(5)]
    (folder / "transfer.json").write_text(json.dumps({"rows": rows}))
    (folder / "wall.json").write_text(json.dumps({"wall_s": 450.0}))
    return folder


def test_summary_row_reads_the_verdicts_distortion_and_mitsuba_counts(tmp_path: Path) -> None:
    bench = load_benchmark("attack_defaults_bench")
    row = bench.summary_row("bottle/04", "water jug", "default", _folder(tmp_path))
    assert row["attack_views"] == "4/5" and row["held_out"] == "2/8" and row["held_out_rate"] == 0.25
    assert row["succeeded"] is False and row["wall_s"] == 450.0 and row["attack_wall_s"] == 419.5
    assert row["mitsuba_targeted"] == "1/5"
    assert row["mitsuba_untargeted"] == "1/4"  # view 3's benign Mitsuba render is wrong: left out
    table = bench.markdown([row, bench.summary_row("sofa/03", "chest", "eot4", tmp_path / "missing")])
    lines = table.splitlines()
    assert len(lines) == 4 and lines[0].count("|") == lines[1].count("|") == lines[2].count("|")
    assert "| bottle/04 -> water jug | default | no | 4/5 | 2/8 | 1/5 | 1/4 | 0.48% | 6.3 | 0.026 |" in lines[2]
    assert "sofa/03 -> chest | eot4 | no | - |" in lines[3]


def test_cases_are_distinct_meshes_of_four_classes_each_with_one_target() -> None:
    bench = load_benchmark("attack_defaults_bench")
    meshes = [mesh for mesh, _ in bench.CASES]
    assert len(set(meshes)) == len(meshes) == 5
    assert {mesh.split("/")[0] for mesh in meshes} == {"aeroplane", "bottle", "sofa", "chair"}
