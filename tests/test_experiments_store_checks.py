"""Damaged results databases are detected with advice; sweeps with failed jobs or Ctrl-C say so in the exit code."""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

import meshadv.experiments as experiments
from meshadv.cli import app
from meshadv.experiments import ResultStore
from meshadv.experiments.runner import SweepSummary

CONFIG = """
[experiment]
name = "t"
output = "out"
[meshes]
source = "builtin"
builtin = [{name = "sphere", class = "bottle"}]
[render]
image_size = 32
configurations = 1
[victims]
names = ["efficientnet_lite0"]
[attack]
perturbations = ["texture"]
targets = ["chair"]
[attack.texture]
steps = 1
"""


def test_an_empty_file_is_not_taken_as_a_new_database(tmp_path: Path) -> None:
    path = tmp_path / "results.db"
    path.write_bytes(b"")
    with pytest.raises(ValueError, match="is an empty file .*delete it to start a new sweep"):
        ResultStore(path)
    assert path.stat().st_size == 0  # left untouched


def test_a_file_that_is_not_sqlite_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "results.db"
    path.write_text("not a database")
    with pytest.raises(ValueError, match="is not an SQLite database"):
        ResultStore(path)


def test_a_copy_without_its_wal_file_is_detected(tmp_path: Path) -> None:
    src = tmp_path / "run" / "results.db"
    store = ResultStore(src)
    store.add_jobs([{"a": 1}, {"a": 2}])
    # Copy while the sweep is running (the WAL holds the jobs), leaving the -wal file behind.
    copy = tmp_path / "copy" / "results.db"
    copy.parent.mkdir()
    shutil.copy(src, copy)
    store.close()
    with pytest.raises(ValueError, match="was not closed cleanly and its write-ahead log results.db-wal is missing"):
        ResultStore(copy)
    # A database closed cleanly needs no -wal file: the checkpoint moved everything into the .db file.
    with ResultStore(src) as reopened:
        assert reopened.counts()["pending"] == 2


def test_a_wal_mode_file_without_tables_is_reported_as_a_wal_less_copy(tmp_path: Path) -> None:
    path = tmp_path / "results.db"
    conn = sqlite3.connect(path)
    conn.execute("PRAGMA journal_mode=WAL")
    conn.close()
    with pytest.raises(ValueError, match="without a jobs table: it looks like a copy made without its write-ahead"):
        ResultStore(path)


def _sweep(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, behaviour: Any) -> Any:
    config = tmp_path / "sweep.toml"
    config.write_text(CONFIG)
    monkeypatch.setattr(experiments, "run_sweep", behaviour)
    return CliRunner().invoke(app, ["sweep", str(config), "--backend", "serial", "--no-progress"])


