"""meshadv.util.json_file.read_json and the two loaders built on it (rendering sets, assumed-defaults files)."""

from __future__ import annotations

from pathlib import Path

import pytest

from meshadv.datasets.rendering_set import load_rendering_set
from meshadv.experiments.regenerate import load_assumed
from meshadv.util.json_file import read_json


def test_read_json_returns_the_value_and_names_the_file_in_its_errors(tmp_path: Path) -> None:
    good = tmp_path / "good.json"
    good.write_text('[1, {"a": null}]', encoding="utf-8")
    assert read_json(good, "list file") == [1, {"a": None}]
    with pytest.raises(FileNotFoundError, match=r"^list file .*missing\.json does not exist$"):
        read_json(tmp_path / "missing.json", "list file")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json", encoding="utf-8")
    with pytest.raises(ValueError, match=r"^list file .*bad\.json is not JSON: "):
        read_json(bad, "list file")


def test_rendering_set_and_assumed_defaults_loaders_report_missing_and_broken_files(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("{not json", encoding="utf-8")
    with pytest.raises(FileNotFoundError, match=r"^path .*nowhere\.json does not exist"):
        load_rendering_set(tmp_path / "nowhere.json")
    with pytest.raises(ValueError, match=r"^path .*bad\.json is not .*JSON"):
        load_rendering_set(bad)
    with pytest.raises(FileNotFoundError, match=r"^assumed-defaults file .*nowhere\.json does not exist"):
        load_assumed(tmp_path / "nowhere.json")
    with pytest.raises(ValueError, match=r"^assumed-defaults file .*bad\.json is not JSON"):
        load_assumed(bad)
    assert load_assumed(None) == {}
