"""A controlled-transfer result stores a flat record with a fixed set of keys, and reads back equal."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from meshadv.transfer.results import ControlledResult, load_transfer_rows, save_transfer_rows

#: The keys of a stored controlled-transfer row of a successful render.
CONTROLLED_KEYS = {"case_id", "victim", "true_class", "target", "perturbation", "view", "success_meshadv",
                   "success_mitsuba", "untargeted_meshadv", "untargeted_mitsuba", "top1_meshadv", "top1_mitsuba",
                   "mean_abs_image_difference", "variant", "benign_correct"}


def test_controlled_result_records_keep_their_row_format(tmp_path: Path) -> None:
    ok = ControlledResult(case_id="a", victim="v", true_class="boat", target="chair", perturbation="shape", view=1,
                          success_meshadv=True, success_mitsuba=False, untargeted_meshadv=True,
                          untargeted_mitsuba=True, top1_meshadv="folding chair", top1_mitsuba="canoe",
                          mean_abs_image_difference=0.03, variant="scalar_rgb", benign_correct=True)
    failed = ControlledResult(case_id="b", victim="v", true_class="boat", target="", perturbation="texture", view=0,
                              success_meshadv=None, success_mitsuba=None, error="killed by signal 6")
    assert set(ok.to_record()) == CONTROLLED_KEYS  # "error" only on a failed render
    assert failed.to_record()["error"] == "killed by signal 6" and failed.to_record()["success_mitsuba"] is None
    with pytest.raises(dataclasses.FrozenInstanceError, match="'view'"):
        ok.view = 2  # type: ignore[misc]
    db = tmp_path / "r.db"
    save_transfer_rows(db, [ok.to_record(), failed.to_record()], experiment="e")
    loaded = load_transfer_rows(db)
    assert [{k: v for k, v in r.items() if k not in ("experiment", "kind")} for r in loaded] == [
        ok.to_record(), failed.to_record()]
    assert ControlledResult(**{k: v for k, v in loaded[0].items() if k not in ("experiment", "kind")}) == ok
