"""Table 1's three cases and Table 2, computed from hand-made result rows."""

from __future__ import annotations

import math

import pytest

from meshadv.experiments.tables import AttackRow, PairSuccess, attack_rows, pair_success, table1, table2
from meshadv.experiments.tables import labelled_by_protocol, pair_success_markdown, to_csv, to_markdown


def _row(inst: str, target: str, success: bool, dist: float, victim: str = "v", ptype: str = "shape") -> AttackRow:
    return AttackRow(victim=victim, perturbation=ptype, instance=(inst,), source="src", target=target,
                     success=success, distance=dist, measure="color_rmse" if ptype == "texture" else "laplacian_sum")


def test_three_cases_by_hand() -> None:
    rows = [
        # instance A: every target succeeds
        _row("A", "t1", True, 1.0), _row("A", "t2", True, 3.0), _row("A", "t3", True, 2.0),
        # instance B: one target fails
        _row("B", "t1", True, 5.0), _row("B", "t2", False, 9.0), _row("B", "t3", True, 4.0),
        # instance C: every target fails
        _row("C", "t1", False, 7.0), _row("C", "t2", False, 8.0), _row("C", "t3", False, 6.0),
    ]
    (t,) = table1(rows)
    assert (t.instances, t.targets, t.incomplete) == (3, 3, 0)
    # best: A and B succeed (any target); distances min over successful targets: 1 and 4
    assert t.best.success_rate == pytest.approx(2 / 3)
    assert t.best.distance == pytest.approx((1.0 + 4.0) / 2)
    # worst: only A has every target; its distance is the max, 3
    assert t.worst.success_rate == pytest.approx(1 / 3)
    assert t.worst.distance == pytest.approx(3.0)
    # average: per-instance fractions 1, 2/3, 0; distance over all successful attacks 1,3,2,5,4
    assert t.average.success_rate == pytest.approx((1 + 2 / 3 + 0) / 3)
    assert t.average.distance == pytest.approx((1 + 3 + 2 + 5 + 4) / 5)


def test_groups_and_incomplete_instances() -> None:
    rows = [
        _row("A", "t1", True, 1.0, ptype="texture"), _row("A", "t2", True, 2.0, ptype="texture"),
        _row("B", "t1", True, 0.5, ptype="texture"),  # B is missing t2: not in best / worst
        _row("A", "t1", False, 1.0, victim="w"), _row("A", "t2", False, 1.0, victim="w"),
    ]
    tex, w = (r for r in sorted(table1(rows), key=lambda r: r.victim))
    assert tex.perturbation == "texture" and tex.distance_name == "color_rmse"
    assert tex.incomplete == 1 and tex.best.n == 1 and tex.worst.n == 1
    assert tex.best.distance == pytest.approx(1.0) and tex.worst.distance == pytest.approx(2.0)
    assert tex.average.n == 2 and tex.average.distance == pytest.approx((1 + 2 + 0.5) / 3)
    assert w.best.success_rate == 0.0 and math.isnan(w.best.distance)
    md = to_markdown([tex, w])
    assert "| v | texture | color_rmse | yes | 1 | 100.0% |" in md and "1 incomplete" in md
    csv = to_csv([tex, w]).splitlines()
    assert csv[0].startswith("victim,perturbation,distance_name,instances,incomplete,targets,best_success_rate")
    assert len(csv) == 3


def test_attack_rows_from_job_records() -> None:
    mesh = {"source": "pascal3d", "path": "pascal3d/chair/01.ply", "class": "chair"}
    jobs = [
        {"spec": {"kind": "single", "mesh": mesh, "config_index": 0, "seed": 0, "victim": "v", "perturbation": "shape",
                  "source_class": "chair", "target": "sofa"},
         "record": {"success": True, "distance": 9.0, "distances": {"laplacian_sum": 0.25, "laplacian_pair_mean": 0.01,
                                                                      "color_rmse": 0.0}}},
        {"spec": {"kind": "single", "mesh": mesh, "config_index": 1, "seed": 0, "victim": "v",
                  "perturbation": "texture", "source_class": "chair", "target": "sofa"},
         "record": {"skipped": True, "success": False}},
        {"spec": {"kind": "single", "mesh": mesh, "config_index": 2, "seed": 0, "victim": "v", "perturbation": "shape",
                  "source_class": "chair", "target": "boat"}, "record": None},
    ]
    pair, total = attack_rows(jobs)
    assert (pair.measure, pair.distance, total.measure, total.distance) == ("laplacian_pair_mean", 0.01,
                                                                            "laplacian_sum", 0.25)
    assert pair.success and pair.instance == ("pascal3d/chair/01.ply", 0, 0)
    pair_row, sum_row = table1([pair, total])
    assert pair_row.paper_measure and not sum_row.paper_measure
    assert pair_row.best.success_rate == sum_row.best.success_rate == 1.0


