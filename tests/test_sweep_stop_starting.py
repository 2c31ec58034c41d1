"""Stopping a sweep without losing the running jobs' work: ``run_sweep(stop_starting=...)``, ``meshadv sweep
--stop-starting-after`` and SIGUSR1 (the running jobs finish and are recorded, the rest wait for the next run)."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path
from typing import Callable

import pytest
from typer.testing import CliRunner

from meshadv.commands import sweep as sweep_cmd
from meshadv.commands._common import parse_duration
from meshadv.experiments import ResultStore, SerialBackend, run_sweep
from sweep_fixtures import job_states, probe_jobs, start_sweep_process, sweep_cli, two_job_config

PROBE = "probe_jobs:mesh_probe_job"


def test_run_sweep_stops_starting_and_the_next_run_continues(tmp_path: Path) -> None:
    jobs = probe_jobs(["chair", "sofa", "boat"])  # 3 classes x 2 targets = 6 jobs
    started = []

    def after_two() -> bool:
        started.append(1)
        return len(started) > 2

    with ResultStore(tmp_path / "results.db") as store:
        first = run_sweep(store, jobs, PROBE, out_root=tmp_path / "out", backend=SerialBackend(), progress=False,
                          stop_starting=after_two)
        assert (first.ran, first.done, first.not_started) == (2, 2, 4)
        assert store.counts()["pending"] == 4 and store.counts().get("running", 0) == 0
        second = run_sweep(store, jobs, PROBE, out_root=tmp_path / "out", backend=SerialBackend(), progress=False)
    assert (second.ran, second.skipped, second.done, second.not_started) == (4, 2, 6, 0)


def test_stop_starting_after_a_time_and_at_sigusr1() -> None:
    assert not sweep_cmd.StopStarting()()  # no limit: never stops
    elapsed = sweep_cmd.StopStarting(0.0)
    assert elapsed.reason is None  # set when asked
    assert elapsed() and elapsed.reason == "--stop-starting-after reached"
    stop = sweep_cmd.StopStarting(3600.0)
    previous = signal.getsignal(signal.SIGUSR1)
    with stop.on_sigusr1():
        assert not stop()
        os.kill(os.getpid(), signal.SIGUSR1)
        time.sleep(0.05)  # the handler runs in the main thread between bytecodes
        assert stop() and stop.reason == "SIGUSR1 received"
    assert signal.getsignal(signal.SIGUSR1) is previous


@pytest.mark.parametrize("text, seconds", [("90m", 5400.0), ("2h", 7200.0), ("1h30m", 5400.0), ("45s", 45.0),
                                           ("3600", 3600.0), ("1.5h", 5400.0), ("0", 0.0)])
def test_durations(text: str, seconds: float) -> None:
    assert parse_duration(text, "--stop-starting-after") == seconds


@pytest.mark.parametrize("text", ["", "h", "5d", "-5", "1m2h", "soon"])
def test_bad_durations_name_the_option(text: str) -> None:
    with pytest.raises(ValueError, match="--stop-starting-after must be a duration"):
        parse_duration(text, "--stop-starting-after")


def test_cli_stop_starting_after_zero_starts_nothing_and_a_bad_value_is_named(tmp_path: Path) -> None:
    (tmp_path / "sweep.toml").write_text(two_job_config("stop", PROBE))
    db = tmp_path / "results.db"
    args = ["sweep", str(tmp_path / "sweep.toml"), "--db", str(db), "--output", str(tmp_path / "out"),
            "--backend", "serial", "--no-progress"]
    res = CliRunner().invoke(sweep_cli(), args + ["--stop-starting-after", "0"])
    assert res.exit_code == 0, res.output
    assert "stopped starting jobs (--stop-starting-after reached): 2 job(s) wait for the next run" in res.output
    assert job_states(db) == {"pending": 2}
    res = CliRunner().invoke(sweep_cli(), args + ["--stop-starting-after", "soon"])
    assert res.exit_code == 2 and "--stop-starting-after" in res.output
    res = CliRunner().invoke(sweep_cli(), args)
    assert res.exit_code == 0 and "2/2 done" in res.output and "stopped starting" not in res.output


GATED_JOB = '''
import time
from pathlib import Path


def job(spec, out_dir):
    """Say it started (``started`` beside the output folder's ``jobs`` tree), wait until the test creates
    ``release`` there, then succeed."""
    (Path(out_dir).parents[2] / "started").write_text("1")
    release = Path(out_dir).parents[2] / "release"
    while not release.exists():
        time.sleep(0.05)
    return {"success": True, "skipped": False, "distance": 0.0, "steps": 1, "time": 0.0}
'''


def _wait_for(condition: Callable[[], bool], proc: subprocess.Popen, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if proc.poll() is not None:
            raise AssertionError(f"the sweep exited ({proc.returncode}): {proc.communicate()[0][-2000:]}")
        if time.monotonic() > deadline:
            raise AssertionError(f"not reached within {timeout} s")
        time.sleep(0.1)


@pytest.mark.parametrize("when", ["worker starting", "job running"])
def test_sigusr1_to_the_process_group_lets_the_running_job_finish(tmp_path: Path, when: str) -> None:
    """SIGUSR1 to the sweep's whole process group, while its worker process is still starting (importing torch:
    SIGUSR1 is blocked from the spawn until the worker ignores it) or while the job runs."""
    proc, db, out = start_sweep_process(tmp_path, "stop", "gated_probe", GATED_JOB,
                                        start_new_session=True)  # its own process group: the signal reaches its worker
    try:
        _wait_for(lambda: job_states(db).get("running") == 1, proc)
        if when == "job running":
            _wait_for((out / "started").exists, proc)
        os.killpg(proc.pid, signal.SIGUSR1)  # as a batch scheduler signals a job's processes
        time.sleep(0.5)
        # the worker may still be starting (importing torch) and not have made the output folder yet
        out.mkdir(parents=True, exist_ok=True)
        (out / "release").write_text("1")
        output, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 0, output
    assert "stopped starting jobs (SIGUSR1 received): 1 job(s) wait for the next run" in output
    assert job_states(db) == {"done": 1, "pending": 1}  # the running job finished; the other was not started
