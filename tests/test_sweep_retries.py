"""The retry pass (``[attack.retry]``, :mod:`meshadv.experiments.retries`): failed main attacks run again with a
larger budget, resumably, and the tables combine each attack with its retry."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, Optional

import pytest
from typer.testing import CliRunner

from meshadv.experiments.config import parse_config
from meshadv.experiments.report import write_report
from meshadv.experiments.config import job_part, select_parts
from meshadv.experiments.retries import (
    place_retries,
    protocol_label,
    retry_jobs,
    retry_options,
    retry_spec,
    retry_stage,
    superseded_retries,
    with_retried_transfers,
    with_retries,
)
from meshadv.experiments.spec import job_id
from meshadv.experiments.store import JobRow, ResultStore
from meshadv.experiments.config import stored_retry_stages
from meshadv.experiments.tables import attack_rows, table1
from sweep_fixtures import job_states, probe_jobs, run_probe_sweep, sweep_cli, two_job_config

# a job that reaches its target with 50 steps or more, and from the sofa always
RETRY_JOB = '''
def job(spec, out_dir):
    steps = int(spec["attack"].get("steps", 0))
    won = steps >= 50 or spec["source_class"] == "sofa"
    return {"success": won, "distance": 1.0 / steps if steps else 1.0, "steps": steps}
'''


def _config(extra: str) -> Dict[str, Any]:
    import tomllib

    return tomllib.loads(two_job_config("retry", "m:job") + extra)


def _row(job_id: str, spec: Dict[str, Any], record: Optional[Dict[str, Any]], state: str = "done") -> JobRow:
    return JobRow(job_id=job_id, spec=spec, state=state, attempts=1, error=None, record=record, out_dir=None,
                  started=None, finished=None)


def _spec(source: str, target: str, perturbation: str = "shape", **extra: Any) -> Dict[str, Any]:
    return {"kind": "single", "mesh": {"name": source}, "source_class": source, "target": target,
            "victim": "v", "perturbation": perturbation, "attack": {"steps": 10, "lr": 0.1}, "seed": 0,
            "config_index": 0, **extra}


def test_the_retry_table_is_checked_at_load() -> None:
    cfg = parse_config(_config("\n[attack.retry]\nshape = { steps = 60 }\n"))
    assert cfg.attack["retry"] == [{"shape": {"steps": 60}}]  # one stage
    assert parse_config(_config("")).attack["retry"] == []
    with pytest.raises(ValueError, match="'attack.retry.shape.stepz'; did you mean 'attack.retry.shape.steps'"):
        parse_config(_config("\n[attack.retry]\nshape = { stepz = 60 }\n"))
    with pytest.raises(ValueError, match="'attack.retry.colour'"):
        parse_config(_config("\n[attack.retry]\ncolour = { steps = 60 }\n"))
    with pytest.raises(ValueError, match=r"\[attack.retry.shape\]"):
        parse_config(_config("\n[attack.retry]\nshape = { steps = -3 }\n"))
    with pytest.raises(ValueError, match="attack.protocols.retry: the name 'retry' is the retry pass's"):
        parse_config(_config("\n[attack.protocols.retry]\nshape = { steps = 60 }\n"))


def test_retry_jobs_are_due_for_failed_main_attacks_only() -> None:
    rows = [
        _row("a", _spec("chair", "sofa"), {"success": False}),
        _row("b", _spec("sofa", "chair"), {"success": True}),
        _row("c", _spec("boat", "chair"), {"success": False, "skipped": True}),
        _row("d", _spec("boat", "sofa"), None, state="pending"),
        _row("e", _spec("chair", "boat", protocol="paper"), {"success": False}),
        _row("f", _spec("chair", "boat", "texture"), {"success": False}),
        _row("g", dict(_spec("chair", "boat"), kind="multiview"), {"success": False}),
    ]
    due = retry_jobs([{"shape": {"steps": 60}}], rows)
    assert due == [retry_spec(rows[0].spec, "a", {"steps": 60})]
    child = due[0]
    assert child["attack"] == {"steps": 60, "lr": 0.1} and child["retry_of"] == "a"
    assert job_part(child) == "retry" and rows[0].spec["attack"] == {"steps": 10, "lr": 0.1}  # parent untouched
    assert "retry_stage" not in child and retry_stage(child) == 1  # a one-stage sweep's job ids
    assert retry_jobs([{"shape": {"steps": 60}}], [_row("r", child, {"success": False})]) == []  # no second stage
    main, paper = _spec("chair", "sofa"), _spec("chair", "sofa", protocol="paper")
    assert place_retries([main, paper], due) == [main, child, paper]
    assert place_retries([paper], due) == [child, paper]


def test_with_retries_combines_each_attack_with_its_retry() -> None:
    parent, other = _spec("chair", "sofa"), _spec("chair", "boat")
    child = retry_spec(parent, "a", {"steps": 60})
    rows = [_row("a", parent, {"success": False, "distance": 5.0}),
            _row("b", other, {"success": True, "distance": 1.0}),
            _row("c", child, {"success": True, "distance": 2.0})]
    combined = with_retries(rows)
    assert [(c["spec"]["protocol"], c["record"]["distance"]) for c in combined] == [("+retry", 2.0),
                                                                                   ("+retry", 1.0)]
    t1 = {r.victim: r for r in table1(attack_rows([*rows, *combined])) if r.distance_name == "laplacian_pair_mean"}
    assert t1["v"].average.success_rate == 0.5 and t1["v [+retry]"].average.success_rate == 1.0
    assert t1["v [retry]"].average.success_rate == 1.0
    assert with_retries(rows[:2]) == []  # no retry finished: no combined rows


def test_table3_rows_of_the_combined_attacks() -> None:
    parent, other = _spec("chair", "sofa"), _spec("chair", "boat")
    specs = {"a": parent, "b": other, "c": retry_spec(parent, "a", {"steps": 60}),
             "d": _spec("chair", "boat", protocol="paper"), "x": dict(_spec("sofa", "boat"), victim="w")}
    rows = [{"case_id": k, "victim": specs[k]["victim"], "untargeted_mitsuba": True} for k in ("b", "c", "d", "x")]
    rows.append({"case_id": "blackbox-1", "victim": "v"})  # not a job of this sweep
    combined = with_retried_transfers(rows, specs)
    assert [(r["case_id"], r["victim"]) for r in combined] == [("b", "v [+retry]"), ("c", "v [+retry]")]
    assert with_retried_transfers([rows[0], rows[2]], specs) == []  # no retry transferred


def test_sweep_runs_the_retries_of_its_failures_and_resumes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "m.py").write_text(RETRY_JOB)
    monkeypatch.syspath_prepend(str(tmp_path))
    retry = "\n[attack.retry]\nshape = { steps = 60 }\n"
    (tmp_path / "sweep.toml").write_text(two_job_config("retry", "m:job") + retry)
    db = tmp_path / "results.db"
    args = ["sweep", str(tmp_path / "sweep.toml"), "--db", str(db), "--output", str(tmp_path / "out"),
            "--backend", "serial", "--no-progress"]
    res = CliRunner().invoke(sweep_cli(), args + ["--only", "retry"])  # no failure yet: nothing to retry
    assert res.exit_code == 0, res.output
    assert job_states(db) == {}
    res = CliRunner().invoke(sweep_cli(), args + ["--stop-starting-after", "0"])
    assert res.exit_code == 0 and "2 job(s) wait for the next run" in res.output, res.output
    res = CliRunner().invoke(sweep_cli(), args)
    assert res.exit_code == 0, res.output
    assert "3/3 done (2 successful)" in res.output and "ran 3" in res.output
    with ResultStore(db) as store:
        rows = store.rows()
    (child,) = [r for r in rows if r.spec.get("retry_of")]
    parent = next(r for r in rows if r.job_id == child.spec["retry_of"])
    assert parent.spec["source_class"] == "chair" and parent.record["success"] is False
    assert child.record["success"] is True and child.spec["attack"]["steps"] == 60
    res = CliRunner().invoke(sweep_cli(), args)  # resumed: nothing left, no retry of a retry
    assert res.exit_code == 0 and "3/3 done" in res.output and "ran 0" in res.output, res.output
    res = CliRunner().invoke(sweep_cli(), args + ["--only", "paper"])
    assert res.exit_code == 2 and "'retry'" in res.output


def test_select_parts_knows_parts_without_jobs_yet() -> None:
    jobs = [_spec("chair", "sofa")]
    assert select_parts(jobs, ["retry"], also_known=["retry"]) == []
    with pytest.raises(ValueError, match="parts \\['retry'\\] are not in this sweep"):
        select_parts(jobs, ["retry"])


def test_report_has_the_retry_rows_and_draws_no_retry(tmp_path: Path) -> None:
    jobs = probe_jobs(["chair", "sofa"])  # chair -> sofa and sofa -> chair, shape, victim "v"
    jobs[0]["success"] = False  # the synthetic job's outcome
    db = run_probe_sweep(tmp_path / "results.db", jobs, tmp_path / "run")
    with ResultStore(db) as store:
        rows = store.rows()
    retry = {**retry_jobs([{"shape": {"steps": 60}}], rows)[0], "success": True}
    run_probe_sweep(db, [retry], tmp_path / "run")
    out = write_report(db, tmp_path / "report", figures=True)
    table = (tmp_path / "report" / "table1.md").read_text()
    assert "| v [+retry] | shape | laplacian_pair_mean | yes |" in table and "| v [retry] | shape |" in table
    plain = next(line for line in table.splitlines() if line.startswith("| v | shape | laplacian_pair_mean"))
    combined = next(line for line in table.splitlines() if line.startswith("| v [+retry] | shape | laplacian_pair"))
    assert "50.0%" in plain and "100.0%" in combined
    assert not any("retry" in path.name for path in out.figures)  # grids and flow figures leave retries out


STAGES = [{"shape": {"steps": 60}}, {"shape": {"method": "adam", "lr": 1.0}, "texture": {"steps": 5}}]


def test_retry_stages_are_checked_at_load() -> None:
    stages = "\n[[attack.retry]]\nshape = { steps = 60 }\n[[attack.retry]]\nshape = { lr = 1.0 }\n"
    assert parse_config(_config(stages)).attack["retry"] == [{"shape": {"steps": 60}}, {"shape": {"lr": 1.0}}]
    assert parse_config(_config("\n[[attack.retry]]\nshape = { steps = 60 }\n")).attack["retry"] == [
        {"shape": {"steps": 60}}]
    with pytest.raises(ValueError, match=r"'attack.retry\[1\].shape.stepz'; did you mean '.*\[1\].shape.steps'"):
        parse_config(_config(stages.replace("lr = 1.0", "stepz = 3")))
    with pytest.raises(ValueError, match=r"\[attack.retry\[1\].shape\]: steps must be"):
        parse_config(_config(stages.replace("lr = 1.0", "steps = -3")))
    ddn_then_adam = ("\n[attack.shape]\nmethod = 'ddn'\n[[attack.retry]]\nshape = { method_options = { edge_gradient = "
                     "0.1 } }\n[[attack.retry]]\nshape = { method = 'adam'%s }\n")
    with pytest.raises(ValueError, match=r"\[attack.retry\[1\].shape\]: method_options has unknown keys "
                                         r"\['edge_gradient'\] for method='adam'"):
        parse_config(_config(ddn_then_adam % ""))  # stage 1's ddn options reach stage 2's Adam
    assert parse_config(_config(ddn_then_adam % ", method_options = {}")).attack["retry"][1]["shape"] == {
        "method": "adam", "method_options": {}}
    raw = _config("")
    raw["attack"]["retry"] = [{"shape": {"steps": 60}}, "shape"]
    with pytest.raises(ValueError, match=r"section \[attack.retry\[1\]\] must be a table, got str"):
        parse_config(raw)


def test_a_failed_retry_is_retried_by_the_next_stage_with_its_options_over_its_own() -> None:
    parent = _spec("chair", "sofa")
    first = retry_spec(parent, "a", STAGES[0]["shape"])
    rows = [_row("a", parent, {"success": False}), _row(job_id(first), first, {"success": False})]
    assert retry_jobs(STAGES, rows[:1]) == [first]  # stage 2 waits for stage 1 to finish
    due = retry_jobs(STAGES, rows)
    assert due[0] == first  # the main attack's retry (already done here: the sweep skips it by its job id)
    second = due[1]
    assert second["retry_of"] == job_id(first) and second["retry_stage"] == 2 and retry_stage(second) == 2
    assert second["attack"] == {"steps": 60, "lr": 1.0, "method": "adam"}  # main, then stage 1, then stage 2
    assert job_part(second) == "retry" and protocol_label(second) == "retry 2" and protocol_label(first) == "retry"
    assert retry_options(STAGES, second) is None  # the last stage
    assert retry_jobs(STAGES, [*rows, _row(job_id(second), second, {"success": False})]) == [first, second]
    won = [rows[0], _row(job_id(first), first, {"success": True})]
    assert retry_jobs(STAGES, won) == [first]  # a retry that succeeded: no stage 2
    assert retry_jobs(STAGES, [rows[1]]) == []  # a retry without its parent in the rows: no chain reaches it
    texture = _spec("chair", "sofa", "texture")  # stage 1 does not retry texture: its chain ends there
    assert retry_jobs(STAGES, [_row("t", texture, {"success": False})]) == []


def test_with_retries_follows_the_chain_to_the_first_success() -> None:
    parent, other = _spec("chair", "sofa"), _spec("chair", "boat")
    first = retry_spec(parent, "a", STAGES[0]["shape"])
    second = retry_spec(first, "r1", STAGES[1]["shape"])
    rows = [_row("a", parent, {"success": False, "distance": 5.0}),
            _row("b", other, {"success": False, "distance": 1.0}),
            _row("r1", first, {"success": False, "distance": 4.0}),
            _row("r2", second, {"success": True, "distance": 3.0}),
            _row("s1", retry_spec(other, "b", STAGES[0]["shape"]), {"success": True, "distance": 2.0})]
    combined = with_retries(rows)
    assert [c["record"]["distance"] for c in combined] == [3.0, 2.0]
    t1 = {r.victim: r for r in table1(attack_rows([*rows, *combined])) if r.distance_name == "laplacian_pair_mean"}
    assert t1["v"].average.success_rate == 0.0 and t1["v [+retry]"].average.success_rate == 1.0
    assert t1["v [retry]"].average.success_rate == 0.5 and t1["v [retry 2]"].average.success_rate == 1.0
    unfinished = [*rows[:3], _row("r2", second, None, state="running"), rows[4]]
    assert [c["record"]["distance"] for c in with_retries(unfinished)] == [4.0, 2.0]  # the last that finished


def test_sweep_runs_each_retry_stage_after_the_one_before(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # reaches its target with lr >= 1 (stage 2), and from the sofa always (a module name of its own: "m" is cached)
    (tmp_path / "staged.py").write_text(RETRY_JOB.replace("steps >= 50", "float(spec['attack'].get('lr', 0)) >= 1"))
    monkeypatch.syspath_prepend(str(tmp_path))
    stages = "\n[[attack.retry]]\nshape = { steps = 60 }\n[[attack.retry]]\nshape = { lr = 1.0 }\n"
    (tmp_path / "sweep.toml").write_text(two_job_config("retry", "staged:job") + stages)
    db = tmp_path / "results.db"
    args = ["sweep", str(tmp_path / "sweep.toml"), "--db", str(db), "--output", str(tmp_path / "out"),
            "--backend", "serial", "--no-progress"]
    res = CliRunner().invoke(sweep_cli(), args)
    assert res.exit_code == 0, res.output
    assert "4/4 done (2 successful)" in res.output and "ran 4" in res.output
    with ResultStore(db) as store:
        by_id = {r.job_id: r for r in store.rows()}
    (second,) = [r for r in by_id.values() if r.spec.get("retry_stage") == 2]
    first = by_id[second.spec["retry_of"]]
    assert retry_stage(first.spec) == 1 and first.record["success"] is False
    assert by_id[first.spec["retry_of"]].spec["source_class"] == "chair" and second.record["success"] is True
    assert second.spec["attack"]["steps"] == 60 and second.spec["attack"]["lr"] == 1.0
    res = CliRunner().invoke(sweep_cli(), args)  # resumed: nothing left
    assert res.exit_code == 0 and "4/4 done" in res.output and "ran 0" in res.output, res.output
    res = CliRunner().invoke(sweep_cli(), args + ["--only", "retry", "--dry-run"])  # the retries the database holds
    assert res.exit_code == 0 and "2 jobs (2 single-view, 0 multi-view), 2 finished;" in res.output, res.output


def test_retries_of_stages_the_config_no_longer_has_are_superseded() -> None:
    parent, other = _spec("chair", "sofa"), _spec("chair", "boat")
    old = retry_spec(parent, "a", {"steps": 30})  # stage 1 before the config changed, and its stage-2 retry
    old_second = retry_spec(old, job_id(old), STAGES[1]["shape"])
    first = retry_spec(parent, "a", STAGES[0]["shape"])
    rows = [_row("a", parent, {"success": False}), _row("b", other, {"success": True}),
            _row(job_id(old), old, {"success": False}), _row(job_id(old_second), old_second, {"success": True}),
            _row(job_id(first), first, {"success": False})]
    assert superseded_retries(STAGES, rows) == {job_id(old), job_id(old_second)}
    assert retry_jobs(STAGES, rows) == [first, retry_spec(first, job_id(first), STAGES[1]["shape"])]
    assert superseded_retries([{"shape": {"steps": 30}}], rows) == {job_id(first), job_id(old_second)}
    assert superseded_retries(None, rows) == set()  # stages not known: none
    assert superseded_retries([], rows) == {job_id(old), job_id(old_second), job_id(first)}  # retries switched off


def test_changed_retry_stages_run_the_new_retries_and_the_report_leaves_the_old_out(tmp_path: Path, monkeypatch:
                                                                                    pytest.MonkeyPatch) -> None:
    (tmp_path / "changed.py").write_text(RETRY_JOB)  # reaches its target with 50 steps or more
    monkeypatch.syspath_prepend(str(tmp_path))
    db = tmp_path / "results.db"
    args = ["sweep", str(tmp_path / "sweep.toml"), "--db", str(db), "--output", str(tmp_path / "out"),
            "--backend", "serial", "--no-progress"]
    # a retry stage that misses, then the config changed to one that reaches the target: only the new retry runs
    for steps, ran in ((30, "3/3 done (1 successful), 0 failed; ran 3"),
                       (60, "3/3 done (2 successful), 0 failed; ran 1")):
        (tmp_path / "sweep.toml").write_text(two_job_config("retry", "changed:job")
                                             + f"\n[attack.retry]\nshape = {{ steps = {steps} }}\n")
        res = CliRunner().invoke(sweep_cli(), args)
        assert res.exit_code == 0 and ran in res.output, res.output
    with ResultStore(db) as store:
        retries = sorted((r.spec["attack"]["steps"], r.record["success"]) for r in store.rows() if "retry_of" in r.spec)
    assert retries == [(30, False), (60, True)]  # the old retry is kept in the database
    out = write_report(db, tmp_path / "report", figures=False)
    assert list(out.superseded.values()) == ["done"]
    table = (tmp_path / "report" / "table1.md").read_text()
    retry_line = next(line for line in table.splitlines()
                      if line.startswith("| efficientnet_lite0 [retry] | shape | laplacian_pair"))
    assert "100.0%" in retry_line and "| 1 |" in retry_line  # the new retry alone: one instance, reached
    assert "1 retries were made by retry stages the config no longer has (1 of them finished" in (
        tmp_path / "report" / "README.md").read_text()


def test_stored_retry_stages_read_the_config_text_a_sweep_stored() -> None:
    toml = "[attack.retry]\nshape = { steps = 60 }\n"
    assert stored_retry_stages(toml) == [{"shape": {"steps": 60}}]
    assert stored_retry_stages("[[attack.retry]]\nshape = { steps = 60 }\n[[attack.retry]]\nshape = { lr = 1 }\n") == [
        {"shape": {"steps": 60}}, {"shape": {"lr": 1}}]
    assert stored_retry_stages("attack:\n  retry:\n    shape: {steps: 60}\n") == [{"shape": {"steps": 60}}]  # YAML
    assert stored_retry_stages("[victims]\nnames = ['v']\n") == []  # a config without retries
    assert stored_retry_stages(None) is None and stored_retry_stages("") is None  # not known
    assert stored_retry_stages("- a list\n") is None and stored_retry_stages("[attack\n: :") is None  # unreadable