def test_old_records_read_both_conventions() -> None:
    """A record written before both conventions (one key ``laplacian``, the Eq. 4 sum) still fills the tables."""
    mesh = {"source": "pascal3d", "path": "p.ply", "class": "chair"}
    spec = {"kind": "single", "mesh": mesh, "config_index": 0, "seed": 0, "victim": "v", "perturbation": "shape",
            "source_class": "chair", "target": "sofa"}
    old = [{"spec": spec, "record": {"success": True, "distances": {"laplacian": 0.5, "color_rmse": 0.0}}}]
    pair, total = attack_rows(old)
    assert total.distance == 0.5 and pair.distance is None  # the edge count is unknown: no per-pair mean
    with_edges = [{"spec": spec, "record": {"success": True, "distances": {"laplacian": 0.5, "num_edges": 5}}}]
    assert attack_rows(with_edges)[0].distance == pytest.approx(0.05)


def test_table2_by_hand() -> None:
    def job(n: int, rng: list, success: bool, rate: float) -> dict:
        return {"spec": {"kind": "multiview", "victim": "v", "perturbation": "shape", "num_views": n,
                         "azimuth_range": rng}, "record": {"success": success, "eval_success_rate": rate}}

    jobs = [job(5, [45, 60], True, 0.5), job(5, [45, 60], False, 0.1), job(10, [35, 70], True, 0.9),
            {"spec": {"kind": "single"}, "record": {"success": True}}]
    five, ten = table2(jobs)
    assert (five.num_views, five.attacks) == (5, 2)
    assert five.attack_view_success == pytest.approx(0.5) and five.unseen_success == pytest.approx(0.3)
    assert ten.unseen_success == pytest.approx(0.9) and ten.azimuth_range == (35.0, 70.0)
    assert "35°–70°" in to_markdown([five, ten])


def test_table2_per_class_splits_a_cell_by_class() -> None:
    """per_class gives one row per (class, target) within a cell; the pooled table keeps one row per cell."""
    def job(source: str, target: str, rate: float) -> dict:
        return {"spec": {"kind": "multiview", "victim": "v", "perturbation": "shape", "num_views": 5,
                         "azimuth_range": [45, 60], "source_class": source, "target": target},
                "record": {"success": True, "eval_success_rate": rate, "benign_correct": source == "sofa"}}

    jobs = [job("chair", "sofa", 0.2), job("sofa", "chair", 0.6), job("chair", "sofa", 0.4)]
    (pooled,) = table2(jobs)
    assert pooled.attacks == 3 and pooled.unseen_success == pytest.approx(0.4) and pooled.pair == ""
    assert pooled.benign_correct == 1  # only the sofa's benign views were all classified right
    assert pooled.benign_all_views is None  # no record says how its unseen views were classified benignly
    judged = [{**j, "record": {**j["record"], "benign_unseen_correct": i != 1}} for i, j in enumerate(jobs)]
    assert table2(judged)[0].benign_all_views == 0  # the sofa, right on its attack views, is wrong on unseen ones
    judged[1]["record"]["benign_unseen_correct"] = True
    assert table2(judged)[0].benign_all_views == 1 and "| 1 | 1 |" in to_markdown(table2(judged))
    chair, sofa = table2(jobs, per_class=True)
    assert (chair.pair, chair.attacks, sofa.pair, sofa.attacks) == ("chair -> sofa", 2, "sofa -> chair", 1)
    assert chair.unseen_success == pytest.approx(0.3) and sofa.unseen_success == pytest.approx(0.6)
    text = to_markdown([chair, sofa])
    assert "class -> target" in text and "| chair -> sofa | 5 |" in text
    assert "class -> target" not in to_markdown([pooled])


def test_benign_correct_filter() -> None:
    mesh = {"source": "pascal3d", "path": "p.ply", "class": "chair"}

    def job(ci: int, correct: bool) -> dict:
        return {"spec": {"kind": "single", "mesh": mesh, "config_index": ci, "seed": 0, "victim": "v",
                         "perturbation": "shape", "source_class": "chair", "target": "sofa"},
                "record": {"success": True, "benign_correct": correct, "distances": {"color_rmse": float(ci)}}}

    jobs = [job(0, True), job(1, False)]
    assert len(attack_rows(jobs)) == 4  # two jobs x two Laplacian conventions
    only, _ = attack_rows(jobs, benign_correct_only=True)
    assert only.instance[1] == 0


def test_protocol_jobs_are_rows_of_their_own() -> None:
    mesh = {"source": "pascal3d", "path": "p.ply", "class": "chair"}
    spec = {"kind": "single", "mesh": mesh, "config_index": 0, "seed": 0, "victim": "v", "perturbation": "texture",
            "source_class": "chair", "target": "sofa"}
    jobs = [{"spec": spec, "record": {"success": True, "distances": {"color_rmse": 0.1}}},
            {"spec": {**spec, "protocol": "paper"}, "record": {"success": False, "distances": {"color_rmse": 0.2}}}]
    main, paper_row = table1(attack_rows(jobs))
    assert (main.victim, main.targets, main.best.success_rate) == ("v", 1, 1.0)
    assert (paper_row.victim, paper_row.targets, paper_row.best.success_rate) == ("v [paper]", 1, 0.0)


