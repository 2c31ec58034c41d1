"""The results database alone is the sweep: a copy of the .db file resumes elsewhere, and artefacts come back on demand.

A tiny real sweep (built-in meshes, 32 px, 3 steps) runs half its jobs in folder A; only ``results.db`` is copied to
folder B ("a new machine") and A is deleted. The sweep resumed in B skips the finished jobs and runs the rest; the
missing artefacts of the finished ones are regenerated from their stored spec and seed, reproduce the stored records,
and feed the Mitsuba transfer pass's cases.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from sweep_fixtures import tiny_builtin_config
from typer.testing import CliRunner

from meshadv.experiments import ResultStore, SerialBackend, run_sweep
from meshadv.experiments.config import expand_jobs, parse_config
from meshadv.experiments.regenerate import regenerate_job

pytest.importorskip("meshadv._raster", reason="the native renderer is not built (maturin develop --release)")

TINY = tiny_builtin_config("tiny-portable")
JOB = "meshadv.experiments.jobs:run_attack_job"


@pytest.fixture(scope="module")
def victim_available() -> None:
    try:
        from meshadv.victims import load_victim

        load_victim("efficientnet_lite0")
    except ImportError as err:  # the package is missing; broken weights must fail, not skip
        pytest.skip(f"victim efficientnet_lite0 unavailable: {err}")


def test_copied_database_resumes_and_regenerates(tmp_path: Path, victim_available: None) -> None:
    from meshadv.cli import build_app
    from meshadv.transfer.controlled import cases_from_store

    jobs = expand_jobs(parse_config(TINY))
    assert len(jobs) == 4
    first, second = tmp_path / "machine_a", tmp_path / "machine_b"
    with ResultStore(first / "results.db") as store:
        store.set_meta("config_text", "[runner]\njob = \"meshadv.experiments.jobs:run_attack_job\"\n")
        half = run_sweep(store, jobs[:2], JOB, out_root=first, backend=SerialBackend(), max_attempts=1,
                         progress=False)
    assert half.done == 2
    second.mkdir()
    shutil.copyfile(first / "results.db", second / "results.db")  # the .db file only: no -wal, no artefacts
    assert not (second / "results.db-wal").exists()
    shutil.rmtree(first)  # the first machine is gone
    with ResultStore(second / "results.db") as store:
        stored = {r.job_id: r.record for r in store.rows("done")}
        summary = run_sweep(store, jobs, JOB, out_root=second, backend=SerialBackend(), max_attempts=1,
                            progress=False)
    assert (summary.skipped, summary.ran, summary.done) == (2, 2, 4)  # continued, not restarted
    for jid in stored:  # finished jobs were not run again here
        assert not (second / "jobs" / jid[:2] / jid).exists()

    # artefacts on demand: the transfer pass's cases regenerate the missing folders next to the database
    cases = cases_from_store(second / "results.db", only_successful=False)
    with ResultStore(second / "results.db", read_only=True) as store:  # closed: an open one leaves its mark
        assert {c.case_id for c in cases} == {r.job_id for r in store.rows("done")}
    for jid in stored:
        assert (second / "jobs" / jid[:2] / jid / "result.json").is_file()
    # and they reproduce the stored records (success, steps, distance)
    jid = next(iter(stored))
    again = regenerate_job(second / "results.db", jid[:8], tmp_path / "regen")
    assert again.matches, again.differences
    assert (tmp_path / "regen" / "adversarial.ply").is_file()
    res = CliRunner().invoke(build_app(), ["regenerate", str(second / "results.db"), jid, "-o", str(tmp_path / "r2")])
    assert res.exit_code == 0, res.output
    assert "matches the stored one" in res.output
    res = CliRunner().invoke(build_app(), ["regenerate", str(second / "results.db"), "zzzz"])
    assert res.exit_code == 2 and "matches 0 jobs" in res.output
