"""A transfer table written before the concept had one name (column and record key ``attack_type``) stays readable:
it is migrated to ``perturbation`` when opened, and new rows can be added to it. The typed controlled-transfer result
stores records of the same format as the plain rows written before it."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

from meshadv.transfer.results import load_transfer_rows, save_transfer_rows

OLD_SCHEMA = """
CREATE TABLE transfer (
    id INTEGER PRIMARY KEY AUTOINCREMENT, experiment TEXT NOT NULL, kind TEXT NOT NULL, case_id TEXT NOT NULL,
    victim TEXT NOT NULL, true_class TEXT NOT NULL, target TEXT NOT NULL, attack_type TEXT NOT NULL,
    view INTEGER NOT NULL, success_meshadv INTEGER, success_mitsuba INTEGER, record TEXT NOT NULL,
    created REAL NOT NULL, UNIQUE (experiment, kind, case_id, view));
"""


def test_old_transfer_table_is_read_and_extended(tmp_path: Path) -> None:
    db = tmp_path / "old.db"
    old = {"case_id": "a", "victim": "v", "true_class": "boat", "target": "", "attack_type": "shape", "view": 0,
           "success_meshadv": True, "success_mitsuba": False}
    with sqlite3.connect(db) as conn:
        conn.executescript(OLD_SCHEMA)
        conn.execute("INSERT INTO transfer (experiment, kind, case_id, victim, true_class, target, attack_type, view,"
                     " success_meshadv, success_mitsuba, record, created) VALUES ('e', 'controlled', 'a', 'v', "
                     "'boat', '', 'shape', 0, 1, 0, ?, 0.0)", (json.dumps(old),))
    rows = load_transfer_rows(db)
    assert len(rows) == 1 and rows[0]["perturbation"] == "shape" and "attack_type" not in rows[0]
    new = {**{k: v for k, v in old.items() if k != "attack_type"}, "case_id": "b", "perturbation": "texture"}
    save_transfer_rows(db, [new], experiment="e")
    assert [r["perturbation"] for r in load_transfer_rows(db)] == ["shape", "texture"]
    with sqlite3.connect(db) as conn:
        columns = {r[1] for r in conn.execute("PRAGMA table_info(transfer)")}
    assert "perturbation" in columns and "attack_type" not in columns


#: The keys of a controlled-transfer row as evaluate_case wrote it (a plain dict) before ControlledResult existed.
OLD_CONTROLLED_KEYS = {"case_id", "victim", "true_class", "target", "perturbation", "view", "success_meshadv",
                       "success_mitsuba", "untargeted_meshadv", "untargeted_mitsuba", "top1_meshadv", "top1_mitsuba",
                       "mean_abs_image_difference", "variant", "benign_correct"}


def test_controlled_result_records_keep_the_old_row_format(tmp_path: Path) -> None:
    import dataclasses

    import pytest

    from meshadv.transfer.results import ControlledResult

    ok = ControlledResult(case_id="a", victim="v", true_class="boat", target="chair", perturbation="shape", view=1,
                          success_meshadv=True, success_mitsuba=False, untargeted_meshadv=True,
                          untargeted_mitsuba=True, top1_meshadv="folding chair", top1_mitsuba="canoe",
                          mean_abs_image_difference=0.03, variant="scalar_rgb", benign_correct=True)
    failed = ControlledResult(case_id="b", victim="v", true_class="boat", target="", perturbation="texture", view=0,
                              success_meshadv=None, success_mitsuba=None, error="killed by signal 6")
    assert set(ok.to_record()) == OLD_CONTROLLED_KEYS  # "error" only on a failed render, as before
    assert failed.to_record()["error"] == "killed by signal 6" and failed.to_record()["success_mitsuba"] is None
    with pytest.raises(dataclasses.FrozenInstanceError, match="'view'"):
        ok.view = 2  # type: ignore[misc]
    db = tmp_path / "r.db"
    save_transfer_rows(db, [ok.to_record(), failed.to_record()], experiment="e")
    loaded = load_transfer_rows(db)
    assert [{k: v for k, v in r.items() if k not in ("experiment", "kind")} for r in loaded] == [
        ok.to_record(), failed.to_record()]
    assert ControlledResult(**{k: v for k, v in loaded[0].items() if k not in ("experiment", "kind")}) == ok
