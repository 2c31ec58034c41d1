"""relative_path: the paths a copied results folder keeps pointing with."""

from __future__ import annotations

from pathlib import Path

import pytest

from meshadv.util.paths import relative_path


@pytest.mark.parametrize("target, base, expected", [
    ("run/results.db", "run/report", "../results.db"),
    ("run/results.db", "run", "results.db"),
    ("run/a/b/results.db", "other/report", "../../run/a/b/results.db"),
    ("run/./x/../results.db", "run/report/", "../results.db"),
    ("run", "run", "."),
])
def test_relative_to_the_folder(tmp_path: Path, target: str, base: str, expected: str) -> None:
    assert relative_path(tmp_path / target, tmp_path / base) == expected
    assert (tmp_path / base / expected).resolve() == (tmp_path / target).resolve()


def test_symbolic_links_are_followed(tmp_path: Path) -> None:
    (tmp_path / "real").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "real", target_is_directory=True)
    assert relative_path(tmp_path / "link" / "results.db", tmp_path / "real" / "report") == "../results.db"


def test_without_a_common_root_the_absolute_path(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    def no_common_root(path: str, start: str) -> str:
        raise ValueError("path is on mount 'D:', start on mount 'C:'")

    monkeypatch.setattr("meshadv.util.paths.os.path.relpath", no_common_root)
    assert relative_path(tmp_path / "results.db", tmp_path / "report") == (tmp_path / "results.db").resolve().as_posix()