def test_percentile_interpolates_between_order_statistics() -> None:
    from meshadv.experiments.tables import percentile

    values = [5.0, 1.0, 4.0, 2.0, 3.0]  # sorted 1..5: rank (n - 1) q / 100
    assert percentile(values, 0.0) == 1.0 and percentile(values, 100.0) == 5.0
    assert percentile(values, 50.0) == 3.0
    assert percentile(values, 90.0) == pytest.approx(4.6)  # rank 3.6: 4 + 0.6 * (5 - 4)
    assert percentile([7.0], 90.0) == 7.0 and math.isnan(percentile([], 90.0))
    with pytest.raises(ValueError, match=r"^q must be in \[0, 100\]"):
        percentile(values, 101.0)
    with pytest.raises(ValueError, match="^values must not contain nan"):
        percentile([1.0, math.nan], 50.0)


def test_tail_columns_over_successful_attacks_and_the_paper_threshold() -> None:
    from meshadv.experiments.tables import PAPER_WORST

    assert PAPER_WORST == {"shape": pytest.approx(3.0e-4), "texture": pytest.approx(3.2e-2)}

    def pair(inst: str, target: str, success: bool, dist: float) -> AttackRow:
        return AttackRow(victim="v", perturbation="shape", instance=(inst,), source="src", target=target,
                         success=success, distance=dist, measure="laplacian_pair_mean")

    # ten successes 1e-5 .. 1e-4 and 1.2e-3 (a broken mesh), one failure at 5e-3 that must not count
    dists = [k * 1e-5 for k in range(1, 11)] + [1.2e-3]
    rows = [pair(f"I{k // 3}", f"t{k % 3}", True, d) for k, d in enumerate(dists)] + [pair("I3", "t2", False, 5e-3)]
    (t,) = table1(rows)
    tail = t.tail
    assert tail is not None and tail.n == 11
    assert tail.median == pytest.approx(6e-5) and tail.max == pytest.approx(1.2e-3)
    assert tail.p90 == pytest.approx(1e-4)  # rank 9 of 0..10: the tenth smallest
    assert tail.threshold == pytest.approx(3e-4) and tail.above_n == 1 and tail.above == pytest.approx(1 / 11)
    md = to_markdown([t])
    assert "successes: p90 dist" in md and "| 6e-05 | 0.0001 | 0.0012 | 9.1% (1 of 11 > 0.0003) |" in md
    header, line = to_csv([t]).splitlines()
    cells = dict(zip(header.split(","), line.split(",")))
    assert float(cells["tail_p90"]) == pytest.approx(1e-4) and cells["tail_above_n"] == "1"
    # the literal sum is not the paper's measure: no threshold, no share
    (total,) = table1([AttackRow(**{**r.__dict__, "measure": "laplacian_sum"}) for r in rows])
    assert total.tail is not None and total.tail.above_n == 0 and math.isnan(total.tail.above)
    assert to_markdown([total]).rstrip().endswith("| 0.0012 | – |")


def test_pair_success_counts_each_attack_once_per_class_pair() -> None:
    """Both shape conventions are rows of one job: counted once; a failed pair is bold, totals per target."""
    def rows(source: str, target: str, success: bool, victim: str = "v") -> list:
        return [AttackRow(victim=victim, perturbation="shape", instance=(source, i), source=source, target=target,
                          success=success, distance=1e-4, measure=measure)
                for i in range(2) for measure in ("laplacian_pair_mean", "laplacian_sum")]

    pairs = pair_success(rows("chair", "sofa", True) + rows("sofa", "chair", False) + rows("chair", "sofa", True, "w"))
    assert pairs == [PairSuccess("v", "shape", "chair", "sofa", 2, 2), PairSuccess("v", "shape", "sofa", "chair", 2, 0),
                     PairSuccess("w", "shape", "chair", "sofa", 2, 2)]
    md = pair_success_markdown(pairs)
    assert "| source \\ target | chair | sofa | all targets |" in md
    assert "| chair | – | 2/2 | 2/2 |" in md and "| sofa | **0/2** | – | **0/2** |" in md
    assert "| all sources | **0/2** | 2/2 | **2/4** |" in md
    assert md.count("**v, shape**") == 1 and md.count("**w, shape**") == 1
    assert pair_success_markdown([]) == "_no results_\n"


def test_transfer_rows_of_a_protocol_are_labelled_as_in_table1() -> None:
    """Table 3 keeps an extra protocol's attacks apart: the row of a protocol job is ``victim [protocol]``."""
    rows = [{"case_id": "a", "victim": "v"}, {"case_id": "b", "victim": "v"}, {"case_id": "gone", "victim": "v"}]
    specs = {"a": {"victim": "v"}, "b": {"victim": "v", "protocol": "paper"}}
    assert [r["victim"] for r in labelled_by_protocol(rows, specs)] == ["v", "v [paper]", "v"]
    assert rows[1]["victim"] == "v"  # the input rows are not changed