def test_a_sweep_with_failed_jobs_exits_non_zero(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def one_failed(*_args: Any, **_kwargs: Any) -> SweepSummary:
        return SweepSummary(total=2, done=1, successes=1, failed=1, ran=2, skipped=0, requeued=0)

    result = _sweep(tmp_path, monkeypatch, one_failed)
    assert result.exit_code == 1, result.output
    assert "1 job(s) failed" in result.output


def test_ctrl_c_says_what_was_kept_and_requeues(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def interrupted(store: ResultStore, jobs: list, *_args: Any, **_kwargs: Any) -> SweepSummary:
        store.add_jobs(jobs)
        store.mark_running(store.runnable(1)[0])
        raise KeyboardInterrupt

    result = _sweep(tmp_path, monkeypatch, interrupted)
    assert result.exit_code == 130
    assert "interrupted: 0 finished job(s) are kept" in result.output
    assert "1 running job(s) were put back to pending" in result.output
    with ResultStore(tmp_path / "out" / "results.db") as store:
        assert store.counts()["running"] == 0


def test_a_damaged_database_is_a_one_line_cli_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "results.db").write_bytes(b"")
    result = _sweep(tmp_path, monkeypatch, None)
    assert result.exit_code == 1
    assert "Traceback" not in result.output
    assert result.output.strip().startswith("meshadv sweep: error: path")
    assert len(result.output.strip().splitlines()) == 1


def test_a_truncated_result_json_of_a_finished_job_is_reported(tmp_path: Path) -> None:
    with ResultStore(tmp_path / "results.db") as store:
        store.add_jobs([{"a": 1}, {"a": 2}])
        jobs = store.runnable(1)
        for i, job in enumerate(jobs):
            folder = tmp_path / job
            folder.mkdir()
            (folder / "result.json").write_text('{"success": true}' if i == 0 else '{"succ')
            store.mark_running(job)
            store.mark_done(job, {"success": True}, str(folder))
        damaged = store.damaged_results()
    assert [job for job, _ in damaged] == [jobs[1]]
    assert "is truncated or not JSON" in damaged[0][1]


def test_a_skipped_job_without_result_json_is_not_reported_as_damaged(tmp_path: Path) -> None:
    """A job skipped because the benign render was misclassified writes its benign images but no result.json."""
    with ResultStore(tmp_path / "results.db") as store:
        store.add_jobs([{"a": 1}, {"a": 2}])
        jobs = store.runnable(2)
        for job, skipped in zip(jobs, (True, False)):
            folder = tmp_path / job
            folder.mkdir()
            (folder / "benign_v0.png").write_bytes(b"png")
            store.mark_running(job)
            store.mark_done(job, {"success": False, "skipped": skipped}, str(folder))
        damaged = store.damaged_results()
    assert [job for job, _ in damaged] == [jobs[1]]
    assert "is missing" in damaged[0][1]


def test_report_and_sweep_name_the_damaged_job_and_the_command_that_rebuilds_it(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from meshadv.commands._job_index import warn_damaged_results

    with ResultStore(tmp_path / "results.db") as store:
        store.add_jobs([{"a": 1}])
        (job,) = store.runnable(1)
        (tmp_path / job).mkdir()
        (tmp_path / job / "result.json").write_text('{"succ')  # cut short by a crash
        store.mark_running(job)
        store.mark_done(job, {"success": True}, str(tmp_path / job))
        assert warn_damaged_results(store, tmp_path / "results.db") == 1
    err = capsys.readouterr().err
    assert f"job {job} is recorded as done but" in err and "is truncated or not JSON" in err
    assert f"meshadv regenerate {tmp_path / 'results.db'} {job}" in err


def test_a_store_dropped_without_close_leaves_a_database_that_reopens(tmp_path: Path) -> None:
    """An owner that dies on an exception without closing its store (SQLite then closes the connection and removes
    the -wal file) must not leave the open mark that makes the next open refuse the file as a WAL-less copy."""
    import subprocess
    import sys

    path = tmp_path / "results.db"
    script = ("import sys\nfrom meshadv.experiments import ResultStore\n"
              f"store = ResultStore({str(path)!r})\nstore.add_jobs([{{'a': 1}}])\n"
              "raise KeyboardInterrupt  # the store is never closed\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0 and "KeyboardInterrupt" in proc.stderr
    assert not Path(str(path) + "-wal").exists()  # SQLite's own close removed the write-ahead log
    with ResultStore(path) as reopened:
        assert reopened.counts()["pending"] == 1
    conn = sqlite3.connect(path)
    try:
        assert conn.execute("SELECT value FROM meta WHERE key = 'open'").fetchone() == ("0",)
    finally:
        conn.close()


def test_the_lost_wal_message_says_how_to_clear_the_mark_when_another_program_folded_the_log(tmp_path: Path) -> None:
    """A sweep killed mid-run leaves its open mark; another SQLite program that then opens the original file moves
    the log into it and deletes it. The refusal names the statement that clears the mark, and after it the file
    opens with every job."""
    path = tmp_path / "results.db"
    store = ResultStore(path)
    store.add_jobs([{"a": 1}, {"a": 2}])
    store._closed = True  # the sweep is killed: no clean close, its mark stays
    other = sqlite3.connect(path)  # e.g. the sqlite3 shell, opened after the crash
    other.execute("SELECT count(*) FROM jobs").fetchone()
    other.close()
    store._conn.close()  # the last connection closes: SQLite moves the log into the file and deletes it
    assert not (tmp_path / "results.db-wal").exists()
    with pytest.raises(ValueError, match="another SQLite program") as refused:
        ResultStore(path)
    statement = str(refused.value).split('"')[1]
    assert statement == "UPDATE meta SET value = '0' WHERE key = 'open'"
    conn = sqlite3.connect(path)
    conn.execute(statement)
    conn.commit()
    conn.close()
    with ResultStore(path) as reopened:
        assert reopened.counts()["pending"] == 2
