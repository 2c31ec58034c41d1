"""Every ``meshadv`` command takes SIGTERM as Ctrl-C (``meshadv.commands._common_options``), and
``meshadv transfer controlled`` keeps every finished mesh when interrupted."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any, Collection, List

import pytest
from typer.testing import CliRunner

from meshadv.cli import app
from meshadv.transfer.results import ControlledResult, load_transfer_rows
from signal_fixtures import terminate_when

SLEEPING_COMMAND = textwrap.dedent('''
    import sys, time
    import typer
    from meshadv.commands._common_options import install

    app = typer.Typer(add_completion=False)

    @app.command()
    def sleep() -> None:
        print("ready", flush=True)
        time.sleep(120)

    @app.command()
    def other() -> None:
        pass

    install(app)
    app(args=["sleep"], prog_name="sleeper")
''')


def test_sigterm_ends_any_command_like_ctrl_c(tmp_path: Path) -> None:
    """A plain command killed with SIGTERM exits 130 with one line (without the wrapper it dies with -15)."""
    script = tmp_path / "sleeper.py"
    script.write_text(SLEEPING_COMMAND)
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert proc.stdout is not None
    _, stderr = terminate_when(proc, lambda: proc.stdout.readline().strip() == "ready", exit_timeout=60)
    assert proc.returncode == 130, stderr
    assert "interrupted" in stderr
    assert "Traceback" not in stderr


def _fake_case(case_id: str) -> Any:
    return type("Case", (), {"case_id": case_id})()


def test_interrupted_transfer_keeps_finished_meshes_and_resumes(tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    import meshadv.transfer.controlled as controlled

    db = tmp_path / "results.db"
    db.touch()
    skipped: List[Collection[str]] = []

    def cases(db_path: Any, *, skip: Collection[str] = (), **kwargs: Any) -> list:
        skipped.append(set(skip))
        return [_fake_case(c) for c in ("job-a", "job-b", "job-c") if c not in skip]

    def transfer_interrupted_on_b(batch: list, **kwargs: Any) -> List[ControlledResult]:
        if batch[0].case_id == "job-b":
            raise KeyboardInterrupt  # Ctrl-C, or SIGTERM through the command wrapper
        return [ControlledResult(batch[0].case_id, "efficientnet_lite0", "car", "sofa", "shape", 0, True, False)]

    monkeypatch.setattr(controlled, "cases_from_store", cases)
    monkeypatch.setattr(controlled, "controlled_transfer", transfer_interrupted_on_b)
    runner = CliRunner()
    first = runner.invoke(app, ["transfer", "controlled", str(db)])
    assert first.exit_code == 130, first.output
    assert "1 transferred adversarial meshes are kept" in first.output
    assert "transfer the other 2" in first.output
    assert [r["case_id"] for r in load_transfer_rows(db, experiment="controlled", kind="controlled")] == ["job-a"]

    monkeypatch.setattr(controlled, "controlled_transfer", lambda batch, **kw: [
        ControlledResult(batch[0].case_id, "efficientnet_lite0", "car", "sofa", "shape", 0, True, True)])
    second = runner.invoke(app, ["transfer", "controlled", str(db)])
    assert second.exit_code == 0, second.output
    assert skipped[-1] == {"job-a"}  # the finished mesh is not rendered again
    ids = sorted(r["case_id"] for r in load_transfer_rows(db, experiment="controlled", kind="controlled"))
    assert ids == ["job-a", "job-b", "job-c"]
