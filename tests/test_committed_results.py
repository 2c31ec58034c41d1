"""The committed results databases open on a fresh clone (the .db file alone, no -wal) and hold finished jobs."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from meshadv.experiments import ResultStore

ROOT = Path(__file__).parents[1]
DATABASES = sorted((ROOT / "docs" / "results").glob("**/results.db"))


@pytest.mark.parametrize("db", DATABASES, ids=lambda p: str(p.relative_to(ROOT)))
def test_committed_database_resumes_from_the_file_alone(db: Path, tmp_path: Path) -> None:
    """A copy of the file alone opens (it was closed cleanly before the copy) and has finished jobs to resume from;
    a job a stopped run left ``running`` goes back to pending."""
    copy = tmp_path / "results.db"
    shutil.copyfile(db, copy)
    with ResultStore(copy) as store:
        store.requeue_running()
        counts = store.counts()
    assert counts["done"] > 0 and counts["running"] == 0 and counts["total"] >= counts["done"]
