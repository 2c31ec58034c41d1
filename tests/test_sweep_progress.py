"""Sweep progress per attack step: workers report their steps to the driver, whose step bar counts them."""

from __future__ import annotations

from pathlib import Path
from typing import Any, List, Tuple

import pytest
from sweep_fixtures import tiny_builtin_config

from meshadv.experiments import LocalBackend, ResultStore, SerialBackend, run_sweep
from meshadv.experiments.config import expand_jobs, parse_config
from meshadv.experiments.jobs import planned_steps
from meshadv.experiments.progress import Progress
from meshadv.experiments.worker import StepReport, execute, report_steps

JOB = "meshadv.experiments.jobs:run_attack_job"
PROBE = "probe_jobs:probe_job"


def _victim_or_skip() -> None:
    pytest.importorskip("meshadv._raster", reason="the native renderer is not built (maturin develop --release)")
    try:
        from meshadv.victims import load_victim

        load_victim("efficientnet_lite0")
    except ImportError as err:  # the package is missing; broken weights must fail, not skip
        pytest.skip(f"victim efficientnet_lite0 unavailable: {err}")


def test_planned_steps_of_attack_specs() -> None:
    assert planned_steps({"perturbation": "shape", "attack": {"steps": 7, "binary_search_steps": 3}}) == 21
    assert planned_steps({"perturbation": "shape", "attack": {"steps": 7, "method": "ddn"}}) == 7
    assert planned_steps({"perturbation": "texture", "attack": {"steps": 5}}) == 5
    assert planned_steps({"perturbation": "shape", "attack": {"steps": 7, "not_an_option": 1}}) is None
    assert planned_steps({"perturbation": "colour", "attack": {}}) is None


def test_report_steps_reaches_the_sink_of_the_running_job_only(tmp_path: Path) -> None:
    reports: List[StepReport] = []
    report_steps(5, 9)  # outside a job: dropped
    outcome = execute(PROBE, "j1", {"steps": 3}, str(tmp_path / "a"), step_sink=reports.append)
    assert outcome.ok, outcome.error
    assert reports == [StepReport("j1", k, 3) for k in (1, 2, 3)]
    report_steps(4, 9)  # after the job: dropped again
    assert len(reports) == 3


def test_progress_counts_reports_early_stops_and_retries() -> None:
    bar = Progress(total=2, enabled=False, planned={"a": 10, "b": 4})
    assert bar.steps_total == 14
    for k in (1, 2, 3):
        bar.step(StepReport("a", k, 10))
    bar.step(StepReport("a", 3, 10))  # a repeated report counts once
    assert bar.steps_done == 3
    bar.job_finished("a")  # stopped early at 3 of 10: the 7 it will not run are counted
    assert (bar.steps_done, bar.steps_total) == (10, 14)
    bar.step(StepReport("b", 2, 4))
    bar.job_finished("b", retry=True)  # the 2 steps run again
    assert (bar.steps_done, bar.steps_total) == (12, 16)
    for k in (1, 2, 3, 4):
        bar.step(StepReport("b", k, 4))
    bar.job_finished("b")
    assert bar.steps_done == bar.steps_total == 16
    assert Progress(total=3, done=3, enabled=False, planned={}).steps_total == 0  # a resumed, finished sweep
    assert Progress(total=3, enabled=False).steps_total is None  # no plan: a count without a total
    unknown = Progress(total=1, enabled=False, planned={"c": None})
    unknown.step(StepReport("c", 2, 6))
    unknown.job_finished("c")
    assert (unknown.steps_done, unknown.steps_total) == (6, None)


def test_local_workers_report_steps_over_their_pipe_and_retries_count_again(tmp_path: Path) -> None:
    specs = [{"i": 0, "steps": 5}, {"i": 1, "steps": 3, "probe": "flaky"}]
    reports: List[StepReport] = []
    backend = LocalBackend(workers=2, threads_per_job=1)
    try:
        with ResultStore(tmp_path / "r.db") as store:
            summary = run_sweep(store, specs, PROBE, out_root=tmp_path, backend=backend, max_attempts=2,
                                progress=False, planned_steps=lambda spec: spec["steps"], on_steps=reports.append)
            ids = {row.spec["i"]: row.job_id for row in store.rows()}
    finally:
        backend.close()
    assert summary.done == 2
    assert [r.done for r in reports if r.job_id == ids[0]] == [1, 2, 3, 4, 5]
    assert [r.done for r in reports if r.job_id == ids[1]] == [1, 2, 3]  # the flaky job's failed attempt reported none
    assert backend.on_steps is None  # the driver's sink is removed at the end


def _run_tiny(tmp_path: Path, backend: Any, progress: bool) -> Tuple[ResultStore, list, list]:
    jobs = expand_jobs(parse_config(tiny_builtin_config("tiny-steps", steps=4, perturbations=("shape",))))
    events: list = []
    reports: List[StepReport] = []

    def on_steps(report: StepReport) -> None:
        reports.append(report)
        events.append(("step", report.job_id))

    store = ResultStore(tmp_path / "r.db")
    summary = run_sweep(store, jobs, JOB, out_root=tmp_path / "run", backend=backend, max_attempts=1,
                        progress=progress, planned_steps=planned_steps, on_steps=on_steps,
                        on_outcome=lambda jid, ok: events.append(("outcome", jid)))
    assert summary.done == len(jobs) == 2, [r.error for r in store.rows("failed")]
    return store, reports, events


def _check_reports(store: ResultStore, reports: List[StepReport], events: list) -> None:
    for row in store.rows():
        mine = [r for r in reports if r.job_id == row.job_id]
        # every step of the job reached the driver, in order, with the job's planned steps, before its outcome
        assert [r.done for r in mine] == list(range(1, row.record["steps"] + 1))
        assert all(r.planned == planned_steps(row.spec) == 4 for r in mine)
        mine_events = [kind for kind, jid in events if jid == row.job_id]
        assert mine_events == ["step"] * len(mine) + ["outcome"]


@pytest.mark.slow
def test_local_backend_workers_report_every_step_to_the_driver(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture) -> None:
    _victim_or_skip()
    backend = LocalBackend(workers=1, threads_per_job=1)
    try:
        store, reports, events = _run_tiny(tmp_path, backend, progress=True)
    finally:
        backend.close()
    with store:
        _check_reports(store, reports, events)
    err = capsys.readouterr().err
    assert "steps:" in err and "8/8" in err  # the step bar (2 jobs x 4 planned steps) ends full


def test_serial_backend_reports_every_step(tmp_path: Path) -> None:
    _victim_or_skip()
    store, reports, events = _run_tiny(tmp_path, SerialBackend(threads_per_job=1), progress=False)
    with store:
        _check_reports(store, reports, events)
